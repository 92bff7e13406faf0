"""Run an exported ONNX streaming step with ONNX Runtime over a short sequence and compare it with PyTorch."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..errors import ConfigError


def synthetic_sequence(batch: int, frames: int, height: int, width: int, seed: int = 0):
    """A reproducible test flight: smooth random images, small rotations, ~1 m forward motion, f = W/2.

    Returns ``(rgb [B,T,3,H,W], rot [B,T,4], trans [B,T,3], intrinsics [B,4])`` float32.
    """
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(batch * frames, 3, max(height // 8, 2), max(width // 8, 2), generator=g)
    rgb = torch.nn.functional.interpolate(coarse, size=(height, width), mode="bilinear", align_corners=False)
    rgb = (rgb + 0.05 * torch.rand(rgb.shape, generator=g)).clamp(0, 1).view(batch, frames, 3, height, width)
    q = torch.tensor([1.0, 0.0, 0.0, 0.0]) + 0.01 * torch.randn(batch, frames, 4, generator=g)
    q = torch.nn.functional.normalize(q, dim=-1)
    t = torch.tensor([0.05, -0.02, 1.0]) + 0.1 * torch.randn(batch, frames, 3, generator=g)
    k = torch.tensor([width / 2, height / 2, width / 2, height / 2]).expand(batch, 4).contiguous()
    return rgb, q, t, k


@dataclass
class OnnxComparison:
    """Largest differences ONNX Runtime vs PyTorch per frame: depth relative per pixel, semantic absolute, state
    relative to each state tensor's largest magnitude."""

    depth_rel: list[float] = field(default_factory=list)
    semantic_abs: list[float] = field(default_factory=list)
    state_rel: list[float] = field(default_factory=list)
    depth_tol: float = 1e-3
    semantic_tol: float = 1e-4

    @property
    def ok(self) -> bool:
        return all(d <= self.depth_tol for d in self.depth_rel) and all(
            s <= self.semantic_tol for s in self.semantic_abs
        )

    def summary(self) -> str:
        rows = [f"ONNX Runtime vs PyTorch over {max(len(self.depth_rel), len(self.semantic_abs))} frames:"]
        if self.depth_rel:
            rows.append(f"  depth max relative difference {max(self.depth_rel):.2e} (tolerance {self.depth_tol:g})")
        if self.semantic_abs:
            rows.append(
                f"  semantic max absolute difference {max(self.semantic_abs):.2e} (tolerance {self.semantic_tol:g})"
            )
        rows.append("  OK" if self.ok else "  MISMATCH")
        return "\n".join(rows)


def run_onnx_stream(session, inputs: dict[str, np.ndarray], state: list[np.ndarray]):
    """One call of an exported step; returns ``(outputs by name, next state list)``."""
    names_in = [i.name for i in session.get_inputs()]
    feeds = {k: v for k, v in inputs.items() if k in names_in}  # M4Semantic's graph takes the image only
    reset_in = [i for i in session.get_inputs() if i.name == "reset"]
    if reset_in and reset_in[0].type == "tensor(float)" and "reset" in feeds:
        feeds["reset"] = feeds["reset"].astype(np.float32)
    state_inputs = [n for n in names_in if n.startswith("state_")]
    feeds.update(zip(state_inputs, state))
    names = [o.name for o in session.get_outputs()]
    res = dict(zip(names, session.run(None, feeds)))
    return res, [res["next_" + n] for n in state_inputs]


def compare_onnx(model, path: str | Path, frames: int = 6, reset_at: int | None = None, seed: int = 0):
    """Stream ``frames`` frames (frame 0 and ``reset_at`` reset; default the middle frame) through ONNX Runtime and
    through ``model.step`` (reference path) and return an :class:`OnnxComparison`."""
    try:
        import onnxruntime as ort
    except ImportError as e:  # pragma: no cover - optional dependency
        raise ConfigError("the ONNX check needs onnxruntime (pip install 'cosemdepth[export]')") from e
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    shape = sess.get_inputs()[0].shape
    b, _, h, w = (d if isinstance(d, int) else 1 for d in shape)
    rgb, rot, trans, intr = synthetic_sequence(b, frames, h, w, seed)
    reset = torch.zeros(b, frames, dtype=torch.bool)
    reset[:, 0] = True
    reset[:, frames // 2 if reset_at is None else reset_at] = True
    state_shapes = [[d if isinstance(d, int) else b for d in i.shape] for i in sess.get_inputs() if i.name.startswith("state_")]
    ort_state = [np.zeros(s, np.float32) for s in state_shapes]
    fast_options = model._fast_options
    model.optimize("reference")
    report = OnnxComparison()
    state = None
    try:
        with torch.no_grad():
            for k in range(frames):
                out, state = model.step(rgb[:, k], rot[:, k], trans[:, k], intr, reset[:, k], state)
                feeds = {
                    "rgb": rgb[:, k].numpy(),
                    "rot": rot[:, k].numpy(),
                    "trans": trans[:, k].numpy(),
                    "intrinsics": intr.numpy(),
                    "reset": reset[:, k].numpy(),
                }
                res, ort_state = run_onnx_stream(sess, feeds, ort_state)
                if out.depth is not None:
                    d = out.depth.numpy()
                    report.depth_rel.append(float(np.max(np.abs(res["depth"] - d) / np.maximum(np.abs(d), 1e-6))))
                if out.semantic is not None:
                    report.semantic_abs.append(float(np.max(np.abs(res["semantic"] - out.semantic.numpy()))))
                if state.features:
                    report.state_rel.append(
                        max(
                            float(np.max(np.abs(a - t.numpy())) / max(float(np.max(np.abs(t.numpy()))), 1e-6))
                            for a, t in zip(ort_state, state.flatten())
                        )
                    )
    finally:
        if fast_options is not None:
            model.optimize("fast", **fast_options)
    return report
