"""``predict`` as a library: a source, a :class:`~cosemdepth.inference.policy.Streamer` and sinks (the files, the
output bag, the rerun recording) writing one output folder.

Two entry points: :func:`predict` (a loaded model and a source or a stream-mode dataset: the files of
:mod:`cosemdepth.streaming.sinks.files` and any further sinks) and :func:`run_predict` (what ``cosemdepth predict``
runs once its arguments are parsed: everything from a :class:`PredictOptions`). The output folder is written under a
temporary name beside ``out`` and renamed to ``out`` at the end: a run that fails leaves nothing behind; a previous
output of ``predict`` in ``out`` is replaced.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

from tqdm.auto import tqdm

from ..data.sequence import SequenceDataset
from ..decoders.depth.task import no_depth_warning
from ..errors import ConfigError
from ..evaluation.evaluator import to_json
from ..inference.policy import BASELINE, Streamer, StreamPolicy, policy_info
from ..measures.classes import class_info
from ..models.outputs import ESTIMATED, HELD, RESET
from ..models.protocol import StreamingModel, model_config
from ..output_safety.atomic import atomic_write_text
from ..output_safety.outdir import Input
from ..output_safety.staging import StagedDir
from ..render.visualize import DEFAULT_FPS, DEFAULT_VIDEO
from ..streaming import pipeline
from ..streaming.frames import Source
from ..streaming.sinks.bag import DEFAULT_NAMESPACE, BagSink, check_namespace
from ..streaming.sinks.files import DEFAULT_INVALID, MANIFEST, FileOptions, FilesSink
from ..streaming.sinks.rerun import RerunSink, check_rrd_path, require_rerun
from ..streaming.sources.dataset import DatasetSource
from ..tasks import class_count, tasks_for
from .model import ModelOptions, check_run_size, load_for
from .options import CommandResult, RunOptions, open_source


@dataclass(frozen=True)
class PredictOptions:
    """Everything ``cosemdepth predict`` runs on, checked at construction.

    Attributes:
        source: the input's options (:class:`~cosemdepth.streaming.sources.dataset.DatasetOptions`,
            :class:`~cosemdepth.streaming.sources.flight.FlightOptions`,
            :class:`~cosemdepth.streaming.sources.bag.BagOptions`, or those of a further registered source: an
            object with ``source`` (its :data:`~cosemdepth.streaming.SOURCES` name) and ``inputs()``).
        model: :class:`~cosemdepth.jobs.model.ModelOptions`; run: :class:`~cosemdepth.jobs.options.RunOptions`.
        out: the output folder (new, empty, or a previous ``predict`` output); overwrite: also replace the output of
            another cosemdepth command.
        files: :class:`~cosemdepth.streaming.sinks.files.FileOptions` (video, fps, invalid, depth range).
        out_namespace: the output bag's topic prefix (a bag input); rerun: also write this rerun recording.
    """

    source: Any
    model: ModelOptions
    out: Path
    run: RunOptions = field(default_factory=RunOptions)
    files: FileOptions = field(default_factory=FileOptions)
    overwrite: bool = False
    out_namespace: str = DEFAULT_NAMESPACE
    rerun: Optional[Path] = None

    def __post_init__(self) -> None:
        if self.source.source == "bag":
            check_namespace(self.out_namespace)
        if self.rerun is not None:
            require_rerun()  # the file itself is checked with the command's inputs, before anything is read

    def inputs(self) -> list[Input]:
        """The command's input paths (the output policy of :mod:`cosemdepth.output_safety.outdir`)."""
        return [*self.model.inputs(), *self.source.inputs()]


def default_policy(source_options) -> str | None:
    """The streaming policy of an input when none is asked for: its options' ``default_policy`` (every-frame for
    dataset splits, the paper's protocol), else None (baseline when the model records its training motion)."""
    return getattr(source_options, "default_policy", None)


def make_streamer(
    model: StreamingModel, policy: StreamPolicy | str | None, min_baseline: float | None, source: Source
) -> Streamer:
    """The :class:`~cosemdepth.inference.policy.Streamer` of a run: ``policy`` and ``min_baseline`` as given (None:
    the model's), raised to the source's floor ``source.min_baseline_m`` when it has one (e.g. the resolution of its
    positions) and the policy holds frames."""
    streamer = Streamer(model, policy, min_baseline=min_baseline)
    floor = getattr(source, "min_baseline_m", None)
    if floor is not None and streamer.policy.mode == BASELINE and streamer.has_depth and streamer.min_baseline < floor:
        streamer = Streamer(model, streamer.policy, min_baseline=float(floor))
    return streamer


def _as_source(source):
    """A source: ``source`` itself, or a stream-mode dataset wrapped in a
    :class:`~cosemdepth.streaming.sources.dataset.DatasetSource`."""
    return source if callable(getattr(source, "batches", None)) else DatasetSource(source)


def predict(
    model: StreamingModel,
    source: Source | SequenceDataset,
    out: str | Path,
    *,
    video: str | None = DEFAULT_VIDEO,
    fps: float = DEFAULT_FPS,
    max_frames: int | None = RunOptions.max_frames,
    lanes: int = RunOptions.lanes,
    num_workers: int = RunOptions.workers,
    overwrite: bool = False,
    progress: bool = RunOptions.progress,
    dataset_name: str | None = None,
    info: dict[str, Any] | None = None,
    depth_range: tuple[float, float] | None = None,
    sinks: Sequence = (),
    inputs: Sequence[Input] = (),
    policy: StreamPolicy | str | None = None,
    min_baseline: float | None = None,
    invalid: str = DEFAULT_INVALID,
) -> dict[str, Any]:
    """Stream ``model`` over ``source`` and write every output into ``out`` (the layout of
    :mod:`cosemdepth.streaming.sinks.files`).

    Args:
        model: a loaded model (eval mode). source: a :class:`~cosemdepth.streaming.frames.Source`, or a stream-mode
            dataset of single frames (``open_dataset(..., seq_len=1)``).
        out: output folder: new, empty, or a previous ``predict`` output (the output policy of
            :mod:`cosemdepth.output_safety.outdir`; never an input or a folder holding or inside one).
        video: ``"mp4"`` (GIF when no ffmpeg), ``"gif"`` or ``None``/``"none"``; fps: video frame rate;
            invalid: ``"keep"`` or ``"nan"``; depth_range: near/far metres of the depth colour map (default: per
            trajectory, from its first frames): :class:`~cosemdepth.streaming.sinks.files.FileOptions`.
        max_frames: only the first N frames. lanes: trajectories at once; num_workers: data-loading workers.
        overwrite: also replace the output of another cosemdepth command (never a folder cosemdepth did not write).
        progress: progress bar. dataset_name: for the palette (default: the dataset's name). info: extra entries
            of ``predictions.json``.
        sinks: more outputs (:class:`~cosemdepth.streaming.frames.Sink`: the output bag, a rerun recording...),
            fed after the files; their ``close()`` entries are merged into the manifest.
        inputs: the command's input paths (model, pose file...); a dataset's ``root`` is always one.
        policy: the streaming policy (``"baseline"``, ``"every-frame"``; None: baseline when the model records its
            training motion); min_baseline: its minimum baseline in metres (default: the model's).
    Returns:
        the manifest (also written to ``out/predictions.json``).
    """
    files = FileOptions(video=video, fps=fps, invalid=invalid, depth_range=depth_range)
    source = _as_source(source)
    inputs = list(inputs)
    root = getattr(getattr(source, "dataset", None), "root", None)
    if root is not None:
        inputs.append(Input("dataset root", root))
    staged = StagedDir(out, "predict", overwrite=overwrite, what="--out folder", inputs=inputs)
    staged.check()
    return _predict(
        model,
        source,
        staged,
        files=files,
        run=RunOptions(max_frames=max_frames, lanes=lanes, workers=num_workers, progress=progress),
        streamer=make_streamer(model, policy, min_baseline, source),
        dataset_name=dataset_name,
        info=info,
        sinks=sinks,
    )


def _predict(
    model: StreamingModel,
    source: Source,
    staged: StagedDir,
    *,
    files: FileOptions,
    run: RunOptions,
    streamer: Streamer,
    dataset_name: str | None,
    info: dict[str, Any] | None,
    sinks: Sequence,
) -> dict[str, Any]:
    """:func:`predict` into a checked staging folder."""
    cfg = model_config(model, "predict")
    name = (
        dataset_name
        or getattr(getattr(source, "dataset", None), "name", None)
        or source.describe().get("name")
        or getattr(source, "name", "")
    )
    total = source.total_frames(run.max_frames) if hasattr(source, "total_frames") else None
    if total == 0:
        raise ConfigError("predict: the dataset has no frame")
    start = time.perf_counter()
    with staged as tmp:
        classes = class_count(cfg)
        names, palette = class_info(classes, name) if classes else ((), None)
        writer = FilesSink(tasks_for(cfg), class_names=names, palette=palette, options=files)
        bar = tqdm(total=total, unit="frame", desc="predict", disable=not run.progress, leave=False)
        seconds = [0.0]

        def step_done(batch) -> None:
            seconds[0] += batch.seconds
            bar.update(len(batch))

        try:
            summary = pipeline.run(
                source,
                streamer,
                [writer, *sinks],
                lanes=run.lanes,
                max_frames=run.max_frames,
                num_workers=run.workers,
                progress=step_done,
                out=tmp,
            )
        finally:
            bar.close()
        extra = {k: v for k, v in summary.items() if k not in _FILE_ENTRIES}
        manifest: dict[str, Any] = {
            "format": "cosemdepth-predictions",
            **(info or {}),
            "model": {**(info or {}).get("model", {}), "arch": cfg.arch},
            "dataset": {**(info or {}).get("dataset", {}), "name": name},
            "policy": policy_info(streamer) if streamer.has_depth else None,
            "frames_by_status": summary["frames_by_status"] if streamer.has_depth else None,
            **{k: summary[k] for k in ("encodings", "class_names", "palette", "video", "fps", "frames_written")},
            "model_seconds": seconds[0],
            "wall_seconds": time.perf_counter() - start,
            "trajectories": summary["trajectories"],
            **extra,
            "frames": summary["frames"],
        }
        atomic_write_text(tmp / MANIFEST, to_json(manifest))
    return manifest


#: The entries of ``predictions.json`` the files sink gives.
_FILE_ENTRIES = (
    "frames_by_status",
    "encodings",
    "class_names",
    "palette",
    "video",
    "fps",
    "frames_written",
    "trajectories",
    "frames",
)


def run_settings(options: PredictOptions, source: Source, model: StreamingModel | None = None) -> dict[str, Any]:
    """What determines predict's outputs besides the frames: ``predictions.json``'s ``run`` entry. ``input_size``
    ``[H, W]`` and ``intrinsics`` ``[fx, fy, cx, cy]`` (package convention: pixel centres at +0.5) are those the model
    was fed; the pose settings are null for dataset splits (whose readers fix them); ``precision`` is the graph's
    own (its metadata) with ``backend="onnxruntime"``."""
    graph = getattr(model, "onnx", None) if options.model.backend == "onnxruntime" else None
    size = source.frame_size()
    intrinsics = getattr(source, "intrinsics", None)
    own = options.source.settings() if hasattr(options.source, "settings") else {}
    out = {
        "model": str(options.model.path),
        "path": options.model.path_name,
        "onnx": None if options.model.onnx is None else str(options.model.onnx),
        "precision": graph.precision if graph is not None else options.model.precision,
        "input_size": None if size is None else list(size),
        "intrinsics": None if intrinsics is None else [float(v) for v in intrinsics.tolist()],
    }
    for key in (
        "intrinsics_given",
        "hfov_deg",
        "calibration",
        "camera_info_topic",
        "convention",
        "frame_skip",
        "poses",
        "pose_topic",
        "match",
        "stamp_unit",
        "max_pose_gap",
        "skip_unposed",
    ):
        out[key] = own.get(key)
    calibration = getattr(options.source, "calibration", None)
    out["calibration"] = None if calibration is None else str(calibration)
    out["jpeg_idct"] = getattr(options.source, "jpeg_idct", None)
    entries = getattr(source, "run_entries", None)  # a source's own settings found while opening (a clock offset)
    if callable(entries):
        out.update(entries())
    return out


def run_predict(options: PredictOptions) -> CommandResult:
    """``cosemdepth predict``: the checks that need files (the output folder, once, before anything is read; the
    rerun recording's file), the source at the model's size, the model, the sinks, the run (see the module
    docstring)."""
    options.model.apply_threads()
    policy, min_baseline = options.run.stream_policy(default_policy(options.source))
    inputs = options.inputs()
    staged = StagedDir(options.out, "predict", overwrite=options.overwrite, what="--out folder", inputs=inputs)
    staged.check()
    if options.rerun is not None:
        check_rrd_path(options.rerun, inputs=[*inputs, Input("--out", options.out)])
    source = open_source(options.source, options.run, options.model.operating_point(), note=True)
    try:
        model, device = load_for(options.model, source.frame_size(), options.run.lanes)
        check_run_size(model, source.frame_size(), device, options.run.lanes, getattr(source, "trajectories", None))
        describe = source.describe()
        info = {
            "model": {"path": str(options.model.path)},
            "dataset": describe,
            "device": str(device),
            "run": run_settings(options, source, model),
        }
        sinks = output_sinks(options, source, model)
    except BaseException:
        source.close()
        raise
    manifest = _predict(
        model,
        source,
        staged,
        files=options.files,
        run=options.run,
        streamer=make_streamer(model, policy, min_baseline, source),
        dataset_name=getattr(options.source, "dataset_name", None),
        info=info,
        sinks=sinks,
    )
    return CommandResult(manifest, *predict_report(manifest, options, source_report(source)))


def source_report(source: Source) -> str:
    """What a run's summary line says about its input beyond the frames (a source's optional ``report()``)."""
    report = getattr(source, "report", None)
    return report() if callable(report) else ""


def output_sinks(options: PredictOptions, source: Source, model: StreamingModel) -> list:
    """The outputs of ``predict`` besides its files: the output bag (a bag input) and the rerun recording
    (``rerun``)."""
    cfg = model_config(model, "predict")
    classes = class_count(cfg)
    names, palette = class_info(classes, "flight") if classes else ((), None)
    sinks: list = []
    flight = getattr(source, "flight", None)
    if flight is not None:
        sinks.append(BagSink(flight.intrinsics.tolist(), palette, options.out_namespace))
    if options.rerun is not None:
        sinks.append(
            RerunSink(
                options.rerun,
                class_names=names,
                palette=palette,
                absolute_poses=flight is not None,
                command="predict",
            )
        )
    return sinks


def predict_report(manifest: dict[str, Any], options: PredictOptions, source_report: str) -> tuple[list, list]:
    """``(lines, warnings)``: what ``cosemdepth predict`` prints about a finished run."""
    out = options.out
    n = manifest["frames_written"]
    videos = [t["video"] for t in manifest["trajectories"] if "video" in t]
    nt = len(manifest["trajectories"])
    lines = [
        f"wrote {n} frame{'s' * (n != 1)} of {nt} trajector{'ies' if nt != 1 else 'y'} to {out}"
        + (f"; videos: {', '.join(str(Path(out) / v) for v in videos)}" if videos else "")
        + source_report
        + (f"; rerun recording: {options.rerun}" if options.rerun else "")
    ]
    warnings = []
    statuses = manifest.get("frames_by_status")
    if statuses is not None:
        fractions = [f.get("valid_fraction", 0.0) for f in manifest["frames"]]
        lines.append(depth_report(statuses, manifest["policy"], fractions))
        no_depth = no_depth_warning(
            sum(statuses.values()),
            statuses.get(ESTIMATED, 0),
            statuses.get(HELD, 0),
            sum(fractions) / len(fractions) if fractions else None,
        )
        unavailable = (manifest.get("dataset") or {}).get("depth_unavailable")  # the source's reason, e.g. a log's
        if no_depth and unavailable:
            no_depth = f"no depth was produced: {unavailable}"
        if no_depth:
            warnings.append(f"cosemdepth predict: warning: {no_depth}")
    return lines, warnings


def depth_report(statuses: dict, policy: dict, valid_fractions) -> str:
    """The summary line of the depth's statuses, e.g. ``"depth (policy baseline): 137 frames estimated, 1 reset
    (no depth); 12 frames held: the camera moved less than 0.74 m from its reference frame; 91.3 % of the pixels
    valid"``."""
    est, held, reset = (int(statuses.get(k, 0)) for k in (ESTIMATED, HELD, RESET))
    parts = [f"{est} frame{'s' * (est != 1)} estimated, {reset} reset (no depth)"]
    if held:
        parts.append(
            f"{held} frame{'s' * (held != 1)} held: the camera moved less than "
            f"{policy['min_baseline_m']:.2f} m from its reference frame"
        )
    fractions = list(valid_fractions)
    if fractions:
        parts.append(f"{100.0 * sum(fractions) / len(fractions):.1f} % of the pixels valid")
    return f"depth (policy {policy['mode']}): " + "; ".join(parts)


__all__ = [
    "PredictOptions",
    "default_policy",
    "depth_report",
    "make_streamer",
    "output_sinks",
    "predict",
    "predict_report",
    "run_predict",
    "run_settings",
    "source_report",
]
