"""Run an exported ONNX streaming step with ONNX Runtime over a short flight and compare it with PyTorch.

What ``cosemdepth export --check`` runs (the derivation is in ``docs/deploy.md``, "What --check compares"):

* **meaningful inputs**: a short SynthAir flight rendered on the fly (:func:`flight_sequence`: a real terrain, a
  plausible motion, frames 0.16 s apart, a reset in the middle), not noise images with random poses, on which the
  recurrent depth is chaotic (PyTorch float32 vs float64 alone differ by 1e-2 there);
* **like with like**: every frame, PyTorch runs the step on the *same* inputs as ONNX Runtime, the incoming state
  included (ONNX Runtime's own state, fed back), so that rounding differences are not compounded through the
  recurrence; the outgoing states are compared too;
* **a derived tolerance**: differences are normalised RMS differences ``||a - b|| / ||b||`` (per frame, per output).
  Two float32 implementations of the same graph differ by their summation orders. The two measured on the same
  inputs against a float64 copy of the model are PyTorch's own (``e``) and the same model with the long reductions of
  the graph (DINL's means over H x W terms) summed the way vectorised runtimes sum them, in ``SUMMATION_LANES``
  sequential chains (``s``, :func:`sequential_spatial_mean`), whose rounding grows with the number of terms
  (measured: these reductions are what separates ONNX Runtime from PyTorch at 384 px, see docs/deploy.md). A runtime
  no further from the exact result than ``s`` lies within ``e + s`` of PyTorch (triangle inequality): tolerance =
  ``max(e) + max(s)`` over the frames, at least ``2^-24``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..data.midair.splits import GT_PER_ROW, relative_motions
from ..data.synthair.climate import get_climate
from ..data.synthair.render import render_frames
from ..data.synthair.world import get_world
from ..data.synthair.writer import SynthConfig, plan_flights
from ..errors import ConfigError
from ..models.outputs import StreamState


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


#: Float32 rounding unit (2^-24): the smallest tolerance, for outputs that PyTorch computes exactly (a reset frame).
FLOAT32_UNIT = 2.0**-24


def flight_sequence(batch: int, frames: int, height: int, width: int, seed: int = 0):
    """A short SynthAir flight rendered on the fly: world ``seed``, one trajectory (road mode), camera frames 4
    apart (6.25 Hz, as the split CSVs), images at ``height x width``, motions from the ground truth (the CSV
    convention), f = W/2. The same flight in every batch sample.

    Returns ``(rgb [B,T,3,H,W], rot [B,T,4], trans [B,T,3], intrinsics [B,4])`` float32; frame 0's motion is the
    identity (it is a reset).
    """
    world = get_world(seed)
    cfg = SynthConfig(out=Path("unused"), trajectories=1, frames=4 * frames + 8, size=max(height, width, 16),
                      seed=seed, climates=("sunny",))
    planned = plan_flights(cfg, world)["sunny"][0]
    att, pos = planned.flight.attitude, planned.flight.position
    stride = GT_PER_ROW  # ground-truth samples between two CSV rows (100 Hz, every 4th 25 Hz frame)
    shots = render_frames(world, get_climate("sunny").with_sun_azimuth(planned.sun_azimuth),
                          att[0 : stride * frames : stride], pos[0 : stride * frames : stride], height, width)
    q, t = relative_motions(att[: stride * frames + stride], pos[: stride * frames + stride])
    rgb = torch.from_numpy(np.stack([f.rgb for f in shots])).permute(0, 3, 1, 2).float().div(255)
    rot = torch.from_numpy(np.concatenate([[[1.0, 0.0, 0.0, 0.0]], q[: frames - 1]])).float()
    trans = torch.from_numpy(np.concatenate([[[0.0, 0.0, 0.0]], t[: frames - 1]])).float()
    k = torch.tensor([width / 2, height / 2, width / 2, height / 2]).expand(batch, 4).contiguous()
    expand = lambda x: x.unsqueeze(0).expand(batch, *x.shape).contiguous()  # noqa: E731
    return expand(rgb), expand(rot), expand(trans), k


#: Lanes of the sequential summation that :func:`sequential_spatial_mean` models: the float32 lanes of a 128-bit SIMD
#: register (SSE, NEON), the narrowest vector unit a runtime's reduction kernel uses. Measured: ONNX Runtime 1.31's
#: ReduceMean on this x86 CPU sums in 8 lanes (AVX2; its means equal the 8-lane model bit for bit on half the
#: channels); wider units (AVX-512: 16) make shorter chains and smaller errors.
SUMMATION_LANES = 4


def sequential_spatial_mean(x: torch.Tensor, lanes: int = SUMMATION_LANES) -> torch.Tensor:
    """Per-image, per-channel mean over H x W (``[B,C,H,W] -> [B,C,1,1]``) as a vectorised runtime sums it, in the
    tensor's dtype: ``lanes`` accumulators, accumulator ``j`` adds terms ``j, j + lanes, ...`` one after the other,
    then the accumulators are added in order and the sum divided by H x W. Its rounding grows with the length of the
    chains (``H W / lanes``), unlike PyTorch's pairwise sums (logarithmic). ``lanes = 1`` is the textbook loop."""
    b, c, h, w = x.shape
    n = h * w
    flat = x.detach().cpu().reshape(b * c, n).numpy()
    pad = (-n) % lanes
    if pad:  # zeros add exactly
        flat = np.concatenate([flat, np.zeros((b * c, pad), flat.dtype)], axis=1)
    chains = np.cumsum(flat.reshape(b * c, -1, lanes), axis=1, dtype=flat.dtype)[:, -1, :]
    total = chains[:, 0].copy()
    for j in range(1, lanes):
        total += chains[:, j]
    mean = torch.from_numpy(total / flat.dtype.type(n)).to(x.device, x.dtype)
    return mean.view(b, c, 1, 1)


def nrms(a, b) -> float:
    """Normalised RMS difference ``||a - b|| / ||b||`` (float64; 0 when both are 0)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    den = float(np.linalg.norm(b))
    num = float(np.linalg.norm(a - b))
    return num / den if den > 0 else num


@dataclass
class OnnxComparison:
    """Per frame, as normalised RMS differences, for depth, semantic probabilities and the outgoing state (the worst
    tensor): ONNX Runtime vs PyTorch float32 (``*_rel``), PyTorch float32 vs float64 (``*_e``) and PyTorch float32
    with DINL's means summed in ``SUMMATION_LANES`` sequential chains vs float64 (``*_s``). ``depth_max_rel`` is the largest per-pixel relative depth
    difference, for information only (ill-conditioned where the predicted depth is near 0)."""

    depth_rel: list[float] = field(default_factory=list)
    semantic_rel: list[float] = field(default_factory=list)
    state_rel: list[float] = field(default_factory=list)
    depth_e: list[float] = field(default_factory=list)
    semantic_e: list[float] = field(default_factory=list)
    state_e: list[float] = field(default_factory=list)
    depth_s: list[float] = field(default_factory=list)
    semantic_s: list[float] = field(default_factory=list)
    state_s: list[float] = field(default_factory=list)
    depth_max_rel: list[float] = field(default_factory=list)

    @staticmethod
    def _tol(es: list[float], ss: list[float]) -> float:
        return max(max(es, default=0.0) + max(ss, default=0.0), FLOAT32_UNIT)

    @property
    def depth_tol(self) -> float:
        """``max(e) + max(s)`` over the frames, at least 2^-24 (see the module docstring and docs/deploy.md)."""
        return self._tol(self.depth_e, self.depth_s)

    @property
    def semantic_tol(self) -> float:
        return self._tol(self.semantic_e, self.semantic_s)

    @property
    def state_tol(self) -> float:
        return self._tol(self.state_e, self.state_s)

    def _pairs(self):
        return [("depth", self.depth_rel, self.depth_e, self.depth_s, self.depth_tol),
                ("semantic", self.semantic_rel, self.semantic_e, self.semantic_s, self.semantic_tol),
                ("state", self.state_rel, self.state_e, self.state_s, self.state_tol)]

    @property
    def ok(self) -> bool:
        return all(d <= tol for _, ds, _, _, tol in self._pairs() for d in ds)

    def summary(self) -> str:
        n = max(len(self.depth_rel), len(self.semantic_rel))
        rows = [f"ONNX Runtime vs PyTorch, step by step on {n} frames of a SynthAir flight (normalised RMS "
                "difference; tolerance = e + s, the float32 rounding of PyTorch (e) and of the normalisation means "
                f"summed in {SUMMATION_LANES} sequential chains (s), each measured against float64 on the same frames):"]
        for name, ds, es, ss, tol in self._pairs():
            if not ds:
                continue
            bad = sum(d > tol for d in ds)
            rows.append(f"  {name:8s} max difference {max(ds):.2e}, tolerance {tol:.2e} (e {max(es):.2e}, "
                        f"s {max(ss):.2e})" + (f": {bad} frame(s) over" if bad else ""))
        if self.depth_max_rel:
            rows.append(f"  (largest per-pixel relative depth difference {max(self.depth_max_rel):.2e}, information)")
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


def compare_onnx(model, path: str | Path, frames: int = 6, reset_at: int | None = None, seed: int = 0,
                 inputs=None) -> OnnxComparison:
    """Stream ``frames`` frames (frame 0 and ``reset_at`` reset; default the middle frame) of a SynthAir flight
    (:func:`flight_sequence`, or ``inputs = (rgb, rot, trans, intrinsics)``) through ONNX Runtime and, step by step on
    the same inputs and incoming state, through ``model.step`` (reference path) in float32 and in float64; returns
    an :class:`OnnxComparison` (see the module docstring)."""
    try:
        import onnxruntime as ort  # deferred: an optional dependency (cosemdepth[export])
    except ImportError as e:  # pragma: no cover - optional dependency
        raise ConfigError("the ONNX check needs onnxruntime (pip install 'cosemdepth[export]')") from e
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    shape = sess.get_inputs()[0].shape
    b, _, h, w = (d if isinstance(d, int) else 1 for d in shape)
    rgb, rot, trans, intr = inputs if inputs is not None else flight_sequence(b, frames, h, w, seed)
    frames = rgb.shape[1]
    reset = torch.zeros(b, frames, dtype=torch.bool)
    reset[:, 0] = True
    reset[:, frames // 2 if reset_at is None else reset_at] = True
    state_shapes = [[d if isinstance(d, int) else b for d in i.shape] for i in sess.get_inputs() if i.name.startswith("state_")]
    ort_state = [np.zeros(s, np.float32) for s in state_shapes]
    mode, options = model.inference_mode, model.inference_options
    model.optimize("reference")
    p = next(model.parameters())
    m64 = copy.deepcopy(model).to(device="cpu", dtype=torch.float64)
    mseq = copy.deepcopy(model)
    if getattr(mseq.encoder, "dinl", None) is not None:
        mseq.encoder.dinl.spatial_mean = sequential_spatial_mean
    report = OnnxComparison()
    try:
        with torch.no_grad():
            for k in range(frames):
                feeds = {"rgb": rgb[:, k].numpy(), "rot": rot[:, k].numpy(), "trans": trans[:, k].numpy(),
                         "intrinsics": intr.numpy(), "reset": reset[:, k].numpy()}
                st_in = [torch.from_numpy(s) for s in ort_state]
                res, ort_state = run_onnx_stream(sess, feeds, ort_state)
                args = (rgb[:, k], rot[:, k], trans[:, k], intr)
                st32 = StreamState.unflatten([s.to(p.device) for s in st_in]) if st_in and k > 0 else None
                out, new = model.step(*(a.to(p.device) for a in args), reset[:, k].to(p.device), st32)
                st64 = StreamState.unflatten([s.double() for s in st_in]) if st_in and k > 0 else None
                out64, new64 = m64.step(*(a.double() for a in args), reset[:, k], st64)
                outs, news = mseq.step(*(a.to(p.device) for a in args), reset[:, k].to(p.device), st32)
                if out.depth is not None:
                    d, d64 = out.depth.cpu().numpy(), out64.depth.numpy()
                    report.depth_rel.append(nrms(res["depth"], d))
                    report.depth_e.append(nrms(d, d64))
                    report.depth_s.append(nrms(outs.depth.cpu().numpy(), d64))
                    report.depth_max_rel.append(
                        float(np.max(np.abs(res["depth"] - d) / np.maximum(np.abs(d), 1e-6))))
                if out.semantic is not None:
                    sem, sem64 = out.semantic.cpu().numpy(), out64.semantic.numpy()
                    report.semantic_rel.append(nrms(res["semantic"], sem))
                    report.semantic_e.append(nrms(sem, sem64))
                    report.semantic_s.append(nrms(outs.semantic.cpu().numpy(), sem64))
                if new.features:
                    pairs = list(zip(ort_state, new.flatten(), new64.flatten()))
                    report.state_rel.append(max(nrms(a, t.cpu().numpy()) for a, t, _ in pairs))
                    report.state_e.append(max(nrms(t.cpu().numpy(), t64.numpy()) for _, t, t64 in pairs))
                    report.state_s.append(max(nrms(t.cpu().numpy(), t64.numpy())
                                              for t, t64 in zip(news.flatten(), new64.flatten())))
    finally:
        model.optimize(mode, **(options or {}))
    return report
