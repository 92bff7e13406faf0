"""Compare a model with reference outputs of the authors' TensorFlow implementation (the ``tfref-*`` fixtures).

A fixture folder holds ``ckpt/`` (a TF checkpoint) and ``reference.npz`` (NHWC arrays with leading ``[frame, batch]``
axes): inputs ``rgb``, ``rot``, ``trans``, ``new_traj``, ``camera_f``, ``camera_c``; streaming outputs ``infer_depth``,
``infer_semantic`` and ``infer_lvl{l}_{depth,parallax,depth_other,semantic,semantic_other}``; training-mode outputs
``train_lvl{l}_*``; encoder features ``feat_lvl{l}``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..inference.fast_model import reference_model
from ..models.protocol import StreamingModel

#: our level-map name -> fixture suffix
LEVEL_KEYS = {
    "depth": "depth",
    "parallax": "parallax",
    "depth_other": "depth_other",
    "semantic": "semantic",
    "semantic_other": "semantic_other",
}


def _nchw(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a)).permute(0, 3, 1, 2)


def _nhwc(t: torch.Tensor) -> np.ndarray:
    return t.detach().permute(0, 2, 3, 1).cpu().numpy()


def relative_error_stats(got: np.ndarray, ref: np.ndarray) -> dict[str, float]:
    """Median, 99th percentile and max of ``|got - ref| / max(|ref|, 1e-6)``."""
    e = (np.abs(got.astype(np.float64) - ref) / np.maximum(np.abs(ref), 1e-6)).ravel()
    return {"median": float(np.median(e)), "p99": float(np.percentile(e, 99)), "max": float(e.max())}


def abs_error(got: np.ndarray, ref: np.ndarray) -> float:
    return float(np.abs(got.astype(np.float64) - ref).max())


def inputs_from_reference(ref: Any) -> dict[str, torch.Tensor]:
    """Per-frame model inputs from a reference npz: lists over frames of [B,...] tensors."""
    f, c = ref["camera_f"], ref["camera_c"]
    b = ref["rgb"].shape[1]
    intr = torch.from_numpy(np.concatenate([f, c], axis=-1).astype(np.float32)).expand(b, 4).contiguous()
    n = ref["rgb"].shape[0]
    return {
        "rgb": [_nchw(ref["rgb"][t]) for t in range(n)],
        "rot": [torch.from_numpy(ref["rot"][t]) for t in range(n)],
        "trans": [torch.from_numpy(ref["trans"][t]) for t in range(n)],
        "reset": [torch.from_numpy(np.asarray(ref["new_traj"][t]).astype(bool)) for t in range(n)],
        "intrinsics": intr,
    }


@torch.no_grad()
def compare_with_reference(model: StreamingModel, fixture: str | Path) -> dict[str, Any]:
    """Run ``model`` on a fixture's inputs (streaming, training mode, encoder) and compare every output; a
    :class:`~cosemdepth.inference.FastModel` streams on the fast path, its model's modules run the training mode.

    Returns a nested dict: ``streaming`` / ``training`` -> frame -> key -> stats (relative stats for depth and
    parallax, max abs error for the others), ``features`` -> frame -> level -> max abs error.
    """
    ref = np.load(Path(fixture) / "reference.npz")
    inp = inputs_from_reference(ref)
    n = len(inp["rgb"])
    levels = model.config.levels
    report: dict[str, Any] = {"streaming": [], "training": [], "features": []}

    def level_report(get_level, prefix: str, t: int) -> dict[str, Any]:
        out = {}
        for l in range(1, levels + 1):
            for ours, theirs in LEVEL_KEYS.items():
                key = f"{prefix}_lvl{l}_{theirs}"
                got = get_level(ours, l - 1)
                if key not in ref.files or got is None:
                    continue
                g = _nhwc(got)
                if ours in ("depth", "parallax"):
                    out[f"lvl{l}_{ours}"] = relative_error_stats(g, ref[key][t])
                else:
                    out[f"lvl{l}_{ours}"] = {"max_abs": abs_error(g, ref[key][t])}
        return out

    state = None
    for t in range(n):
        o, state = model.step(inp["rgb"][t], inp["rot"][t], inp["trans"][t], inp["intrinsics"], inp["reset"][t], state)
        frame = level_report(lambda k, j: o.levels[k][j] if k in o.levels else None, "infer", t)
        if o.depth is not None and "infer_depth" in ref.files:
            frame["depth"] = relative_error_stats(_nhwc(o.depth), ref["infer_depth"][t])
        if o.semantic is not None and "infer_semantic" in ref.files:
            frame["semantic"] = {"max_abs": abs_error(_nhwc(o.semantic), ref["infer_semantic"][t])}
        report["streaming"].append(frame)

    seq = reference_model(model).forward_sequence(
        torch.stack(inp["rgb"], 1),
        torch.stack(inp["rot"], 1),
        torch.stack(inp["trans"], 1),
        inp["intrinsics"],
        torch.stack(inp["reset"], 1),
    )
    seq_maps = {k: seq.levels.get(k, []) for k in ("depth", "parallax", "depth_other", "semantic", "semantic_other")}
    for t in range(n):
        report["training"].append(level_report(lambda k, j: seq_maps[k][j][:, t] if seq_maps[k] else None, "train", t))
        feats = {}
        for l in range(1, levels + 1):
            if f"feat_lvl{l}" in ref.files:
                feats[f"lvl{l}"] = abs_error(_nhwc(seq.features[l - 1][:, t]), ref[f"feat_lvl{l}"][t])
        report["features"].append(feats)
    return report
