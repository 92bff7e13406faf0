"""Run an exported ONNX streaming step with ONNX Runtime over a short flight and compare it with PyTorch.

What ``cosemdepth export --check`` runs (measurements and reasons in ``docs/deploy.md``, "What --check compares"):

* **meaningful inputs**: a short SynthAir flight rendered on the fly (:func:`flight_sequence`: a real terrain, a
  plausible motion, frames 0.16 s apart, a reset in the middle), not noise images with random poses, on which the
  recurrent depth is chaotic;
* **like with like**: every frame, PyTorch runs the step on the *same* inputs as ONNX Runtime, the incoming state
  included (ONNX Runtime's own state, fed back), so that rounding differences are not compounded through the
  recurrence; the outgoing states are compared too;
* **a measured noise floor**: the reference is the PyTorch reference path in float32. The same steps are run a second
  time in PyTorch float32, differing from the reference only in the order of the floating-point operations
  (:func:`noise_model`: channels-last convolutions, which oneDNN computes with other kernels, and DINL's two means
  over H x W summed in ``SUMMATION_LANES`` sequential chains as vectorised runtimes sum them). Its distance to the
  reference is how far two correct float32 implementations drift apart on these frames; ONNX Runtime's distance to
  the reference, with the same metric on the same frames, must stay within ``NOISE_MULTIPLE`` times the largest
  noise distance over the frames, and below ``ABSOLUTE_FLOOR`` where the two PyTorch runs agree exactly
  (:func:`acceptance_limit`). Metrics (:data:`CRITERIA`): normalised RMS differences of depth, semantic
  probabilities and the outgoing state (worst tensor), and a high percentile of the per-pixel relative depth
  difference over the valid pixels (:func:`relative_percentile`).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..data.midair.splits import GT_PER_ROW, relative_motions
from ..errors import ConfigError
from ..inference.fast_model import reference_model
from ..models.model import SceneModel
from ..models.outputs import StreamState
from ..models.protocol import StreamingModel
from ..synthair.climate import get_climate
from ..synthair.render import render_frames
from ..synthair.world import get_world
from ..synthair.writer import SynthConfig, plan_flights
from .onnx import state_components
from .provenance import check_model, read_provenance


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


def flight_sequence(batch: int, frames: int, height: int, width: int, seed: int = 0):
    """A short SynthAir flight rendered on the fly: world ``seed``, one trajectory (road mode), camera frames 4
    apart (6.25 Hz, as the split CSVs), images at ``height x width``, motions from the ground truth (the CSV
    convention), f = W/2. The same flight in every batch sample.

    Returns ``(rgb [B,T,3,H,W], rot [B,T,4], trans [B,T,3], intrinsics [B,4])`` float32; frame 0's motion is the
    identity (it is a reset).
    """
    world = get_world(seed)
    cfg = SynthConfig(
        out=Path("unused"),
        trajectories=1,
        frames=4 * frames + 8,
        size=max(height, width, 16),
        seed=seed,
        climates=("sunny",),
    )
    planned = plan_flights(cfg, world)["sunny"][0]
    att, pos = planned.flight.attitude, planned.flight.position
    stride = GT_PER_ROW  # ground-truth samples between two CSV rows (100 Hz, every 4th 25 Hz frame)
    shots = render_frames(
        world,
        get_climate("sunny").with_sun_azimuth(planned.sun_azimuth),
        att[0 : stride * frames : stride],
        pos[0 : stride * frames : stride],
        height,
        width,
    )
    q, t = relative_motions(att[: stride * frames + stride], pos[: stride * frames + stride])
    rgb = torch.from_numpy(np.stack([f.rgb for f in shots])).permute(0, 3, 1, 2).float().div(255)
    rot = torch.from_numpy(np.concatenate([[[1.0, 0.0, 0.0, 0.0]], q[: frames - 1]])).float()
    trans = torch.from_numpy(np.concatenate([[[0.0, 0.0, 0.0]], t[: frames - 1]])).float()
    k = torch.tensor([width / 2, height / 2, width / 2, height / 2]).expand(batch, 4).contiguous()
    expand = lambda x: x.unsqueeze(0).expand(batch, *x.shape).contiguous()  # noqa: E731
    return expand(rgb), expand(rot), expand(trans), k


#: Lanes of the sequential summation that :func:`sequential_spatial_mean` models and the noise run uses: the float32
#: lanes of a 128-bit SIMD register (SSE, NEON), the narrowest vector unit a runtime's reduction kernel uses, so the
#: longest chains; runtimes with wider units (AVX2: 8 lanes, AVX-512: 16) make shorter chains.
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


#: Frames ``cosemdepth export --check`` streams (resets at frame 0 and in the middle).
CHECK_FRAMES = 6
#: ONNX Runtime may be this many times further from the reference than the noise run (the largest over the frames),
#: per output and metric: the size of a rounding difference after the model's ill-conditioned layers depends on its
#: direction, not only on its size, so two correct runs land at different distances on different frames.
NOISE_MULTIPLE = 4.0
#: The smallest limit (16 float32 rounding units, relative): where the two PyTorch runs agree exactly (the constant
#: depth of a reset frame) ONNX Runtime may still differ by rounding.
ABSOLUTE_FLOOR = 2.0**-20
#: Percentile of the per-pixel relative depth difference (robust to the few pixels where the depth is ill-conditioned).
DEPTH_PERCENTILE = 99.0


def nrms(a, b) -> float:
    """Normalised RMS difference ``||a - b|| / ||b||`` (float64; 0 when both are 0, ``inf`` when ``a`` holds a
    non-finite value where ``b`` is finite)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if not np.all(np.isfinite(a) | ~np.isfinite(b)):
        return math.inf
    den = float(np.linalg.norm(b))
    num = float(np.linalg.norm(a - b))
    return num / den if den > 0 else num


def relative_percentile(a, b, valid, q: float = DEPTH_PERCENTILE) -> float | None:
    """The ``q``-th percentile of ``|a - b| / |b|`` over the pixels where ``valid`` is True (``a``, ``b``, ``valid``
    of one shape); a pixel where ``a`` is not finite counts as ``inf``. None when no pixel is valid."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    valid = np.asarray(valid, bool)
    if not valid.any():
        return None
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.abs(a[valid] - b[valid]) / np.abs(b[valid])
    r[~np.isfinite(r)] = math.inf
    return float(np.percentile(r, q, method="higher"))


def valid_depth(depth, reset) -> np.ndarray:
    """The pixels a per-pixel depth comparison reads: finite, positive reference depth (``depth [B,1,H,W]``) of the
    samples that do not reset (``reset [B]``: their depth is the constant of a fresh start)."""
    depth = np.asarray(depth)
    keep = ~np.asarray(reset, bool).reshape(-1, *([1] * (depth.ndim - 1)))
    return np.isfinite(depth) & (depth > 0) & keep


def acceptance_limit(noise, multiple: float = NOISE_MULTIPLE, absolute: float = ABSOLUTE_FLOOR) -> float:
    """The largest distance to the reference that ONNX Runtime may have: ``multiple`` times the largest distance of
    the noise run over the frames, at least ``absolute``. NaN (never accepted) if the noise run has a NaN."""
    noise = [float(x) for x in noise]
    if any(math.isnan(x) for x in noise):
        return math.nan
    return max(multiple * max(noise, default=0.0), absolute)


#: ``(output, metric)`` pairs the check compares, in the order of its report; ``metric`` names what is measured.
CRITERIA = (
    ("depth", "normalised RMS"),
    ("depth", f"p{DEPTH_PERCENTILE:g} relative, valid pixels"),
    ("semantic", "normalised RMS"),
    ("state", "normalised RMS, worst tensor"),
)


@dataclass
class Criterion:
    """One output and metric: per compared frame (``frames``, the indices in the flight), ONNX Runtime's distance to
    the PyTorch reference (``onnx``) and the noise run's (``noise``), with the same metric."""

    output: str
    metric: str
    frames: list[int] = field(default_factory=list)
    onnx: list[float] = field(default_factory=list)
    noise: list[float] = field(default_factory=list)
    multiple: float = NOISE_MULTIPLE
    absolute: float = ABSOLUTE_FLOOR

    def add(self, frame: int, onnx: float | None, noise: float | None) -> None:
        """Record one frame (nothing when the metric has nothing to compare there: ``None``)."""
        if onnx is None or noise is None:
            return
        self.frames.append(frame)
        self.onnx.append(float(onnx))
        self.noise.append(float(noise))

    @property
    def floor(self) -> float:
        """The largest distance of the noise run over the frames."""
        return max(self.noise, default=0.0)

    @property
    def limit(self) -> float:
        return acceptance_limit(self.noise, self.multiple, self.absolute)

    @property
    def worst(self) -> float:
        return max(self.onnx, default=0.0) if not any(math.isnan(x) for x in self.onnx) else math.nan

    @property
    def over(self) -> list[int]:
        """The frames where ONNX Runtime is not within the limit (a NaN distance is never within it)."""
        lim = self.limit
        return [f for f, d in zip(self.frames, self.onnx) if not d <= lim]

    @property
    def ok(self) -> bool:
        return not self.over


def _frame_list(frames: list[int]) -> str:
    if frames and frames == list(range(frames[0], frames[-1] + 1)) and len(frames) > 2:
        return f"{frames[0]}-{frames[-1]}"
    return ",".join(map(str, frames)) or "-"


@dataclass
class OnnxComparison:
    """What :func:`compare_onnx` measured: the flight (``size`` H x W, ``batch``, ``frames``, the reset frames),
    one :class:`Criterion` per entry of :data:`CRITERIA` that the model has, and for information the largest
    per-pixel relative depth difference of ONNX Runtime and of the noise run (ill-conditioned at single pixels)."""

    size: tuple[int, int] = (0, 0)
    batch: int = 1
    frames: int = 0
    resets: list[int] = field(default_factory=list)
    criteria: list[Criterion] = field(default_factory=list)
    depth_max_rel: list[float] = field(default_factory=list)
    depth_max_rel_noise: list[float] = field(default_factory=list)

    def criterion(self, output: str, metric: str | None = None) -> Criterion:
        """The criterion of ``output`` (the first one when ``metric`` is None)."""
        for c in self.criteria:
            if c.output == output and (metric is None or c.metric == metric):
                return c
        raise KeyError((output, metric))

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.criteria)

    def summary(self) -> str:
        h, w = self.size
        mult = self.criteria[0].multiple if self.criteria else NOISE_MULTIPLE
        rows = [
            f"ONNX Runtime vs PyTorch float32 (reference path): {self.frames} frames of a SynthAir flight at {h}x{w}, "
            f"batch {self.batch}, resets at frames {_frame_list(self.resets)}; each step on ONNX Runtime's incoming "
            "state.",
            "Noise floor: the same steps in PyTorch float32 differing only in rounding (channels-last convolutions, "
            f"DINL's means over H x W summed in {SUMMATION_LANES} sequential chains), its largest distance to the "
            f"reference over the frames; ONNX Runtime is accepted within {mult:g} x that floor (at least "
            f"{ABSOLUTE_FLOOR:.1e}) on every frame.",
            f"  {'output':8s}  {'metric':34s}  {'frames':7s}  {'floor':>8s}  {'ONNX':>8s}  {'ratio':>6s}  "
            f"{'limit':>8s}",
        ]
        for c in self.criteria:
            ratio = c.worst / c.floor if c.floor > 0 else math.nan
            verdict = "ok" if c.ok else f"OVER on frame(s) {_frame_list(c.over)}"
            rows.append(
                f"  {c.output:8s}  {c.metric:34s}  {_frame_list(c.frames):7s}  {c.floor:8.2e}  "
                f"{c.worst:8.2e}  {ratio:6.3g}  {c.limit:8.2e}  {verdict}"
            )
        if self.depth_max_rel:
            rows.append(
                "  (largest per-pixel relative depth difference, information: "
                f"ONNX {max(self.depth_max_rel):.2e}, noise run {max(self.depth_max_rel_noise):.2e})"
            )
        rows.append("  OK" if self.ok else "  MISMATCH")
        return "\n".join(rows)


def noise_model(model: SceneModel) -> SceneModel:
    """A copy of ``model`` (reference modules, float32) that computes the same step with another order of the
    floating-point operations: its weights channels-last (oneDNN then takes its NHWC convolution kernels, which block
    and sum the products differently; :func:`compare_onnx` feeds it channels-last inputs and state) and DINL's two
    means over H x W summed in ``SUMMATION_LANES`` sequential chains (:func:`sequential_spatial_mean`), the long
    reductions whose summation order a runtime chooses. Nothing else changes."""
    noisy = copy.deepcopy(model).float().to(memory_format=torch.channels_last)
    if getattr(noisy.encoder, "dinl", None) is not None:
        noisy.encoder.dinl.spatial_mean = sequential_spatial_mean
    return noisy


def _channels_last(x: torch.Tensor) -> torch.Tensor:
    return x.contiguous(memory_format=torch.channels_last) if x.dim() == 4 else x


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


def compare_onnx(
    model: StreamingModel,
    path: str | Path,
    frames: int = CHECK_FRAMES,
    reset_at: int | None = None,
    seed: int = 0,
    inputs=None,
    multiple: float = NOISE_MULTIPLE,
) -> OnnxComparison:
    """Stream ``frames`` frames (frame 0 and ``reset_at`` reset; default the middle frame) of a SynthAir flight
    (:func:`flight_sequence`, or ``inputs = (rgb, rot, trans, intrinsics)``) through ONNX Runtime and, step by step on
    the same inputs and incoming state, through ``model.step`` (its modules, float32: a
    :class:`~cosemdepth.inference.FastModel`'s model) and through :func:`noise_model`; returns an
    :class:`OnnxComparison` (see the module docstring). A graph that was not exported from ``model`` (its recorded
    provenance, :mod:`cosemdepth.export.provenance`) is refused with a :class:`ConfigError`."""
    try:
        import onnxruntime as ort  # deferred: an optional dependency (cosemdepth[export])
    except ImportError as e:  # pragma: no cover - optional dependency
        raise ConfigError("the ONNX check needs onnxruntime (pip install 'cosemdepth[export]')") from e
    check_model(read_provenance(path), model, path)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    shape = sess.get_inputs()[0].shape
    b, _, h, w = (d if isinstance(d, int) else 1 for d in shape)
    rgb, rot, trans, intr = inputs if inputs is not None else flight_sequence(b, frames, h, w, seed)
    frames = rgb.shape[1]
    reset = torch.zeros(b, frames, dtype=torch.bool)
    reset[:, 0] = True
    reset[:, frames // 2 if reset_at is None else reset_at] = True
    state_shapes = [
        [d if isinstance(d, int) else b for d in i.shape] for i in sess.get_inputs() if i.name.startswith("state_")
    ]
    ort_state = [np.zeros(s, np.float32) for s in state_shapes]
    comps = state_components(i.name for i in sess.get_inputs() if i.name.startswith("state_"))
    model = reference_model(model)
    p = next(model.parameters())
    dev = p.device
    reference = model if p.dtype == torch.float32 else copy.deepcopy(model).float()
    noisy = noise_model(reference)
    report = OnnxComparison(
        size=(int(rgb.shape[-2]), int(rgb.shape[-1])),
        batch=b,
        frames=frames,
        resets=[k for k in range(frames) if bool(reset[:, k].any())],
    )
    crit = {key: Criterion(*key, multiple=multiple) for key in CRITERIA}
    with torch.no_grad():
        for k in range(frames):
            feeds = {
                "rgb": rgb[:, k].numpy(),
                "rot": rot[:, k].numpy(),
                "trans": trans[:, k].numpy(),
                "intrinsics": intr.numpy(),
                "reset": reset[:, k].numpy(),
            }
            st_in = [torch.from_numpy(s).to(dev) for s in ort_state]
            res, ort_state = run_onnx_stream(sess, feeds, ort_state)
            args = tuple(a.to(dev) for a in (rgb[:, k], rot[:, k], trans[:, k], intr, reset[:, k]))
            st = StreamState.unflatten(st_in, comps) if st_in and k > 0 else None
            out, new = reference.step(*args, st)
            st_cl = StreamState.unflatten([_channels_last(s) for s in st_in], comps) if st is not None else None
            outn, newn = noisy.step(*(_channels_last(a) for a in args), st_cl)
            if out.depth is not None:
                d, dn, do = out.depth.cpu().numpy(), outn.depth.cpu().numpy(), res["depth"]
                ok = valid_depth(d, reset[:, k].numpy())
                crit[CRITERIA[0]].add(k, nrms(do, d), nrms(dn, d))
                crit[CRITERIA[1]].add(k, relative_percentile(do, d, ok), relative_percentile(dn, d, ok))
                if ok.any():
                    report.depth_max_rel.append(relative_percentile(do, d, ok, 100.0))
                    report.depth_max_rel_noise.append(relative_percentile(dn, d, ok, 100.0))
            if out.semantic is not None:
                s = out.semantic.cpu().numpy()
                crit[CRITERIA[2]].add(k, nrms(res["semantic"], s), nrms(outn.semantic.cpu().numpy(), s))
            if new.flatten():
                ref = [t.cpu().numpy() for t in new.flatten()]
                crit[CRITERIA[3]].add(
                    k,
                    max(nrms(a, t) for a, t in zip(ort_state, ref)),
                    max(nrms(t.cpu().numpy(), r) for t, r in zip(newn.flatten(), ref)),
                )
    report.criteria = [c for c in crit.values() if c.frames]
    return report
