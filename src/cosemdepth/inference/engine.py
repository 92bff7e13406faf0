"""The fast streaming inference path: the same computation as :meth:`SceneModel.step`, re-arranged for speed.

What changes with respect to the reference path (and what does not):

* convolutions run on channels-last tensors with pre-packed weights and the LeakyReLU fused into the kernel
  (:class:`PackedConv`); the 3x3 "same" padding, the TF asymmetric stride-2 padding and the weights are unchanged;
* on the fine levels (up to 32 channels) the spatial cost volume is computed by :func:`spatial_cost_volume_fast`
  (channel loop over all window offsets at once, half the offsets mirrored) instead of one Python iteration per
  offset, and the parallax-sweep correlation accumulates per channel instead of materialising the product;
* nearest upsampling by an integer factor uses ``F.interpolate`` (pixel replication, identical values);
* concatenations write straight into one channels-last buffer in the compute dtype;
* optional reduced precision (``dtype=torch.bfloat16`` / ``torch.float16``): only the six hidden convolutions of
  each refiner (about 97% of the multiply-accumulates) run in it; the encoder, the feature normalisation, the
  geometry, the cost volumes, the last convolution of each refiner (which produces the log-parallax and the
  logits), the softmax and the state stay in float32.

With ``dtype=torch.float32`` the results equal the reference path up to float rounding (summation order inside the
convolutions and the cost volume), which the tests check. Everything runs without autograd.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Optional

import torch
import torch.nn.functional as F

from ..geometry.camera import level_intrinsics
from ..geometry.parallax import epipolar_geometry
from ..geometry.rotation import quaternion_to_matrix
from ..models.depth_decoder import INIT_DEPTH, DepthLevel, RefineOps
from ..models.outputs import DepthLevelOutput, SemanticLevelOutput, StepOutput, StreamState, step_output
from ..models.semantic_decoder import SemanticLevel
from ..ops.cost_volume import (
    parallax_sweep_cost_volume,
    parallax_sweep_cost_volume_fast,
    spatial_cost_volume,
    spatial_cost_volume_fast,
)
from ..ops.normalize import grouped_l2_normalize
from ..ops.resample import resize_nn1, resize_nn2
from .convs import PackedConv

_CL = torch.channels_last
REDUCED_DTYPES = (torch.bfloat16, torch.float16)
#: The channel-loop cost volumes pay off on the large, thin maps of the fine levels (16 and 32 channels); the coarse
#: levels have many channels on small maps, where the reference's per-offset loop is cheaper.
_CHANNEL_LOOP_MAX = 32


_DTYPES = {
    "float32": torch.float32,
    "fp32": torch.float32,
    "bfloat16": torch.bfloat16,
    "bf16": torch.bfloat16,
    "float16": torch.float16,
    "fp16": torch.float16,
}


def parse_dtype(dtype: torch.dtype | str) -> torch.dtype:
    """``torch.float32`` / ``"fp32"`` / ``"bf16"`` / ``"float16"`` ... -> a torch dtype of the fast path."""
    if isinstance(dtype, torch.dtype):
        if dtype in _DTYPES.values():
            return dtype
    elif isinstance(dtype, str) and dtype.lower() in _DTYPES:
        return _DTYPES[dtype.lower()]
    raise ValueError(f"dtype must be one of {sorted(_DTYPES)} (or the torch dtypes), got {dtype!r}")


def upsample_nearest(x: torch.Tensor, size: tuple[int, int], half_pixel: bool) -> torch.Tensor:
    """TF nearest resize (NN2 if ``half_pixel`` else NN1); an integer factor is plain pixel replication, done with
    ``F.interpolate`` (same values, keeps channels-last)."""
    h_in, w_in = x.shape[-2:]
    h, w = size
    if (h_in, w_in) == (h, w):
        return x
    if h % h_in == 0 and w % w_in == 0 and x.dim() == 4:
        return F.interpolate(x, size=(h, w), mode="nearest")
    return resize_nn2(x, size) if half_pixel else resize_nn1(x, size)


class _Refiner:
    """Packed refiner: hidden convolutions in the compute dtype, the last one in float32."""

    def __init__(self, refiner, dtype: torch.dtype, device: torch.device, use_mkldnn: bool | None):
        convs = list(refiner.convs)
        self.in_channels = convs[0].in_channels
        self.hidden = [PackedConv(c, dtype, device, act=True, use_mkldnn=use_mkldnn) for c in convs[:-1]]
        self.last = PackedConv(convs[-1], torch.float32, device, act=False, use_mkldnn=use_mkldnn)
        self.dtype = dtype

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        for conv in self.hidden:
            x = conv(x)
        return self.last(x)


def _concat_channels_last(blocks: list[torch.Tensor], dtype: torch.dtype) -> torch.Tensor:
    """``torch.cat(blocks, 1)`` written once into a channels-last buffer of ``dtype``."""
    b, _, h, w = blocks[0].shape
    c = sum(t.shape[1] for t in blocks)
    out = torch.empty((b, c, h, w), dtype=dtype, device=blocks[0].device, memory_format=_CL)
    k = 0
    for t in blocks:
        out[:, k : k + t.shape[1]].copy_(t)
        k += t.shape[1]
    return out


@dataclass
class _DepthLevelSpec:
    module: DepthLevel
    refiner: _Refiner
    ops: RefineOps


def _fast_pscv(feat, prev, points, groups, half):
    return parallax_sweep_cost_volume_fast(feat, prev, points, groups)


def _depth_ops(level: DepthLevel, refiner: _Refiner, pscv_half: bool) -> RefineOps:
    """The fast operations of one depth level (channel-loop cost volumes on the thin fine levels only)."""
    thin = level.channels <= _CHANNEL_LOOP_MAX
    return RefineOps(
        pscv=_fast_pscv if thin and not pscv_half else parallax_sweep_cost_volume,
        sncv=spatial_cost_volume_fast if thin else spatial_cost_volume,
        concat=functools.partial(_concat_channels_last, dtype=refiner.dtype),
        refiner=refiner,
    )


@dataclass
class _SemanticLevelSpec:
    module: SemanticLevel
    refiner: _Refiner


class FastEngine:
    """Inference-only twin of a :class:`~cosemdepth.models.SceneModel`, built from a snapshot of its weights.

    Args:
        model: the source model (its configuration and numerics switches are read now; weights are copied).
        dtype: compute dtype of the refiners' hidden convolutions: float32 (default), bfloat16 or float16.
        device: where to run (default: the model's device).
        static: never branch on the values of the reset mask (the refiners always run and the reset is a per-sample
            select), for CUDA-graph capture; a state (zeros are fine, with ``reset=True``) must always be given.
        use_mkldnn: use the fused oneDNN convolution kernels on CPU (default: when this PyTorch build has them).
    """

    def __init__(
        self,
        model,
        dtype: torch.dtype = torch.float32,
        device: torch.device | str | None = None,
        static: bool = False,
        use_mkldnn: bool | None = None,
    ):
        if dtype not in (torch.float32, *REDUCED_DTYPES):
            raise ValueError(f"dtype must be float32, bfloat16 or float16, got {dtype}")
        p = next(model.parameters())
        self.device = torch.device(device) if device is not None else p.device
        self.dtype = dtype
        self.static = static
        self.config = model.config
        f32 = torch.float32
        enc = model.encoder
        self.enc_s1 = [
            PackedConv(c, f32, self.device, act=not (k == 0 and enc.dinl is not None), use_mkldnn=use_mkldnn)
            for k, c in enumerate(enc.conv_s1)
        ]
        self.enc_s2 = [PackedConv(c, f32, self.device, act=True, use_mkldnn=use_mkldnn) for c in enc.conv_s2]
        self.dinl = None
        if enc.dinl is not None:
            self.dinl = (
                enc.dinl.weight.detach().to(self.device, f32).view(1, -1, 1, 1),
                enc.dinl.bias.detach().to(self.device, f32).view(1, -1, 1, 1),
            )
        self.depth_levels: list[_DepthLevelSpec] = []
        self.semantic_levels: list[_SemanticLevelSpec] = []
        dd, sd = model.depth_decoder, model.semantic_decoder
        if dd is not None:
            self.guard = dd.guard
            self.pscv_half = dd.pscv_half
            self.depth_levels = []
            for lvl in dd.levels:
                refiner = _Refiner(lvl.refiner, dtype, self.device, use_mkldnn)
                self.depth_levels.append(_DepthLevelSpec(lvl, refiner, _depth_ops(lvl, refiner, self.pscv_half)))
        if sd is not None:
            self.sem_guard = sd.guard
            self.semantic_levels = [
                _SemanticLevelSpec(lvl, _Refiner(lvl.refiner, dtype, self.device, use_mkldnn)) for lvl in sd.levels
            ]

    # ------------------------------------------------------------------ encoder
    def encode(self, rgb: torch.Tensor) -> list[torch.Tensor]:
        """``[B, 3, H, W]`` -> per-level features (finest first), channels-last float32."""
        x = rgb.to(self.device, torch.float32).contiguous(memory_format=_CL)
        feats = []
        for k, (c1, c2) in enumerate(zip(self.enc_s1, self.enc_s2)):
            x = c1(x)
            if k == 0 and self.dinl is not None:
                x = F.leaky_relu_(self._dinl(x), 0.1)
            x = c2(x)
            feats.append(x)
        return feats

    def _dinl(self, x: torch.Tensor) -> torch.Tensor:
        """DINL (spec 2.2) in few passes: ``z = (x - mean) / (var + 1e-12)``, ``z / max(|z|, 1e-6)`` over channels
        (= the reference's ``sqrt(max(sum z^2, 1e-12))``), then ``gamma * n + beta``."""
        gamma, beta = self.dinl
        z = x - x.mean(dim=(2, 3), keepdim=True)
        var = (z * z).mean(dim=(2, 3), keepdim=True)  # (torch.var_mean is not vectorised: 40x slower here)
        z.mul_((var + 1e-12).reciprocal_())
        rnorm = torch.linalg.vector_norm(z, dim=1, keepdim=True).clamp_min_(1e-6).reciprocal_()
        return torch.addcmul(beta, z.mul_(rnorm), gamma)

    # ------------------------------------------------------------------ depth
    def _depth_refine(self, spec: _DepthLevelSpec, f_hat, rho_in, other_in, R, trans, intrinsics, prev_f, prev_d):
        lvl = spec.module
        h, w = f_hat.shape[-2:]
        geom = epipolar_geometry(h, w, R, trans, level_intrinsics(intrinsics, lvl.level), guard=self.guard, hypot=True)
        return lvl.refine(f_hat, rho_in, other_in, geom, prev_f, prev_d, trans, self.guard, self.pscv_half, spec.ops)

    def decode_depth(self, feats, rot, trans, intrinsics, reset, state: Optional[StreamState]):
        prev_f = prev_d = None
        if state is not None and state.features:
            prev_f, prev_d = state.features, state.depths
        if prev_f is None:
            if self.static:
                raise ValueError("a static engine needs an explicit state (zeros with reset=True for a first frame)")
            all_reset = any_reset = True
        elif reset is None:
            all_reset = any_reset = False
        elif self.static:
            all_reset, any_reset = False, True
        else:
            all_reset, any_reset = bool(reset.all()), bool(reset.any())
        if prev_f is not None and not all_reset:
            _check_state(state, feats)
        R = quaternion_to_matrix(rot)
        n = len(self.depth_levels)
        outs: list = [None] * n
        new_f: list = [None] * n
        new_d: list = [None] * n
        coarse = None
        for j in range(n - 1, -1, -1):
            spec = self.depth_levels[j]
            lvl = spec.module
            # NCHW for the cost volumes (one layout change here instead of one per cost volume and per frame)
            feat = feats[j].contiguous()
            f_hat = grouped_l2_normalize(feat, lvl.groups, guard=self.guard) if lvl.normalize else feat
            rho_in, depth_in, other_in = lvl.coarse_inputs(coarse, f_hat)
            if all_reset:
                out = DepthLevelOutput(rho_in, depth_in, other_in)
                state_depth = torch.full_like(depth_in, INIT_DEPTH)
            else:
                out = self._depth_refine(spec, f_hat, rho_in, other_in, R, trans, intrinsics, prev_f[j], prev_d[j])
                state_depth = out.depth
                if any_reset:
                    m = reset.view(-1, 1, 1, 1)
                    out = DepthLevelOutput(
                        torch.where(m, rho_in, out.parallax),
                        torch.where(m, depth_in, out.depth),
                        torch.where(m, other_in, out.other),
                    )
                    state_depth = torch.where(m, torch.full_like(state_depth, INIT_DEPTH), state_depth)
            outs[j], new_f[j], new_d[j] = out, f_hat, state_depth
            coarse = out
        return outs, StreamState(tuple(new_f), tuple(new_d))

    # ------------------------------------------------------------------ semantic
    def decode_semantic(self, feats) -> list[SemanticLevelOutput]:
        n_levels = len(self.semantic_levels)
        outs: list = [None] * n_levels
        coarse = None
        for j in range(n_levels - 1, -1, -1):
            spec = self.semantic_levels[j]
            lvl = spec.module
            feat = feats[j]
            n = lvl.num_classes
            f_hat = grouped_l2_normalize(feat, 1, guard=self.sem_guard) if lvl.normalize else feat
            b, _, h, w = feat.shape
            if coarse is None:
                probs_in = feat.new_zeros(b, n, h, w)
                probs_in[:, n - 1] = 1.0
                other_in = feat.new_zeros(b, 4, h, w)
            else:
                probs_in = upsample_nearest(coarse.probs, (h, w), half_pixel=False)
                other_in = upsample_nearest(coarse.other, (h, w), half_pixel=False)
            y = spec.refiner(_concat_channels_last([probs_in, other_in, f_hat], spec.refiner.dtype))
            logits = y[:, :n]
            coarse = outs[j] = SemanticLevelOutput(torch.softmax(logits, dim=1), logits, y[:, n:])
        return outs

    # ------------------------------------------------------------------ step
    @torch.inference_mode()
    def step(
        self,
        rgb: torch.Tensor,
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
        state: Optional[StreamState] = None,
    ) -> tuple[StepOutput, StreamState]:
        """Same contract as :meth:`SceneModel.step` (inputs are moved to the engine's device)."""
        dev = self.device
        rot, trans, intrinsics = (t.to(dev, torch.float32) for t in (rot, trans, intrinsics))
        if reset is not None:
            reset = reset.to(dev)
        feats = self.encode(rgb)
        size = tuple(rgb.shape[-2:])
        dl = sl = None
        new_state = StreamState()
        if self.depth_levels:
            dl, new_state = self.decode_depth(feats, rot, trans, intrinsics, reset, state)
        if self.semantic_levels:
            sl = self.decode_semantic(feats)
        return step_output(dl, sl, lambda x: upsample_nearest(x, size, half_pixel=True)), new_state

    def zero_state(self, batch: int, height: int, width: int) -> StreamState:
        """An all-zero state for a ``batch x height x width`` input (use with ``reset=True`` on the first frame)."""
        feats, depths = [], []
        h, w = height, width
        for spec in self.depth_levels:
            h, w = (h + 1) // 2, (w + 1) // 2
            c = spec.module.channels
            feats.append(torch.zeros(batch, c, h, w, device=self.device))
            depths.append(torch.zeros(batch, 1, h, w, device=self.device))
        return StreamState(tuple(feats), tuple(depths))


def _check_state(state: StreamState, feats: list[torch.Tensor]) -> None:
    from ..models.model import _check_state as check

    check(state, feats)
