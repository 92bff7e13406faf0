"""The end-to-end demo (``cosemdepth demo``): a trained Co-SemDepth on a held-out SynthAir flight, against baselines.

Steps:

1. load the model (default: the shipped weights ``weights/synthair-cosemdepth/``, trained with ``cosemdepth train``
   on SynthAir; a clear error if they are missing);
2. build a held-out SynthAir flight with the generator of ``cosemdepth synth`` (one trajectory of ``frames`` evaluated frames at
   ``size``, with a world seed the training data did not use) - or use an existing Mid-Air-format dataset
   (``data_root``);
3. evaluate the model with the test protocol (design 11.3: streamed frame by frame, the reset frame excluded): the
   evaluator's source and Streamer, with the demo's collector (:class:`DemoCollector`) as a further sink;
4. evaluate two trivial baselines on the same frames: *constant depth* (the median of all evaluated ground-truth
   depths, clipped to [0, 80] m as the metrics clip them, predicted everywhere) and *majority class* (the most
   frequent ground-truth class, predicted everywhere);
5. write the report folder: ``metrics.json`` (schema below), ``report.md``, ``iou.png`` (per-class IoU chart),
   ``qualitative.png`` (RGB | predicted depth | ground-truth depth | predicted labels | ground-truth labels for a few
   frames, with a depth colour bar and a class legend) and ``flight.mp4`` (the same panels, captions, colour bar and
   legend for every frame; ``flight.gif`` without ffmpeg). Both are drawn by :mod:`cosemdepth.render.figures`
   with one depth range for the whole flight (``metrics.json``'s ``pictures``).

``metrics.json``::

    {"model": {"miou": ..., "abs_rel": ..., "rmse": ..., "delta1": ...},
     "baselines": {"majority_class": {"miou": ...}, "constant_depth": {"abs_rel": ..., "rmse": ..., "delta1": ...}},
     ...more keys: "details", "flight", "timings", "machine", "date"}

mIoU and delta1 are fractions in [0, 1]. The report folder is written under a temporary name and renamed at the end.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import importlib.util
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from . import __version__
from .checkpoints.model_io import load_model, read_config_file
from .data import open_dataset
from .data.decode import DEFAULT_JPEG_IDCT, JPEG_IDCTS
from .data.frames import FocalSize, midair_intrinsics
from .defaults import DEFAULT_DEVICE
from .errors import CheckpointError, ConfigError, DatasetError
from .evaluation.evaluator import Evaluator, to_json
from .evaluation.resources import machine_info, resolve_device
from .inference.fast_model import reference_model
from .measures.classes import class_info
from .measures.metrics import EPS, EVAL_MAX_DEPTH, ConfusionMatrix, DepthMetrics
from .models.footprint import check_size
from .operating_point import OperatingPoint
from .output_safety.atomic import atomic_path, atomic_write_text
from .output_safety.outdir import Input, check_not_input, model_inputs
from .output_safety.staging import StagedDir
from .render.figures import FlightPictures, frame_maps
from .render.visualize import DEFAULT_FPS, DEFAULT_VIDEO, VIDEO_FORMATS, VideoWriter, save_png
from .synthair.climate import CLIMATES
from .synthair.writer import MAX_FRAMES, SynthConfig
from .synthair.writer import generate as synth_generate
from .tasks import class_count

#: Where the shipped weights live, relative to the repository root (or the current folder).
DEFAULT_MODEL = Path("weights") / "synthair-cosemdepth"
DEFAULT_SIZE = 128
DEFAULT_FRAMES = 150
#: World seed of the held-out flight (the shipped weights are trained on other seeds).
DEFAULT_SEED = 1001
DEFAULT_CLIMATE = "sunny"
#: Colour rays per pixel of the generated flight: the shipped weights were trained on 3x supersampled SynthAir
#: (scripts/make_demo_weights.sh), and the held-out flight is rendered the same way.
DEFAULT_SUPERSAMPLE = 3
REPORT_MARKER = "report.md"
QUALITATIVE_FRAMES = 4


# ---------------------------------------------------------------------------------------------------- model


def default_model_candidates() -> list[Path]:
    """``./weights/synthair-cosemdepth`` and ``<repository>/weights/synthair-cosemdepth`` (source checkout)."""
    repo = Path(__file__).resolve().parents[2]
    out = [Path.cwd() / DEFAULT_MODEL, repo / DEFAULT_MODEL]
    return list(dict.fromkeys(out))


def resolve_model_path(model: str | os.PathLike | None) -> Path:
    """The model folder to use: ``model`` as given, else the first existing default candidate."""
    if model is not None:
        return Path(model)
    for c in default_model_candidates():
        if c.exists():
            return c
    raise CheckpointError(
        f"the demo's trained weights were not found (looked for {', '.join(str(c) for c in default_model_candidates())}). "
        "They ship with the repository in weights/synthair-cosemdepth/; run the demo from the repository, or pass "
        "--model DIR (a model folder written by `cosemdepth train` or `cosemdepth convert`)"
    )


def flight_size(op: OperatingPoint | None) -> int:
    """The side of the generated (square, 90-degree) SynthAir flight: the size where its focal length in pixels is
    the model's (:attr:`~cosemdepth.operating_point.OperatingPoint.focal`), or :data:`DEFAULT_SIZE` for a model
    without an operating point."""
    if op is None:
        return DEFAULT_SIZE
    native = (DEFAULT_SIZE, DEFAULT_SIZE)
    return op.input_size(native, float(midair_intrinsics(native)[0]))[1]


def _hw(size) -> str:
    return f"{size}x{size}" if isinstance(size, int) else "x".join(str(v) for v in size)


# ---------------------------------------------------------------------------------------------------- flight


def synth_available() -> bool:
    return importlib.util.find_spec("cosemdepth.synthair.writer") is not None


def synth_frames(frames: int) -> int:
    """The 25 Hz camera frames ``cosemdepth synth`` renders for a demo flight of ``frames`` CSV rows (every 4th)."""
    return 4 * (frames + 1)


#: Longest demo flight, in CSV rows: what ``cosemdepth synth`` can render.
MAX_DEMO_FRAMES = MAX_FRAMES // 4 - 1


def generate_flight(
    data_dir: Path,
    *,
    size: int,
    frames: int,
    seed: int,
    climate: str,
    supersample: int = DEFAULT_SUPERSAMPLE,
    progress: bool = False,
) -> Path:
    """Render one SynthAir trajectory of ``frames`` CSV rows with the generator of ``cosemdepth synth``; returns the
    dataset root."""
    if not synth_available():
        raise ConfigError(
            "this installation has no `cosemdepth synth` command to build the SynthAir flight; pass "
            "--data-root ROOT to evaluate on an existing Mid-Air-format dataset (splits in ROOT/splits)"
        )
    config = SynthConfig(
        out=Path(data_dir),
        trajectories=1,
        frames=synth_frames(frames),
        size=size,
        seed=seed,
        climates=(climate,),
        supersample=supersample,
    )
    synth_generate(config, progress=progress)
    return data_dir


def open_flight_split(
    root: Path, size: int | FocalSize, split_dir: Path | None = None, jpeg_idct: str = DEFAULT_JPEG_IDCT
):
    """The first of the test, val and train splits of ``root`` (splits in ``root/splits``) that has trajectories."""
    split_dir = split_dir or root / "splits"
    errors = []
    for split in ("test", "val", "train"):
        try:
            return open_dataset(
                "synthair", root, split_dir=split_dir, split=split, seq_len=1, size=size, jpeg_idct=jpeg_idct
            ), split
        except DatasetError as e:
            errors.append(str(e))
    raise DatasetError(f"{root}: no split with trajectories under {split_dir} ({'; '.join(errors)})")


# ---------------------------------------------------------------------------------------------------- baselines


@dataclass
class DemoCollector:
    """A sink of the evaluation: keeps the evaluated ground truth (for the baselines; ``include``: the frames the
    protocol counts, :meth:`~cosemdepth.evaluation.evaluator.Evaluator.include`, default all), a few frames for the
    qualitative strip, and writes the side-by-side video."""

    total_frames: int
    num_classes: int | None
    palette: np.ndarray | None
    video: Any = None
    qualitative: int = QUALITATIVE_FRAMES
    gt_depths: list[torch.Tensor] = field(default_factory=list)
    label_hist: np.ndarray | None = None
    class_names: tuple[str, ...] = ()
    picks: list[Any] = field(default_factory=list)
    seen: int = 0
    include: Callable[[Any], torch.Tensor] | None = None

    def __post_init__(self) -> None:
        n = self.total_frames
        k = min(self.qualitative, n)
        self.targets = sorted({int(round(x)) for x in np.linspace(0.1 * n, n - 1, k)}) if k else []
        if self.num_classes:
            self.label_hist = np.zeros(self.num_classes, dtype=np.int64)
        self.pictures = FlightPictures(
            lambda _, image: self.video.write(image) if self.video is not None else None,
            class_names=self.class_names,
            palette=self.palette,
        )

    def _labels_ok(self, gt: np.ndarray) -> bool:
        return self.palette is not None and gt.size > 0 and 0 <= int(gt.min()) and int(gt.max()) < len(self.palette)

    def open(self, folder) -> None:
        pass

    def close(self) -> dict:
        return {}

    def abort(self) -> None:
        pass

    def __call__(self, batch) -> None:
        include = self.include(batch) if self.include is not None else torch.ones_like(batch.reset)
        for b in range(len(batch)):
            pos = self.seen
            self.seen += 1
            inc = bool(include[b])
            if inc and batch.gt_depth is not None:
                self.gt_depths.append(batch.gt_depth[b, 0].detach().float().cpu())
            if inc and batch.gt_labels is not None and self.label_hist is not None:
                self.label_hist += np.bincount(batch.gt_labels[b].cpu().numpy().ravel(), minlength=self.num_classes)[
                    : self.num_classes
                ]
            maps = frame_maps(batch, b, title=f"frame {int(batch.frame[b])}", labels_ok=self._labels_ok)
            if self.palette is None:
                maps.labels = None
            self.pictures.add(maps)
            if inc and self.targets and pos >= self.targets[0] and len(self.picks) < self.qualitative:
                self.targets.pop(0)
                self.picks.append(maps)

    def finish(self):
        """Draw the video frames still held back; returns the flight's figure (None without frames)."""
        return self.pictures.finish()

    def constant_depth(self) -> dict[str, float] | None:
        """Metrics of the constant median-depth prediction over the evaluated frames (design 11.1 protocol)."""
        if not self.gt_depths:
            return None
        g = torch.stack(self.gt_depths).to(torch.float64).clamp(0.0, EVAL_MAX_DEPTH)
        valid = g[g > EPS]
        if valid.numel() == 0:
            return None
        median = float(np.median(valid.numpy()))
        dm = DepthMetrics()
        for gt in self.gt_depths:
            dm.update(gt, torch.full_like(gt, median))
        res = dm.compute()
        return {
            "abs_rel": res["abs_rel"],
            "rmse": res["rmse"],
            "delta1": res["delta1"],
            "sq_rel": res["sq_rel"],
            "rmse_log": res["rmse_log"],
            "delta2": res["delta2"],
            "delta3": res["delta3"],
            "depth_m": median,
        }

    def majority_class(self) -> dict[str, Any] | None:
        """mIoU (Keras MeanIoU semantics) of predicting the most frequent GT class everywhere."""
        if self.label_hist is None or self.label_hist.sum() == 0:
            return None
        c = int(np.argmax(self.label_hist))
        cm = ConfusionMatrix(self.num_classes)
        cm.matrix[:, c] = torch.from_numpy(self.label_hist)
        return {"miou": cm.miou(), "class": c, "iou": [float(x) for x in cm.iou()]}


# ---------------------------------------------------------------------------------------------------- figures


def plot_iou(path: Path, class_names, model_iou, baseline_iou, model_miou, baseline_miou) -> None:
    """Per-class IoU bar chart (model vs majority-class baseline), written atomically."""
    import matplotlib  # deferred: heavy (about 0.5 s), and only this figure needs it

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    n = len(class_names)
    x = np.arange(n)
    fig, ax = plt.subplots(figsize=(max(6.0, 0.9 * n + 2), 3.6), dpi=110)
    vals = [np.nan_to_num(np.asarray(v, dtype=float) * 100, nan=0.0) for v in (model_iou, baseline_iou)]
    ax.bar(x - 0.2, vals[0], 0.4, label=f"Co-SemDepth (mIoU {100 * model_miou:.1f}%)", color="#3b6fb6")
    if baseline_iou is not None:
        ax.bar(x + 0.2, vals[1], 0.4, label=f"majority class (mIoU {100 * baseline_miou:.1f}%)", color="#bbbbbb")
    for i, v in enumerate(model_iou):
        if v is None or (isinstance(v, float) and math.isnan(v)):
            ax.text(x[i] - 0.2, 1, "n/a", ha="center", fontsize=7, rotation=90)
    ax.set_xticks(x, class_names, rotation=20)
    ax.set_ylabel("IoU (%)")
    ax.set_ylim(0, 100)
    ax.set_title("Per-class IoU on the held-out flight")
    ax.legend(fontsize=8, loc="upper right")
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def plot_qualitative(path: Path, figure, picks) -> None:
    """The strip: one row per picked frame (:class:`~cosemdepth.render.figures.FrameMaps`), drawn by the flight's
    ``figure`` (the captions, panel order, colour bar and legend of the video), written atomically."""
    save_png(path, figure.rows(picks))


# ---------------------------------------------------------------------------------------------------- report


def _pct(v) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{100 * v:.2f}%"


def _num(v, spec=".4f") -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def report_markdown(m: dict[str, Any]) -> str:
    """``report.md`` from the content of ``metrics.json``."""
    model, base = m["model"], m["baselines"]
    det = m["details"]
    ev = det["evaluation"]
    fl = m["flight"]
    mach = m["machine"]
    tm = m["timings"]
    maj, const = base["majority_class"], base["constant_depth"]
    maj_name = det.get("majority_class_name") or "–"
    lines = [
        "# cosemdepth demo: Co-SemDepth on a held-out SynthAir flight",
        "",
        f"{m['date']} on {mach.get('cpu')} ({mach.get('cpu_cores')} cores, {mach.get('torch_threads')} torch threads, "
        f"device {mach.get('device')}), torch {mach.get('torch')}, cosemdepth {m.get('cosemdepth_version')}.",
        "",
        f"Flight: {fl['description']}. {ev['protocol']['frames_streamed']} frames streamed frame by frame, "
        f"{ev['protocol']['frames_evaluated']} evaluated ("
        + (
            "reset frames excluded, design 11.3)."
            if ev["protocol"].get("reset_frames_excluded", True)
            else "every frame is a reset: counted for the labels, never for the depth)."
        ),
        f"Model: `{det['model_path']}` ({ev['model']['arch']}, {ev['params']:,} parameters).",
        "",
        "## Results",
        "",
        "| | mIoU | AbsRel | RMSE (m) | δ<1.25 | SqRel | RMSE_log | δ<1.25² | δ<1.25³ |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    em = ev["metrics"]
    lines.append(
        f"| **Co-SemDepth** | {_pct(model['miou'])} | {_num(model['abs_rel'])} | {_num(model['rmse'], '.3f')} "
        f"| {_pct(model['delta1'])} | {_num(em.get('sq_rel'))} | {_num(em.get('rmse_log'))} | "
        f"{_pct(em.get('delta2'))} | {_pct(em.get('delta3'))} |"
    )
    lines.append(f"| majority class ({maj_name} everywhere) | {_pct(maj['miou'])} | – | – | – | – | – | – | – |")
    cd = det.get("constant_depth") or {}
    lines.append(
        f"| constant depth ({_num(cd.get('depth_m'), '.2f')} m everywhere) | – | {_num(const['abs_rel'])} | "
        f"{_num(const['rmse'], '.3f')} | {_pct(const['delta1'])} | {_num(cd.get('sq_rel'))} | "
        f"{_num(cd.get('rmse_log'))} | {_pct(cd.get('delta2'))} | {_pct(cd.get('delta3'))} |"
    )
    valid_line = _validity_line(ev)
    if valid_line:
        lines += ["", valid_line]
    if m.get("warning"):
        lines += ["", f"**Warning**: {m['warning']}."]
    ratios = m.get("comparison", {})
    lines += ["", "Against the baselines:", ""]
    if ratios.get("miou_ratio") is not None:
        lines.append(f"- mIoU is {ratios['miou_ratio']:.2f} x the majority-class baseline's (target: at least 2 x)")
    if ratios.get("abs_rel_ratio") is not None:
        lines.append(
            f"- AbsRel is {ratios['abs_rel_ratio']:.2f} x the constant-depth baseline's (target: at most 0.5 x)"
        )
    names = det.get("class_names") or []
    if names:
        lines += [
            "",
            "## Per-class IoU",
            "",
            "| class | " + " | ".join(names) + " |",
            "|---" * (len(names) + 1) + "|",
            "| Co-SemDepth | " + " | ".join(_pct(v) for v in det["model_iou"]) + " |",
            "| majority class | " + " | ".join(_pct(v) for v in det.get("majority_iou") or []) + " |",
            "",
            "![per-class IoU](iou.png)",
        ]
    pics = m.get("pictures") or {}
    panels = " | ".join(pics.get("panels") or [])
    lines += ["", "## Qualitative", "", f"![{panels or 'qualitative'}](qualitative.png)", ""]
    if pics.get("depth_range_m"):
        near, far = pics["depth_range_m"]
        lines.append(
            f"Depth colours: turbo, linear from {near:g} m (red) to {far:g} m (dark blue), one range for the "
            "whole flight (chosen from its first frames); farther depths, the sky among them, "
            "are dark blue."
        )
    if m.get("files", {}).get("video"):
        lines.append(
            f"The whole flight: [{m['files']['video']}]({m['files']['video']}) "
            f"(the same panels{': ' + panels if panels else ''})."
        )
    lines += ["", "## Timings", "", "| stage | seconds |", "|---|---|"]
    for k, v in tm.items():
        lines.append(f"| {k.replace('_', ' ')} | {v:.1f} |")
    lines += [
        "",
        f"Model speed: {_num(ev['speed']['ms_per_frame'], '.1f')} ms/frame at {_hw(fl['size'])} "
        f"(model step only, batch 1, float32); peak memory {_num(ev.get('peak_memory_mb'), '.0f')} MiB "
        f"({ev.get('peak_memory_method')}).",
        "",
        "## Reproduce",
        "",
        "```bash",
        m["command"],
        "```",
        "",
    ]
    return "\n".join(lines)


def _ratio(a, b) -> float | None:
    if a is None or b is None or not (isinstance(a, float) and isinstance(b, float)):
        return None
    if math.isnan(a) or math.isnan(b) or b == 0:
        return None
    return a / b


def _validity_line(ev: dict) -> str | None:
    """The report's line on the depth's validity mask (coverage, metrics of the valid pixels, frame statuses)."""
    em, proto = ev.get("metrics", {}), ev.get("protocol", {})
    policy, counts = proto.get("policy") or {}, proto.get("frames_by_status")
    if em.get("coverage") is None or not counts:
        return None
    mb = policy.get("min_baseline_m")
    how = f"streaming policy {policy.get('mode')}" + (f", minimum baseline {mb:.2f} m" if mb else "")
    return (
        f"Validity mask ({how}; docs/motion.md): {_pct(em['coverage'])} of the ground-truth pixels valid; on "
        f"them AbsRel {_num(em.get('valid_abs_rel'))}, δ<1.25 {_pct(em.get('valid_delta1'))}. Evaluated frames: "
        + ", ".join(f"{v} {k}" for k, v in counts.items())
        + "."
    )


def run_demo(
    out: str | os.PathLike,
    *,
    model: str | os.PathLike | None = None,
    size: int | None = None,
    frames: int = DEFAULT_FRAMES,
    seed: int = DEFAULT_SEED,
    climate: str = DEFAULT_CLIMATE,
    supersample: int = DEFAULT_SUPERSAMPLE,
    data_root: str | os.PathLike | None = None,
    data_dir: str | os.PathLike | None = None,
    device: str = DEFAULT_DEVICE,
    video: str | None = DEFAULT_VIDEO,
    overwrite: bool = False,
    progress: bool = True,
    fast: bool = True,
    jpeg_idct: str = DEFAULT_JPEG_IDCT,
    policy: str | None = None,
    min_baseline: float | None = None,
    log=print,
) -> dict[str, Any]:
    """Run the demo and write the report folder ``out``; returns the content of ``metrics.json``.

    Args:
        out: report folder (new, empty, or a previous demo report, which is replaced).
        model: model folder (default: the shipped ``weights/synthair-cosemdepth``).
        size: image size of the generated flight and of the evaluation (default: the size where the flight's
            90-degree camera has the model's focal length in pixels, from its operating point: the training size
            of a model trained on SynthAir; 128 for a model without one; with ``data_root``, the size rule applied to
            that dataset's camera). A size whose focal length is far from the model's gets a warning on stderr.
        frames: evaluated-flight length in CSV rows (frames at 6.25 Hz). seed: world seed. climate: SynthAir climate.
        supersample: colour rays per pixel of the generated flight (1, 3 or 5; default 3, as the training data).
        data_root: evaluate on this existing Mid-Air-format dataset (splits in ``data_root/splits``) instead of
            generating one.
        data_dir: where to generate the flight (kept; re-running with the same arguments reuses it); default a
            temporary folder, deleted at the end.
        device: torch device. video: ``"mp4"``, ``"gif"`` or None. overwrite: replace a non-empty ``out``.
        progress: progress bar. fast: the fast fp32 inference path (default; False: the plain modules).
        jpeg_idct: JPEG decoding of the flight, ``"fast"`` (default, the original's) or ``"accurate"``.
        policy, min_baseline: the streaming policy (:mod:`cosemdepth.inference.policy`; default: baseline when the
            model records its training motion, else every-frame) and its minimum baseline (metres; default: the
            model's). The paper's metrics count every pixel with ground truth; the report adds the coverage and the
            metrics of the valid pixels.
        log: where to print progress lines.
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    if not isinstance(frames, int) or not 2 <= frames <= MAX_DEMO_FRAMES:
        raise ConfigError(
            f"--frames must be an integer in [2, {MAX_DEMO_FRAMES}] (the first frame is a reset; the "
            f"flight is rendered by cosemdepth synth, at most {MAX_FRAMES} camera frames), got "
            f"{frames!r}"
        )
    if data_root is None and climate not in CLIMATES:  # said here in one line, not by the synth it runs
        raise ConfigError(f"--climate must be one of {', '.join(CLIMATES)}, got {climate!r}")
    if size is not None and (not isinstance(size, int) or size < 32):
        raise ConfigError(f"--size must be an integer >= 32, got {size!r}")
    if video is not None and video not in VIDEO_FORMATS:
        raise ConfigError(f"--video must be {', '.join(VIDEO_FORMATS)} or none, got {video!r}")
    if jpeg_idct not in JPEG_IDCTS:
        raise ConfigError(f"--jpeg-idct must be {' or '.join(JPEG_IDCTS)}, got {jpeg_idct!r}")
    model_path = resolve_model_path(model)
    inputs = [
        *model_inputs(model_path),
        Input("--data-root", data_root) if data_root is not None else None,
        Input("--data-dir", data_dir) if data_dir is not None else None,
    ]
    staged = StagedDir(out, "demo", overwrite=overwrite, what="--out folder", inputs=inputs)
    staged.check()
    if data_dir is not None:  # the generated flight is an output too: it must not overlap the model or the report
        check_not_input(data_dir, [*model_inputs(model_path), Input("--out", out)], "--data-dir folder")
    dev = resolve_device(device)

    t = time.perf_counter()
    net = load_model(model_path, device=dev, mode="fast" if fast else "reference")
    try:
        _, meta = read_config_file(model_path)
    except CheckpointError:
        meta = {}
    cfg = net.config
    op = getattr(net, "operating_point", None)
    requested = size
    if size is None:
        size = flight_size(op)
    check_size(reference_model(net), size, size, device=dev)  # before a flight is rendered at that size
    timings["load_model"] = time.perf_counter() - t
    log(f"model: {model_path} ({cfg.arch}, {net.num_parameters():,} parameters)")

    with contextlib.ExitStack() as stack:
        t = time.perf_counter()
        temporary = False
        if data_root is not None:
            root = Path(data_root)
            description = f"the Mid-Air-format dataset {root}"
            timings["generate_flight"] = 0.0
        else:
            if data_dir is not None:
                root = Path(data_dir)
            else:
                root = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="cosemdepth-demo-"))) / "synthair"
                temporary = True
            log(
                f"building a held-out SynthAir flight: {frames} frames at {size}x{size}, seed {seed}, {climate} "
                f"(in {root})"
            )
            generate_flight(root, size=size, frames=frames, seed=seed, climate=climate, supersample=supersample)
            description = (
                f"SynthAir, world seed {seed}, climate {climate}, one trajectory of {frames} frames at "
                f"{size}x{size} ({supersample}x supersampled)"
            )
            timings["generate_flight"] = time.perf_counter() - t
        # an existing dataset without --size: at the model's focal length (its camera, its aspect ratio)
        at_model = data_root is not None and requested is None and op is not None
        dataset, split = open_flight_split(root, FocalSize(op.focal) if at_model else size, jpeg_idct=jpeg_idct)
        if requested is not None and op is not None:  # without --size: the rule above on the input's own camera
            warning = op.size_warning(
                (size, size), float(dataset.intrinsics[0]), default_size=dataset.opened_size(FocalSize(op.focal))
            )
            if warning:
                print(warning, file=sys.stderr)

        with staged as tmp:
            classes = class_count(cfg)
            names, palette = class_info(classes, "synthair") if classes else ((), None)
            writer = VideoWriter(tmp / "flight", fps=DEFAULT_FPS, fmt=video) if video else None
            try:
                t = time.perf_counter()
                log(f"evaluating on {len(dataset)} frames ({split} split of {root}) ...")
                evaluator = Evaluator(
                    net,
                    dataset,
                    progress=progress,
                    dataset_name="synthair",
                    policy=policy,
                    min_baseline=min_baseline,
                )
                collector = DemoCollector(
                    total_frames=dataset.num_frames if hasattr(dataset, "num_frames") else len(dataset),
                    num_classes=classes,
                    palette=palette,
                    video=writer,
                    class_names=tuple(names),
                    include=evaluator.include,
                )
                evaluator.sinks.append(collector)
                result = evaluator.run()
                no_depth = result.depth_warning()
                if no_depth:
                    print(f"cosemdepth demo: warning: {no_depth}", file=sys.stderr)
                figure = collector.finish()
                timings["evaluate"] = time.perf_counter() - t
                video_path = writer.close() if writer is not None else None
            except BaseException:
                if writer is not None:
                    writer.abort()
                raise
            t = time.perf_counter()
            em = result.metrics
            const = collector.constant_depth()
            maj = collector.majority_class()
            model_block = {
                "miou": em.get("miou"),
                "abs_rel": em.get("abs_rel"),
                "rmse": em.get("rmse"),
                "delta1": em.get("delta1"),
                "coverage": em.get("coverage"),
                "valid_abs_rel": em.get("valid_abs_rel"),
                "valid_delta1": em.get("valid_delta1"),
            }
            metrics: dict[str, Any] = {
                "model": model_block,
                "baselines": {
                    "majority_class": {"miou": None if maj is None else maj["miou"]},
                    "constant_depth": {k: None if const is None else const[k] for k in ("abs_rel", "rmse", "delta1")},
                },
                "comparison": {
                    "miou_ratio": _ratio(model_block["miou"], None if maj is None else maj["miou"]),
                    "abs_rel_ratio": _ratio(model_block["abs_rel"], None if const is None else const["abs_rel"]),
                },
                "details": {
                    "model_path": str(model_path),
                    "model_source": meta.get("source"),
                    "class_names": list(names),
                    "model_iou": em.get("iou"),
                    "majority_iou": None if maj is None else maj["iou"],
                    "majority_class": None if maj is None else maj["class"],
                    "majority_class_name": None if maj is None or not names else names[maj["class"]],
                    "constant_depth": const,
                    "evaluation": result.to_dict(),
                },
                # the generated flight's root only when it is kept (--data-dir); a temporary one is gone by now
                "flight": {
                    "description": description,
                    "root": None if temporary else str(root.resolve()),
                    "kept": not temporary,
                    "jpeg_idct": jpeg_idct,
                    "split": split,
                    "size": result.info["dataset"]["size"] if at_model else size,
                    "model_operating_point": None if op is None else op.to_dict(),
                    "frames": frames if data_root is None else None,
                    "seed": seed if data_root is None else None,
                    "climate": climate if data_root is None else None,
                },
                "files": {
                    "report": "report.md",
                    "iou_chart": "iou.png" if names else None,
                    "qualitative": "qualitative.png",
                    "video": None if video_path is None else video_path.name,
                },
                "warning": no_depth,
                "machine": machine_info(dev),
                "date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
                "cosemdepth_version": __version__,
            }
            cmd = ["cosemdepth demo", f"--out {out}", *([] if at_model else [f"--size {size}"])]
            if model is not None:
                cmd.append(f"--model {model}")
            if data_root is not None:
                cmd.append(f"--data-root {data_root}")
            else:
                cmd += [f"--frames {frames}", f"--seed {seed}", f"--climate {climate}"]
            metrics["command"] = " ".join(cmd)
            if names:
                plot_iou(
                    tmp / "iou.png",
                    names,
                    em.get("iou") or [math.nan] * len(names),
                    None if maj is None else maj["iou"],
                    em.get("miou", math.nan),
                    math.nan if maj is None else maj["miou"],
                )
            if figure is not None:
                metrics["pictures"] = figure.metadata()  # what qualitative.png and the video show, the depth range
                plot_qualitative(tmp / "qualitative.png", figure, collector.picks)
            timings["report"] = time.perf_counter() - t
            timings["total"] = time.perf_counter() - t_start
            metrics["timings"] = timings
            atomic_write_text(tmp / "metrics.json", to_json(metrics))
            atomic_write_text(tmp / REPORT_MARKER, report_markdown(metrics))
    log(f"Report: {Path(out) / REPORT_MARKER}  (metrics: {Path(out) / 'metrics.json'})")
    return metrics


__all__ = ["DEFAULT_MODEL", "DemoCollector", "generate_flight", "resolve_model_path", "run_demo"]
