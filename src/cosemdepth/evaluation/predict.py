"""Run a model over a dataset split or your own flight and write every output (``cosemdepth predict``).

Output folder (one sub-folder per trajectory; ``NNNNNN`` is the input image's file stem, so that a user can match
outputs and inputs (for a bag frame: ``<topic's last part>_<seconds, 10 digits>.<nanoseconds, 9 digits>``, the
image's full stamp); the frame's row in its trajectory, 6 digits, when the dataset has no file names; a stem seen
twice in one trajectory gets ``_<row>`` appended)::

    OUT/predictions.json                       what was run, the encodings below, every frame's status and files
    OUT/<trajectory>/depth/NNNNNN.npy          predicted depth, float32 [H, W], metres (the model's output as is;
                                               with invalid="nan", NaN where depth_valid is 0)
    OUT/<trajectory>/depth_valid/NNNNNN.png    8-bit PNG, 255 where the depth is an estimate, 0 where it is not
    OUT/<trajectory>/depth_png/NNNNNN.png      16-bit PNG, uint16 = round(depth_m * 256), saturated to [1, 65535]
                                               (1/256 m steps up to 255.996 m; depth_m = png / 256); 0: no depth
    OUT/<trajectory>/labels/NNNNNN.png         8-bit PNG of class indices (argmax)
    OUT/<trajectory>/labels_color/NNNNNN.png   RGB PNG, the dataset's palette (Mid-Air/SynthAir: design 10.5)
    OUT/<trajectory>/side_by_side/NNNNNN.png   RGB | depth | GT depth | labels | GT labels (GT when known), each
                                               panel >= 384 px, a depth colour bar and a class legend below
    OUT/<trajectory>/video.mp4                 the side-by-side frames as a video (GIF without ffmpeg)

The pictures (:mod:`cosemdepth.evaluation.figures`) colour depth on a range fixed per trajectory, chosen from its
first frames (recorded in ``predictions.json`` under the trajectory's ``pictures``) unless ``depth_range`` is given.

Depth outputs are absent for M4Semantic, label outputs for M4Depth. A depth map says which pixels it could not
estimate (:mod:`cosemdepth.inference.policy`): each frame's record in ``predictions.json`` has its ``status``
(``reset``: the first frame of a trajectory or a frame held after it, no pixel valid, its depth the model's initial
value; ``estimated``; ``held``: the reference frame's depth carried into this view because the camera moved less
than the policy's minimum baseline), ``baseline_m`` and ``valid_fraction``; ``depth_valid`` is the per-pixel mask.

The folder is written under a temporary name beside ``OUT`` and renamed to ``OUT`` at the end (each file is also
written atomically): a run that fails leaves nothing behind; a previous output of ``predict`` in ``OUT`` is replaced.
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from ..decoders.depth.task import valid_mask
from ..errors import ConfigError
from ..inference.policy import Streamer, StreamPolicy, policy_info
from ..measures.classes import class_info
from ..output_safety.atomic import atomic_write_text
from ..output_safety.outdir import Input
from ..output_safety.staging import StagedDir
from ..tasks import TASKS, DecoderTask, TaskWriter, WriteOptions, class_count, tasks_for
from .evaluator import _model_config, to_json
from .figures import FlightPictures, frame_maps
from .streaming import StreamBatch, make_schedule, stream, trajectory_rows
from .visualize import DEFAULT_FPS, DEFAULT_VIDEO, VIDEO_FORMATS, VideoWriter, save_png

MANIFEST = "predictions.json"


class _NoFiles(TaskWriter):
    """The writer of a task that writes no file."""

    def write(self, folder, rel, stem, frames, b, record):
        return {}


_NO_FILES = _NoFiles()
#: What the ``.npy`` depth holds where the mask is 0 (``--invalid``): the model's values, or NaN.
INVALID_MODES = ("keep", "nan")
DEFAULT_INVALID = "keep"


def safe_relpath(name: str) -> str:
    """A trajectory name as a relative folder path: path parts kept, odd characters replaced by ``_``."""
    parts = [re.sub(r"[^A-Za-z0-9._-]+", "_", p) for p in re.split(r"[/\\]+", str(name))]
    parts = [p for p in parts if p not in ("", ".", "..")]
    return "/".join(parts) or "trajectory"


#: A file-type extension: a dot, a letter, up to 4 more letters or digits (``.png``, ``.JPEG``, ``.jp2``). A
#: numeric tail is not one: a bag frame's stamp (``image_raw@1700000000.000001000``) keeps its fraction.
_EXTENSION = re.compile(r"\.[A-Za-z][A-Za-z0-9]{0,4}$")


def file_stem(source: str) -> str:
    """The last part of a frame's source (a path, or a bag frame's ``bag:topic@stamp``) without its file-type
    extension."""
    return _EXTENSION.sub("", Path(source).name)


class PredictionWriter:
    """Writes the files of every frame of a stream (a callback for :func:`stream` batches).

    Args:
        folder: output folder (the staging folder of :func:`predict`).
        num_classes, dataset_name: for the palette; depth_range: ``(near, far)`` of the depth colour map (metres;
            default: chosen per trajectory from its first frames).
        video: ``"mp4"``, ``"gif"`` or ``None``; fps: video frame rate.
        sources: dataset index -> source image path (recorded in the manifest).
        invalid: ``"keep"`` (the ``.npy`` holds the model's values everywhere; the mask says which are estimates) or
            ``"nan"`` (NaN in the ``.npy`` where the mask is 0).
        tasks: the model's decoder tasks (:func:`cosemdepth.tasks.tasks_for`), whose writers write the files of each
            frame (default: those of the heads the stream has).
    """

    def __init__(
        self,
        folder: Path,
        *,
        num_classes: int | None,
        dataset_name: str | None = None,
        video: str | None = DEFAULT_VIDEO,
        fps: float = DEFAULT_FPS,
        depth_range: tuple[float, float] | None = None,
        sources: dict[int, str] | None = None,
        invalid: str = DEFAULT_INVALID,
        tasks: Sequence[DecoderTask] | None = None,
    ) -> None:
        if invalid not in INVALID_MODES:
            raise ConfigError(f"--invalid must be one of {', '.join(INVALID_MODES)}, got {invalid!r}")
        self.invalid = invalid
        self.folder = Path(folder)
        self.video = video
        self.fps = fps
        self.depth_range = depth_range
        self.names, self.palette = class_info(num_classes, dataset_name) if num_classes else ((), None)
        self.sources = sources or {}
        self.tasks = None if tasks is None else list(tasks)
        self.options = WriteOptions(invalid=invalid, palette=self.palette)
        self._writers: dict[str, TaskWriter] = {}
        self.frames: list[dict[str, Any]] = []
        self.trajectories: dict[str, dict[str, Any]] = {}
        self._stems: dict[str, set[str]] = {}
        self._videos: dict[str, VideoWriter] = {}
        self._pictures: dict[str, FlightPictures] = {}

    def __call__(self, batch: StreamBatch, include: torch.Tensor | None = None) -> None:
        for b in range(len(batch)):
            self.write_frame(batch, b)

    def _stem(self, entry: dict[str, Any], batch: StreamBatch, b: int) -> str:
        """The input image's file stem (made file-name safe), else the row number; unique within the trajectory."""
        row = int(batch.frame[b])
        src = self.sources.get(int(batch.indices[b]))
        stem = re.sub(r"[^A-Za-z0-9._-]+", "_", file_stem(src)).strip(".") if src else ""
        stem = stem or f"{row:06d}"
        used = self._stems.setdefault(entry["folder"], set())
        if stem in used:
            stem = f"{stem}_{row:06d}"
        used.add(stem)
        return stem

    def write_frame(self, batch: StreamBatch, b: int) -> dict[str, Any]:
        traj = batch.trajectory[b]
        rel = safe_relpath(traj)
        if traj not in self.trajectories:
            if rel in {t["folder"] for t in self.trajectories.values()}:
                rel = f"{rel}_{len(self.trajectories)}"
            self.trajectories[traj] = {"name": traj, "folder": rel, "frames": 0}
        entry = self.trajectories[traj]
        rel = entry["folder"]
        stem = self._stem(entry, batch, b)
        base = self.folder / rel
        record = {"trajectory": traj, "frame": int(batch.frame[b]), "reset": bool(batch.reset[b])}
        files: dict[str, str] = {}
        maps = frame_maps(batch, b, title=f"frame {int(batch.frame[b])}", labels_ok=self._labels_ok)
        for t in self._tasks_of(batch):
            files.update(self._writer(t).write(self.folder, rel, stem, batch, b, record))
        files["side_by_side"] = f"{rel}/side_by_side/{stem}.png"
        pictures = self._pictures.get(traj)
        if pictures is None:
            pictures = self._pictures[traj] = FlightPictures(
                lambda path, image, traj=traj, base=base: self._emit(traj, base, path, image),
                class_names=self.names,
                palette=self.palette,
                depth_range=self.depth_range,
            )
        pictures.add(maps, self.folder / files["side_by_side"])
        record["files"] = files
        src = self.sources.get(batch.indices[b])
        if src is not None:
            record["source"] = src
        self.frames.append(record)
        entry["frames"] += 1
        return record

    def _tasks_of(self, batch: StreamBatch) -> list[DecoderTask]:
        """The tasks whose files are written: the model's (``tasks``), else those of every head the stream has."""
        if self.tasks is not None:
            return self.tasks
        return [t for t in TASKS.values() if t.head in batch.heads]

    def _writer(self, t: DecoderTask) -> TaskWriter:
        if t.name not in self._writers:
            self._writers[t.name] = t.writer(self.options) or _NO_FILES
        return self._writers[t.name]

    def summary(self) -> dict[str, Any]:
        """What the tasks' writers say about the whole run (e.g. ``frames_by_status``)."""
        return {k: v for w in self._writers.values() for k, v in w.summary().items()}

    def encodings(self) -> dict[str, Any]:
        """``predictions.json``'s ``encodings`` of the tasks' files."""
        return {k: v for t in (self.tasks or ()) for k, v in t.encodings(self.options).items()}

    def _labels_ok(self, gt: np.ndarray) -> bool:
        return self.palette is not None and gt.size > 0 and int(gt.max()) < len(self.palette) and int(gt.min()) >= 0

    def _emit(self, traj: str, base: Path, path: Path, image: np.ndarray) -> None:
        """A drawn side-by-side frame: its PNG and the trajectory's video."""
        save_png(path, image)
        if self.video:
            writer = self._videos.get(traj)
            if writer is None:
                writer = self._videos[traj] = VideoWriter(base / "video", fps=self.fps, fmt=self.video)
            writer.write(image)

    def close(self) -> None:
        """Draw the frames still held back, finish the videos."""
        for traj, pictures in self._pictures.items():
            figure = pictures.finish()
            if figure is not None:
                self.trajectories[traj]["pictures"] = figure.metadata()
        for traj, writer in list(self._videos.items()):
            path = writer.close()
            self.trajectories[traj]["video"] = path.relative_to(self.folder).as_posix()
            del self._videos[traj]

    def abort(self) -> None:
        self._pictures.clear()
        for writer in self._videos.values():
            writer.abort()
        self._videos.clear()


def _sources(dataset, indices) -> dict[int, str]:
    out = {}
    windows = getattr(dataset, "windows", None)
    trajs = getattr(dataset, "trajectories", None)
    if windows is None or trajs is None:
        return out
    for i in indices:
        ti, row = windows[i]
        out[i] = str(trajs[ti].frame(row).rgb)
    return out


def predict(
    model,
    dataset,
    out: str | Path,
    *,
    video: str | None = DEFAULT_VIDEO,
    fps: float = DEFAULT_FPS,
    max_frames: int | None = None,
    lanes: int = 1,
    num_workers: int = 0,
    overwrite: bool = False,
    progress: bool = False,
    dataset_name: str | None = None,
    info: dict[str, Any] | None = None,
    depth_range: tuple[float, float] | None = None,
    sinks: tuple = (),
    inputs: Sequence[Input] = (),
    policy: StreamPolicy | str | None = None,
    min_baseline: float | None = None,
    invalid: str = DEFAULT_INVALID,
) -> dict[str, Any]:
    """Stream ``model`` over ``dataset`` and write every output into ``out`` (see the module docstring).

    Args:
        model: a loaded model (eval mode). dataset: stream-mode single frames (``open_dataset(..., seq_len=1)``).
        out: output folder: new, empty, or a previous ``predict`` output (the output policy of
            :mod:`cosemdepth.output_safety.outdir`; never an input or a folder holding or inside one).
        video: ``"mp4"`` (GIF when no ffmpeg), ``"gif"`` or ``None``/``"none"``.
        fps: video frame rate. max_frames: only the first N rows. lanes, num_workers: as :func:`stream`.
        overwrite: also replace the output of another cosemdepth command (never a folder cosemdepth did not write).
        progress: progress bar. dataset_name: for the palette. info: extra entries of ``predictions.json``.
        depth_range: near/far metres of the depth colour map (default: per trajectory, from its first frames).
        sinks: more outputs (the ROS bag of :mod:`cosemdepth.robotics.bag_writer`, the rerun recording of
            :mod:`cosemdepth.robotics.rerun_writer`): objects with ``open(folder)``, ``__call__(batch)``, ``close() -> dict``
            (merged into the manifest) and ``abort()``.
        inputs: the command's input paths (model, pose file...); ``dataset.root`` is always one.
        policy: the streaming policy (:mod:`cosemdepth.inference.policy`: ``"baseline"`` or ``"every-frame"``, the
            paper's protocol; None: baseline when the model records its training motion); min_baseline: its minimum baseline in metres (default: the
            model's). invalid: ``"keep"`` or ``"nan"`` (:class:`PredictionWriter`).
    Returns:
        the manifest (also written to ``out/predictions.json``).
    """
    if video == "none":
        video = None
    if video is not None and video not in VIDEO_FORMATS:
        raise ConfigError(f"--video must be one of {(*VIDEO_FORMATS, 'none')}, got {video!r}")
    if not fps > 0:
        raise ConfigError(f"--fps must be positive, got {fps}")
    if invalid not in INVALID_MODES:
        raise ConfigError(f"--invalid must be one of {', '.join(INVALID_MODES)}, got {invalid!r}")
    cfg = _model_config(model)
    streamer = Streamer(model, policy, min_baseline=min_baseline)
    name = dataset_name or getattr(dataset, "name", None) or ""
    inputs = list(inputs)
    if getattr(dataset, "root", None) is not None:
        inputs.append(Input("dataset root", dataset.root))
    staged = StagedDir(out, "predict", overwrite=overwrite, what="--out folder", inputs=inputs)
    staged.check()
    groups = trajectory_rows(dataset, max_frames)
    schedule = make_schedule(groups, lanes)
    if not schedule:
        raise ConfigError("predict: the dataset has no frame")
    start = time.perf_counter()
    with staged as tmp:
        tasks = tasks_for(cfg)
        writer = PredictionWriter(
            tmp,
            num_classes=class_count(cfg),
            dataset_name=name,
            video=video,
            fps=fps,
            depth_range=depth_range,
            sources=_sources(dataset, [i for g in groups for i in g]),
            invalid=invalid,
            tasks=tasks,
        )
        bar = tqdm(total=sum(len(g) for g in groups), unit="frame", desc="predict", disable=not progress, leave=False)
        model_seconds = 0.0
        extra: dict[str, Any] = {}
        opened: list = []
        try:
            for sink in sinks:
                sink.open(tmp)
                opened.append(sink)
            for batch in stream(streamer, dataset, schedule=schedule, num_workers=num_workers):
                writer(batch)
                for sink in sinks:
                    sink(batch)
                model_seconds += batch.seconds
                bar.update(len(batch))
            writer.close()
            for sink in sinks:
                extra.update(sink.close())
        except BaseException:
            writer.abort()
            for sink in opened:
                sink.abort()
            raise
        finally:
            bar.close()
        manifest: dict[str, Any] = {
            "format": "cosemdepth-predictions",
            **(info or {}),
            "model": {**(info or {}).get("model", {}), "arch": cfg.arch},
            "dataset": {**(info or {}).get("dataset", {}), "name": name},
            "policy": policy_info(streamer) if streamer.has_depth else None,
            "frames_by_status": writer.summary().get("frames_by_status") if streamer.has_depth else None,
            "encodings": {
                **writer.encodings(),
                "side_by_side": "side_by_side/*.png: RGB | predicted depth | ground-truth depth | predicted labels | "
                "ground-truth labels (GT when known), depth on the turbo colour map, linear from red (0 m) to dark "
                "blue at the range in trajectories[].pictures.depth_range_m, with a colour bar and a class legend",
            },
            "class_names": list(writer.names),
            "palette": None if writer.palette is None else np.asarray(writer.palette).tolist(),
            "video": video,
            "fps": fps,
            "frames_written": len(writer.frames),
            "model_seconds": model_seconds,
            "wall_seconds": time.perf_counter() - start,
            "trajectories": list(writer.trajectories.values()),
            **extra,
            "frames": writer.frames,
        }
        atomic_write_text(tmp / MANIFEST, to_json(manifest))
    return manifest


__all__ = ["DEFAULT_INVALID", "INVALID_MODES", "MANIFEST", "PredictionWriter", "predict", "safe_relpath", "valid_mask"]
