"""The test protocol of the original (design 11.3) with every metric of design 11, speed, size and memory.

Each trajectory of the split is streamed frame by frame with the model's explicit state (design 7.2); frames that start
a trajectory (``reset``; Mid-Air's CSV ``id == 0``) are run (they initialise the state) but left out of **all**
metrics. Depth metrics are per-frame values averaged over the evaluated frames (design 11.1); mIoU comes from one global
confusion matrix (design 11.2). What is evaluated follows the model and the data: each decoder of the model whose
ground truth the dataset has, with its task's metrics (:mod:`cosemdepth.tasks`): depth when the model predicts depth
and the dataset has depth, segmentation when the model predicts classes and the dataset has labels (M4Depth,
M4Semantic, Aeroscapes), and so on for any further registered decoder.

Datasets of independent images (Aeroscapes: every image is its own reset) would have no frame left under the reset
rule; there every frame counts for the labels (the semantic decoder does not use time). ``exclude_resets`` overrides
this. The depth of a reset frame is never a measurement (a placeholder: depth needs the camera's motion), so the depth
metrics leave every frame without depth out, whatever ``exclude_resets`` says: with none left they are absent (NaN),
and :meth:`EvaluationResult.depth_warning` says why.

Speed: ``ms_per_frame`` is the mean wall time of ``model.step`` per frame (synchronised on CUDA) over the steps after
``warmup`` steps, without data loading; with several trajectories per batch it is the step time divided by the batch.

Usage::

    from cosemdepth import load_model
    from cosemdepth.data import open_dataset
    from cosemdepth.evaluation.evaluator import evaluate
    result = evaluate(load_model("weights/synthair-cosemdepth"), open_dataset("synthair", "data/synthair", size=128))
    print(result.to_markdown())
"""

from __future__ import annotations

import datetime as _dt
import inspect
import json
import math
import re
import time
from dataclasses import dataclass, field
from typing import Any, Iterable

import torch
from tqdm.auto import tqdm

from .. import __version__
from ..decoders.depth.task import no_depth_warning
from ..errors import ConfigError
from ..inference.policy import EVERY_FRAME, Streamer, policy_info
from ..measures.metrics import ALL_DEPTH_METRICS, format_markdown_table
from ..models.outputs import ESTIMATED, HELD
from ..models.protocol import StreamingModel, model_config
from ..streaming import pipeline
from ..streaming.frames import Sink, StreamBatch
from ..streaming.sinks.metrics import MetricsSink
from ..streaming.sources.dataset import DatasetSource, make_schedule, trajectory_rows
from ..tasks import TASKS, TEST, MetricContext, tasks_for
from .resources import PeakMemory, machine_info


def dataset_ground_truth(dataset) -> set[str]:
    """The ground-truth keys of every registered decoder task that ``dataset`` carries (from its trajectories, else
    from its first item: :meth:`~cosemdepth.tasks.DecoderTask.dataset_has_ground_truth`)."""
    item: list = []

    def first_item():
        if not item:
            item.append(dataset[0])
        return item[0]

    return {t.gt_key for t in TASKS.values() if t.dataset_has_ground_truth(dataset, first_item)}


def dataset_modalities(dataset) -> tuple[bool, bool]:
    """``(has_depth, has_labels)`` of a sequence dataset (from its trajectories, else from its first item)."""
    found = dataset_ground_truth(dataset)
    return "depth" in found, "semantic" in found


def _finite_or_none(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite_or_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite_or_none(v) for v in x]
    return x


_NUMBER_LIST = re.compile(r"\[(?:\s*(?:-?[0-9.eE+-]+|null|true|false)\s*,)*\s*(?:-?[0-9.eE+-]+|null|true|false)\s*\]")


def to_json(data: Any) -> str:
    """Indented JSON text with NaN/inf written as ``null`` (strict JSON); lists of numbers on one line."""
    text = json.dumps(_finite_or_none(data), indent=2, allow_nan=False)
    text = _NUMBER_LIST.sub(lambda m: "[" + ", ".join(v.strip() for v in m.group(0)[1:-1].split(",")) + "]", text)
    return text + "\n"


@dataclass
class EvaluationResult:
    """What :func:`evaluate` measured.

    Attributes:
        metrics: depth metrics (``abs_rel``, ``sq_rel``, ``rmse``, ``rmse_log`` (the original's quirky mask),
            ``rmse_log_fixed``, ``delta1..3`` as fractions, ``depth_frames``) and/or ``miou`` (fraction), ``iou``
            (per-class list, NaN for a class absent from GT and prediction), ``semantic_frames``; with labels and
            depth in the dataset, the labels' temporal consistency (``flicker`` ... ``flicker_pairs``,
            :mod:`cosemdepth.measures.temporal`).
        confusion_matrix: ``[N, N]`` int64 counts (rows ground truth, columns prediction) or None.
        class_names: names of the N classes (or empty).
        params: parameter count; ms_per_frame: see the module docstring; peak_memory_mb and memory_method.
        info: model, dataset, protocol and machine descriptions.
    """

    metrics: dict[str, Any]
    confusion_matrix: torch.Tensor | None
    class_names: tuple[str, ...]
    params: int
    ms_per_frame: float
    peak_memory_mb: float | None
    memory_method: str
    info: dict[str, Any] = field(default_factory=dict)

    def table_row(self) -> dict[str, Any]:
        """The flat dict :func:`~cosemdepth.measures.metrics.format_markdown_table` takes."""
        return {**self.metrics, "params": self.params, "ms_per_frame": self.ms_per_frame}

    def to_dict(self) -> dict[str, Any]:
        m = dict(self.metrics)
        out: dict[str, Any] = {"metrics": {k: v for k, v in m.items() if k != "iou"}}
        if "iou" in m:
            out["per_class_iou"] = dict(zip(self.class_names, m["iou"]))
            out["class_names"] = list(self.class_names)
        if self.confusion_matrix is not None:
            out["confusion_matrix"] = self.confusion_matrix.tolist()
        out["params"] = self.params
        out["speed"] = {"ms_per_frame": self.ms_per_frame, **self.info.get("speed", {})}
        out["peak_memory_mb"] = self.peak_memory_mb
        out["peak_memory_method"] = self.memory_method
        out.update({k: v for k, v in self.info.items() if k != "speed"})
        return out

    def to_json(self) -> str:
        return to_json(self.to_dict())

    def validity_line(self) -> str | None:
        """The depth's validity under the streaming policy: coverage and the metrics of the valid pixels."""
        m, proto = self.metrics, self.info.get("protocol", {})
        policy, counts = proto.get("policy") or {}, proto.get("frames_by_status")
        if "coverage" not in m or not counts:
            return None
        mb = policy.get("min_baseline_m")
        how = f"policy {policy.get('mode')}" + (f", min baseline {mb:.2f} m" if mb else "")
        return (
            f"Validity ({how}): {_fmt(100 * m['coverage'], '.1f')} % of the ground-truth pixels valid; on them "
            f"AbsRel {_fmt(m['valid_abs_rel'], '.4f')}, RMSE {_fmt(m['valid_rmse'], '.3f')}, delta1 "
            f"{_fmt(100 * m['valid_delta1'], '.1f')} %; evaluated frames: "
            + ", ".join(f"{v} {k}" for k, v in counts.items())
            + " (docs/motion.md)"
        )

    def depth_warning(self) -> str | None:
        """Why the run gave no usable depth (every frame a reset, or not one valid pixel), as the commands warn it
        (:func:`~cosemdepth.decoders.depth.task.no_depth_warning`); None when it gave some, or the model has no depth."""
        proto = self.info.get("protocol", {})
        counts = proto.get("frames_by_status")
        if not counts:
            return None
        return no_depth_warning(
            int(proto.get("frames_streamed") or 0),
            int(counts.get(ESTIMATED, 0)),
            int(counts.get(HELD, 0)),
            self.metrics.get("coverage"),
        )

    def flicker_line(self) -> str | None:
        """The labels' temporal consistency (``flicker`` and the other fields of docs/evaluation.md)."""
        m = self.metrics
        if "flicker" not in m:
            return None
        pct = lambda k: _fmt(None if m.get(k) is None else 100 * m[k], ".1f")  # noqa: E731
        return (
            f"Temporal consistency over {m['flicker_pairs']} pairs of consecutive frames: flicker {pct('flicker')} % "
            f"of the pixels whose ground truth does not change (per pair: median {pct('flicker_median')} %, max "
            f"{pct('flicker_max')} %); real changes followed: {pct('change_recall')} % (the ground truth changes "
            f"on {pct('gt_change')} %; docs/evaluation.md)"
        )

    def to_markdown(self, name: str | None = None) -> str:
        """A report: the paper-style tables (with SqRel and both RMSE_log variants), the confusion matrix, settings."""
        info = self.info
        name = name or info.get("model", {}).get("name", "model")
        ds = info.get("dataset", {})
        proto = info.get("protocol", {})
        lines = [f"# Evaluation of {name} on {ds.get('name', '?')} ({ds.get('split', '?')})", ""]
        lines.append(format_markdown_table({name: self.table_row()}, self.class_names or None, extra_columns=True))
        valid = self.validity_line()
        if valid:
            lines += ["", valid]
        flicker = self.flicker_line()
        if flicker:
            lines += ["", flicker]
        for t in TASKS.values():  # the metrics of further decoders (the built-in ones are in the tables above)
            more = t.report_lines(self.metrics)
            if more:
                lines += ["", *more]
        if self.confusion_matrix is not None:
            names = list(self.class_names)
            lines += ["", "Confusion matrix (rows: ground truth, columns: prediction; pixels):", ""]
            lines.append("| GT \\ pred | " + " | ".join(names) + " |")
            lines.append("|---" * (len(names) + 1) + "|")
            for n, row in zip(names, self.confusion_matrix.tolist()):
                lines.append(f"| {n} | " + " | ".join(str(v) for v in row) + " |")
        mach = info.get("machine", {})
        speed = info.get("speed", {})
        lines += [
            "",
            "Settings:",
            "",
            f"- model: {info.get('model', {}).get('path', '?')} ({info.get('model', {}).get('arch', '?')}, "
            f"{self.params:,} parameters)",
            f"- dataset: {ds.get('name')} at {ds.get('root')}, split {ds.get('split')}, "
            f"{'x'.join(str(v) for v in ds.get('size') or ['?'])} px, "
            f"{proto.get('frames_streamed')} frames streamed in {proto.get('trajectories')} trajectories, "
            f"{proto.get('frames_evaluated')} evaluated",
            f"- protocol: each trajectory streamed frame by frame ({proto.get('lanes')} at a time); "
            + (
                "reset frames excluded from all metrics (design 11.3)"
                if proto.get("reset_frames_excluded")
                else "every frame counted for the labels (a dataset of independent images); the depth metrics "
                "only on frames with depth"
            ),
            f"- speed: {_fmt(self.ms_per_frame, '.1f')} ms/frame (model step only, {speed.get('timed_frames')} "
            f"frames after {speed.get('warmup_steps')} warm-up steps) on {mach.get('device')}: {mach.get('cpu')}"
            + (f", {mach.get('gpu')}" if mach.get("gpu") else "")
            + f", {mach.get('torch_threads')} threads, torch {mach.get('torch')}, float32, batch "
            f"{proto.get('lanes')}",
            f"- peak memory: {_fmt(self.peak_memory_mb, '.1f')} MiB ({self.memory_method})",
            f"- date: {info.get('date')}",
            "",
            "RMSE_log is the original's (its mask drops every pixel with ground truth <= 1 m, design 11.1); "
            "RMSE_log (fixed) uses the plain valid mask. Depth metrics are per-frame values averaged over frames; "
            "ground truth is clipped to [0, 80] m and predictions to [0.001, 80] m (design 10.7, 11.1).",
        ]
        return "\n".join(lines) + "\n"


def _fmt(v: Any, spec: str) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return format(v, spec)


class Evaluator:
    """Runs the test protocol; see the module docstring and :func:`evaluate` for the arguments."""

    def __init__(
        self,
        model: StreamingModel,
        dataset,
        *,
        lanes: int = 1,
        max_frames: int | None = None,
        num_workers: int = 0,
        exclude_resets: bool | None = None,
        warmup: int = 2,
        progress: bool = False,
        sinks: Iterable[Sink] = (),
        dataset_name: str | None = None,
        policy=EVERY_FRAME,
        min_baseline: float | None = None,
    ) -> None:
        self.model = model
        self.policy = policy
        self.min_baseline = min_baseline
        self.dataset = dataset
        self.cfg = model_config(model, "evaluate")
        self.lanes = lanes
        self.max_frames = max_frames
        self.num_workers = num_workers
        self.warmup = max(int(warmup), 0)
        self.progress = progress
        self.sinks = list(sinks)
        self.dataset_name = dataset_name or getattr(dataset, "name", None) or ""
        self.groups = trajectory_rows(dataset, max_frames)
        self.schedule = make_schedule(self.groups, lanes)
        if not self.schedule:
            raise ConfigError("evaluate: the dataset has no frame to stream")
        #: the ground-truth keys the dataset has (of every registered task: one decoder's metrics may use another's)
        self.ground_truth = dataset_ground_truth(dataset)
        tasks = tasks_for(self.cfg)
        #: the model's decoders whose ground truth the dataset has: those evaluated, in order
        self.tasks = [t for t in tasks if t.gt_key in self.ground_truth]
        if not self.tasks:
            what = [t.predicts for t in tasks]
            raise ConfigError(
                f"nothing to evaluate: the {self.cfg.arch} model predicts {' and '.join(what)}, and the dataset "
                f"{self.dataset_name!r} has no {' and no '.join(what)} ground truth"
            )
        for t in self.tasks:
            t.check_dataset(self.cfg, self.dataset_name)
        if exclude_resets is None:
            trajs = getattr(dataset, "trajectories", None) or []
            every_reset = bool(trajs) and all(bool(t.reset.all()) for t in trajs)
            exclude_resets = not every_reset
        self.exclude_resets = bool(exclude_resets)

    @property
    def num_frames(self) -> int:
        return sum(len(s.indices) for s in self.schedule)

    def include(self, batch: StreamBatch) -> torch.Tensor:
        """``[B]`` bool: the frames of ``batch`` the metrics count (the test protocol leaves the frames that start a
        trajectory out, unless every frame is a reset: :attr:`exclude_resets`)."""
        return ~batch.reset if self.exclude_resets else torch.ones_like(batch.reset)

    def run(self) -> EvaluationResult:
        context = MetricContext(TEST, self.cfg, self.dataset_name, frozenset(self.ground_truth), self.exclude_resets)
        metrics = {t.name: t.metrics(context) for t in self.tasks}
        streamer = Streamer(self.model, self.policy, min_baseline=self.min_baseline)
        device = next((p.device for p in self.model.parameters()), torch.device("cpu"))
        start = time.perf_counter()
        bar = tqdm(total=self.num_frames, unit="frame", desc="evaluate", disable=not self.progress, leave=False)

        def step_done(batch: StreamBatch, ms: float | None) -> None:
            bar.update(len(batch))
            if ms is not None:
                bar.set_postfix(ms_per_frame=f"{ms:.1f}", refresh=False)

        counts = MetricsSink(metrics, self.include, warmup=self.warmup, steps=len(self.schedule), progress=step_done)
        with PeakMemory(device) as mem:
            pipeline.run(
                DatasetSource(self.dataset),
                streamer,
                [counts, *self.sinks],
                lanes=self.lanes,
                max_frames=self.max_frames,
                num_workers=self.num_workers,
            )
        bar.close()
        timed_seconds, timed_frames = counts.timed_seconds, counts.timed_frames
        frames, evaluated, resets = counts.frames, counts.evaluated, counts.resets
        wall = time.perf_counter() - start
        values: dict[str, Any] = {}
        for m in metrics.values():
            values.update(m.compute())
        reports = {name: m.report() for name, m in metrics.items()}
        for r in reports.values():  # the further metrics (validity, temporal consistency) after every main one
            values.update(r.get("metrics", {}))
        confusion = next((r["confusion_matrix"] for r in reports.values() if "confusion_matrix" in r), None)
        class_names = next((r["class_names"] for r in reports.values() if "class_names" in r), ())
        params = sum(p.numel() for p in self.model.parameters())
        ms = 1000.0 * timed_seconds / timed_frames if timed_frames else math.nan
        ds = self.dataset
        model_info = {"arch": self.cfg.arch, "levels": self.cfg.levels, "num_classes": None}
        for t in tasks_for(self.cfg):
            model_info.update(t.model_info(self.cfg))
        protocol = {
            "lanes": self.lanes,
            "trajectories": len(self.groups),
            "frames_streamed": frames,
            "reset_frames": resets,
            "frames_evaluated": evaluated,
            "reset_frames_excluded": self.exclude_resets,
            **{f"{name}_evaluated": name in metrics for name in TASKS},
            "max_frames": self.max_frames,
            "policy": policy_info(streamer),
        }
        for name, t in TASKS.items():
            protocol.update(t.protocol_info(metrics.get(name)))
        info = {
            "model": model_info,
            "dataset": {"name": self.dataset_name, "size": _dataset_size(ds), "split": None, "root": None},
            "protocol": protocol,
            "speed": {
                "timed_frames": timed_frames,
                "warmup_steps": min(self.warmup, len(self.schedule)),
                "wall_seconds": wall,
            },
            "machine": machine_info(device),
            "date": _dt.datetime.now().astimezone().isoformat(timespec="seconds"),
        }
        info["cosemdepth_version"] = __version__
        return EvaluationResult(
            metrics=values,
            confusion_matrix=confusion,
            class_names=tuple(class_names),
            params=int(params),
            ms_per_frame=ms,
            peak_memory_mb=mem.peak_mb,
            memory_method=mem.method,
            info=info,
        )


def _dataset_size(ds) -> list[int] | None:
    loader = getattr(ds, "load_frame", None)
    size = getattr(loader, "size", None)
    if size is None:
        return None
    return [int(s) for s in size] if isinstance(size, (tuple, list)) else [int(size), int(size)]


def evaluate(model: StreamingModel, dataset, **options: Any) -> EvaluationResult:
    """Evaluate ``model`` on ``dataset`` with the test protocol (see the module docstring).

    The keyword-only options are those of :class:`Evaluator` (one signature, shown as this function's).

    Args:
        model: a model from :func:`cosemdepth.load_model` / :func:`cosemdepth.models.build_model` (eval mode).
        dataset: ``open_dataset(name, root, split=..., seq_len=1, size=...)`` (stream mode, single frames).
        lanes: trajectories streamed at once as one batch, with per-sample resets (1 = the original's batch 1).
        max_frames: evaluate only the first N rows of the split (in order).
        num_workers: DataLoader workers reading frames.
        exclude_resets: leave reset frames out of the metrics (default: yes, unless every frame is a reset); the
            depth metrics leave them out in any case (a reset frame has no depth).
        policy: the streaming policy (:class:`~cosemdepth.inference.StreamPolicy` or ``"every-frame"`` (default,
            the paper's protocol) / ``"baseline"``); min_baseline: its minimum baseline (metres; default: the
            model's); the paper's metrics use every pixel with ground truth, the
            ``valid_*`` metrics and ``coverage`` the pixels the prediction marks valid.
        warmup: streaming steps left out of the timing.
        progress: show a progress bar (tqdm, on stderr).
        sinks: further :class:`~cosemdepth.streaming.frames.Sink` objects fed every streaming step after the
            metrics (writers, baselines; :meth:`Evaluator.include` says which frames the metrics count).
        dataset_name: dataset name for class names/palette and class-count checks (default ``dataset.name``).
    Returns:
        :class:`EvaluationResult`.
    """
    return Evaluator(model, dataset, **options).run()


evaluate.__signature__ = inspect.signature(Evaluator).replace(return_annotation="EvaluationResult")


__all__ = ["ALL_DEPTH_METRICS", "EvaluationResult", "Evaluator", "dataset_modalities", "evaluate", "to_json"]
