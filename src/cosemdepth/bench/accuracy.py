"""Accuracy of the fast inference modes against the fp32 reference path (``cosemdepth fast-accuracy``).

Each mode streams the same split frame by frame (batch 1, the test protocol: reset frames count in no metric) from
a freshly loaded copy of the weights; mIoU and the depth metrics come from
:class:`~cosemdepth.measures.metrics.EvaluationMetrics`. A mode passes when its mIoU is within
:data:`MIOU_TOL_POINTS` points and its AbsRel within :data:`ABSREL_TOL_REL` (relative) of the reference's.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Iterable, Optional, Sequence

import torch

from ..inference.fast_model import FastModel
from ..measures.metrics import EvaluationMetrics
from ..models.protocol import StreamingModel

#: mode -> (path, dtype of the :class:`~cosemdepth.inference.FastModel`); "reference" (the modules) is what the
#: others are compared with
MODES = {
    "reference": ("reference", None),
    "fast-fp32": ("fast", "float32"),
    "fast-bf16": ("fast", "bfloat16"),
    "fast-fp16": ("fast", "float16"),
    "fast-int8": ("fast", "int8"),
    "onnx-fp32": ("onnx", "float32"),
    "onnx-int8": ("onnx", "int8"),
}
#: the modes that calibrate on the calibration frames
CALIBRATED = ("fast-int8", "onnx-int8")
#: the fast modes a run compares by default
DEFAULT_MODES = ("fast-fp32", "fast-bf16")
#: a fast mode's mIoU may differ from the reference's by this many points (percent)
MIOU_TOL_POINTS = 0.5
#: a fast mode's AbsRel may differ from the reference's by this fraction of it
ABSREL_TOL_REL = 0.01
#: int8: frames of the calibration split whose activation ranges calibrate the quantisation
CALIBRATION_FRAMES = 16
#: the metrics printed per mode
SHOWN = ("miou", "abs_rel", "rmse", "delta1", "seconds")


def stream_metrics(model: StreamingModel, dataset, device: torch.device, max_frames: Optional[int] = None) -> dict:
    """The metrics of ``model`` streamed over ``dataset`` (batch 1, frames in order; reset frames left out), with
    ``frames`` (streamed) and ``seconds`` (wall time)."""
    cfg = model.config
    metrics = EvaluationMetrics(cfg.num_classes if cfg.has_semantic else None, depth=cfg.has_depth)
    state = None
    n = len(dataset) if max_frames is None else min(len(dataset), max_frames)
    t0 = time.perf_counter()
    with torch.inference_mode():
        for i in range(n):
            item = dataset[i]
            reset = item["reset"][:1].to(device)
            out, state = model.step(
                item["rgb"][:1].to(device),
                item["rot"][:1].to(device),
                item["trans"][:1].to(device),
                item["intrinsics"].view(1, 4).to(device),
                reset,
                state,
            )
            metrics.update(
                gt_depth=item["depth"][:1] if cfg.has_depth else None,
                pred_depth=out.depth.float().cpu() if cfg.has_depth else None,
                gt_labels=item["semantic"][:1] if cfg.has_semantic else None,
                pred_semantic=out.semantic.float().cpu() if cfg.has_semantic else None,
                include=~reset.cpu(),
            )
    res = metrics.compute()
    res["frames"] = n
    res["seconds"] = round(time.perf_counter() - t0, 1)
    return res


def calibration_frames(dataset, frames: int) -> list[tuple]:
    """The first ``frames`` frames of ``dataset`` as ``(rgb, rot, trans, intrinsics, reset)`` steps of batch 1, the
    first one a reset (what ``FastModel(model, dtype="int8", calibration=...)`` takes)."""
    out = []
    for i in range(min(len(dataset), frames)):
        it = dataset[i]
        out.append(
            (it["rgb"][:1], it["rot"][:1], it["trans"][:1], it["intrinsics"].view(1, 4), it["reset"][:1] | (i == 0))
        )
    return out


def verdict(mode: dict, reference: dict) -> dict:
    """How far ``mode``'s metrics are from ``reference``'s, and whether within the tolerances: ``miou_diff_points``
    and ``miou_ok`` (when there is mIoU), ``abs_rel_rel_diff`` and ``abs_rel_ok`` (when there is depth), ``ok``."""
    v: dict = {}
    if "miou" in reference:
        v["miou_diff_points"] = 100 * (mode["miou"] - reference["miou"])
        v["miou_ok"] = abs(v["miou_diff_points"]) <= MIOU_TOL_POINTS
    if "abs_rel" in reference:
        v["abs_rel_rel_diff"] = (mode["abs_rel"] - reference["abs_rel"]) / reference["abs_rel"]
        v["abs_rel_ok"] = abs(v["abs_rel_rel_diff"]) <= ABSREL_TOL_REL
    v["ok"] = all(x for k, x in v.items() if k.endswith("_ok"))
    return v


def compare_modes(
    load,
    dataset,
    modes: Sequence[str],
    device: torch.device,
    max_frames: Optional[int] = None,
    calibration: Optional[list] = None,
    report=print,
) -> dict:
    """``{"metrics": {mode: metrics}, "verdicts": {mode: verdict}}`` for the reference and every mode of ``modes``;
    ``load()`` returns a fresh copy of the :class:`~cosemdepth.models.SceneModel` for each mode; ``calibration``
    (int8) the steps of :func:`calibration_frames`."""
    unknown = [m for m in modes if m not in MODES or m == "reference"]
    if unknown:
        raise ValueError(f"unknown fast modes {unknown}: choose from {[m for m in MODES if m != 'reference']}")
    results = {}
    for name in ["reference", *modes]:
        path, dtype = MODES[name]
        model = load()
        with tempfile.TemporaryDirectory(prefix="cosemdepth-accuracy-") as work:
            if path == "fast":
                model = FastModel(model, dtype, **({"calibration": calibration} if dtype == "int8" else {}))
            elif path == "onnx":
                model = onnx_model(model, dataset, Path(work), calibration if dtype == "int8" else None)
            results[name] = stream_metrics(model, dataset, device, max_frames)
        report(name, {k: v for k, v in results[name].items() if k in SHOWN})
    verdicts = {name: verdict(results[name], results["reference"]) for name in modes}
    for name, v in verdicts.items():
        report(name, v)
    return {"metrics": results, "verdicts": verdicts}


def onnx_model(model: StreamingModel, dataset, work: Path, calibration: Optional[list] = None):
    """``model`` exported as by ``cosemdepth export --onnx`` at the size of ``dataset``'s frames (batch 1) into
    ``work``, int8 as by ``--int8`` when ``calibration`` steps are given, run by ONNX Runtime's CPU provider behind
    the model's ``step`` (:class:`~cosemdepth.export.runtime.OnnxModel`)."""
    from ..export.onnx import export_onnx  # deferred: optional (onnx, onnxruntime)
    from ..export.quantize import quantize_onnx
    from ..export.runtime import OnnxModel, OnnxStep

    h, w = (int(x) for x in dataset[0]["rgb"].shape[-2:])
    graph = export_onnx(model, work / "float32.onnx", h, w)
    if calibration is not None:
        graph = quantize_onnx(model, graph, work / "int8.onnx", calibration)
    return OnnxModel(model, OnnxStep(graph, threads=torch.get_num_threads()))


def all_ok(verdicts: Iterable[dict]) -> bool:
    return all(v["ok"] for v in verdicts)


__all__ = [
    "ABSREL_TOL_REL",
    "CALIBRATED",
    "CALIBRATION_FRAMES",
    "DEFAULT_MODES",
    "MIOU_TOL_POINTS",
    "MODES",
    "all_ok",
    "calibration_frames",
    "compare_modes",
    "onnx_model",
    "stream_metrics",
    "verdict",
]
