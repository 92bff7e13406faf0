"""The fast streaming inference path: the same computation as :meth:`SceneModel.step`, re-arranged for speed.

What changes with respect to the reference path (and what does not):

* convolutions run on channels-last tensors with pre-packed weights and the LeakyReLU fused into the kernel
  (:class:`PackedConv`); the 3x3 "same" padding, the TF asymmetric stride-2 padding and the weights are unchanged;
* the spatial cost volume is computed by :func:`spatial_cost_volume_fast` (channel loop over all window offsets at
  once, half the offsets mirrored) and, on the fine levels (up to 32 channels), the parallax-sweep correlation
  accumulates per channel instead of materialising the product;
* nearest upsampling by an integer factor uses ``F.interpolate`` (pixel replication, identical values);
* concatenations write straight into one channels-last buffer in the compute dtype;
* optional reduced precision (``dtype=torch.bfloat16`` / ``torch.float16``): only the six hidden convolutions of
  each refiner (about 97% of the multiply-accumulates) run in it, except on the coarsest depth levels
  (:data:`FLOAT32_FROM_LEVEL`); the encoder, the feature normalisation, the geometry, the cost volumes, the last
  convolution of each refiner (which produces the log-parallax and the logits), the softmax and the state stay in
  float32.

With ``dtype=torch.float32`` the results equal the reference path up to float rounding (summation order inside the
convolutions and the cost volume), which the tests check. Everything runs without autograd.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Optional, Sequence

import torch
import torch.nn.functional as F

from ..devices import bf16_convolutions, no_bf16_reason, onednn_enabled
from ..models.model import SceneModel
from ..models.outputs import StepOutput, StreamState
from ..models.pyramid import LevelOps, PyramidLevel, decode_step
from ..ops.concat import write_blocks
from ..ops.cost_volume import spatial_cost_volume_fast
from ..ops.normalize import dinl
from ..ops.resample import resize_nn1, resize_nn2
from .convs import PackedConv
from .int8 import QuantRefiner, RangeRecorder, has_int8

_CL = torch.channels_last
# The channel-loop SNCV is faster than the reference's window-row loop on every level (measured interleaved, 2
# threads, 384 px, loaded machine: 3-13x on levels 2-4, 1.2x on level 5), so every level uses it.


_DTYPES = {
    "float32": torch.float32,
    "fp32": torch.float32,
    "bfloat16": torch.bfloat16,
    "bf16": torch.bfloat16,
    "float16": torch.float16,
    "fp16": torch.float16,
}


INT8_NAMES = ("int8", "qint8")
#: int8 path: per decoder, the hidden refiner convolutions (0-5) that stay float (measured, see the int8 docstring)
INT8_KEEP_FLOAT: dict[str, tuple[int, ...]] = {"depth": (0, 1, 2, 3, 4, 5)}
#: reduced precision (bf16, fp16, int8): per decoder, the first level (1 = half resolution) from which the coarser
#: levels keep float32 refiners. The coarse depth estimates seed every finer level and, through the state, the next
#: frames: in bfloat16 they moved AbsRel by -1.4 % to +2.6 % on three SynthAir flights, float32 there by -0.2 % to
#: +0.1 % for 3.9 % of the refiners' multiply-accumulates (``cosemdepth fast-accuracy``, docs/benchmarks.md).
FLOAT32_FROM_LEVEL: dict[str, int] = {"depth": 3}


def native_bf16() -> bool:
    """Whether oneDNN runs bfloat16 convolutions on this CPU (AVX-512 and up; not an AVX2-only CPU)."""
    return onednn_enabled() and bf16_convolutions("cpu")


def is_int8(dtype) -> bool:
    """Whether ``dtype`` asks for the int8 path (``"int8"`` or ``torch.int8``)."""
    return dtype is torch.int8 or (isinstance(dtype, str) and dtype.lower() in INT8_NAMES)


def parse_dtype(dtype: torch.dtype | str, name: str = "dtype", int8: bool = False) -> torch.dtype:
    """``torch.float32`` / ``"fp32"`` / ``"bf16"`` / ``"float16"`` ... -> a torch dtype of the fast path; else a
    ValueError naming the argument ``name`` and every value it takes (``int8``: "int8" too, handled by the
    caller)."""
    if isinstance(dtype, torch.dtype):
        if dtype in _DTYPES.values():
            return dtype
    elif isinstance(dtype, str) and dtype.lower() in _DTYPES:
        return _DTYPES[dtype.lower()]
    names = sorted([*_DTYPES, *(INT8_NAMES[:1] if int8 else ())])
    raise ValueError(f"{name} must be one of {names} (or the torch dtypes), got {dtype!r}")


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
        self.hidden = [PackedConv(c, dtype, device, act=True, use_mkldnn=use_mkldnn) for c in convs[:-1]]
        self.last = PackedConv(convs[-1], torch.float32, device, act=False, use_mkldnn=use_mkldnn)
        self.dtype = dtype

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        for conv in self.hidden:
            x = conv(x)
        return self.last(x)


def _nearest_nn1(x: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    return upsample_nearest(x, size, half_pixel=False)


def _fast_ops(level: PyramidLevel, refiner: _Refiner) -> LevelOps:
    """The fast operations of one level: packed refiner, channels-last concatenation, nearest resize by pixel
    replication, the channel-loop SNCV, and the level's own choices (:attr:`PyramidLevel.fast_ops`: a depth level's
    NCHW features, one layout change here instead of one per cost volume and per frame, and ``hypot``; the PSCV is
    the reference's own function)."""
    ops = LevelOps(
        concat=functools.partial(write_blocks, dtype=refiner.dtype, memory_format=_CL),
        refiner=refiner,
        nearest=_nearest_nn1,
        sncv=spatial_cost_volume_fast,
    )
    return dataclasses.replace(ops, **level.fast_ops) if level.fast_ops else ops


class FastEngine:
    """Inference-only twin of a :class:`~cosemdepth.models.SceneModel`, built from a snapshot of its weights: its
    ``step`` feeds the model's own level loop (:func:`cosemdepth.models.pyramid.decode_step`) with packed
    :class:`~cosemdepth.models.pyramid.LevelOps`, without input checks. :class:`~cosemdepth.inference.FastModel` is the
    public front (checks, ``infer``, weights followed); the engine is what :class:`~cosemdepth.inference.graphs.StaticStreamer` captures.

    Args:
        model: the source model (its configuration and numerics switches are read now; weights are copied).
        dtype: compute dtype of the refiners' hidden convolutions: float32 (default), bfloat16 or float16 (a torch
            dtype or a name, see :func:`parse_dtype`).
        device: where to run (default: the model's device).
        static: never branch on the values of the reset mask (the refiners always run and the reset is a per-sample
            select), for CUDA-graph capture; a state (zeros are fine, with ``reset=True``) must always be given.
        use_mkldnn: use the fused oneDNN convolution kernels on CPU (default: when this PyTorch build has them).
        calibration: with ``dtype="int8"``: an iterable of ``(rgb, rot, trans, intrinsics, reset)`` frames streamed
            once at construction to calibrate the activation ranges (see :mod:`cosemdepth.inference.int8`).
            Without it, the first ``calibration_frames`` frames given to :meth:`step` calibrate (they run in float32)
            and the int8 refiners take over from the next frame.
        calibration_frames: frames of :meth:`step` used to calibrate when no ``calibration`` is given.
        int8_keep_float: with int8, per decoder the hidden refiner convolutions that stay float (default
            :data:`INT8_KEEP_FLOAT`: the depth refiners).
        int8_float_dtype: with int8, the dtype of those float convolutions (default bfloat16 on a CPU with native
            bf16, else float32; measured within the accuracy bounds, ``cosemdepth fast-accuracy``).
        float32_levels: with a reduced precision (bf16, fp16, int8), per decoder the level numbers (1 = finest) whose
            refiners run entirely in float32 (default: :data:`FLOAT32_FROM_LEVEL`, the depth levels at 1/8 of the
            resolution and coarser: 3, 4 and 5 of the 5-level model); ``{}`` runs every level reduced.
    """

    def __init__(
        self,
        model: SceneModel,
        dtype: torch.dtype | str = torch.float32,
        device: torch.device | str | None = None,
        static: bool = False,
        use_mkldnn: bool | None = None,
        calibration=None,
        calibration_frames: int = 8,
        int8_keep_float: dict[str, tuple[int, ...]] | None = None,
        int8_float_dtype: torch.dtype | str | None = None,
        float32_levels: dict[str, tuple[int, ...]] | None = None,
    ):
        self.int8_keep_float = dict(INT8_KEEP_FLOAT if int8_keep_float is None else int8_keep_float)
        if int8_float_dtype is None:
            int8_float_dtype = torch.bfloat16 if native_bf16() else torch.float32
        self.int8_float_dtype = parse_dtype(int8_float_dtype, "int8_float_dtype")
        self.int8 = is_int8(dtype)
        dtype = torch.float32 if self.int8 else parse_dtype(dtype, int8=True)
        p = next(model.parameters())
        self.device = torch.device(device) if device is not None else p.device
        if torch.bfloat16 in (dtype, self.int8_float_dtype if self.int8 else dtype) and not bf16_convolutions(
            self.device
        ):
            raise ValueError(f"bfloat16 needs bfloat16 convolutions; {no_bf16_reason()}: use fp32 (float32) or int8")
        self.dtype = dtype
        self.static = static
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
                enc.dinl.weight.detach().to(self.device, f32),
                enc.dinl.bias.detach().to(self.device, f32),
            )
        # the decoders' level modules give the structure and numerics switches; their weights are packed here
        self.decoders = model.decoders
        self.state_shapes = model.state_shapes
        if float32_levels is None:
            float32_levels = {
                name: tuple(lvl.level for lvl in dec.levels if lvl.level >= FLOAT32_FROM_LEVEL[name])
                for name, dec in self.decoders.items()
                if name in FLOAT32_FROM_LEVEL
            }
        self.float32_levels = {name: tuple(v) for name, v in float32_levels.items()}
        self.ops = {
            name: [
                _fast_ops(
                    lvl, _Refiner(lvl.refiner, f32 if self._float32(name, lvl) else dtype, self.device, use_mkldnn)
                )
                for lvl in dec.levels
            ]
            for name, dec in self.decoders.items()
        }
        self._calibrating = 0
        if self.int8:
            if self.device.type != "cpu" or not has_int8():
                raise ValueError("dtype int8 needs the CPU and a PyTorch build with oneDNN quantized convolutions")
            if calibration_frames < 1:
                raise ValueError(f"calibration_frames must be at least 1, got {calibration_frames}")
            self._start_calibration()
            if calibration is None:
                self._calibrating = calibration_frames
            else:
                n, state = 0, None
                for frame in calibration:
                    _, state = self.step(*frame, state=state)
                    n += 1
                if n == 0:
                    raise ValueError("the int8 calibration sequence is empty")
                self._finish_calibration()

    # ------------------------------------------------------------------ int8 calibration
    def _start_calibration(self) -> None:
        self.ops = {
            name: [dataclasses.replace(o, refiner=RangeRecorder(o.refiner)) for o in ops]
            for name, ops in self.ops.items()
        }

    def _finish_calibration(self) -> None:
        self.ops = {
            name: [
                dataclasses.replace(
                    o,
                    refiner=o.refiner.refiner
                    if self._float32(name, lvl)
                    else QuantRefiner(
                        lvl.refiner, o.refiner, self.int8_keep_float.get(name, ()), self.int8_float_dtype
                    ),
                )
                for lvl, o in zip(self.decoders[name].levels, ops)
            ]
            for name, ops in self.ops.items()
        }
        self._calibrating = 0

    def _float32(self, decoder: str, level: PyramidLevel) -> bool:
        """Whether ``level`` of ``decoder`` keeps float32 refiners whatever the engine's precision."""
        return level.level in self.float32_levels.get(decoder, ())

    @property
    def calibrated(self) -> bool:
        """False while an int8 engine still records activation ranges (its refiners then run in float32)."""
        return not any(isinstance(o.refiner, RangeRecorder) for ops in self.ops.values() for o in ops)

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
        """DINL (design 4.2) in few passes (:func:`cosemdepth.ops.normalize.dinl`, the training's too)."""
        return dinl(x, *self.dinl)

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
        decoders: Optional[Sequence[str]] = None,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> tuple[StepOutput, StreamState]:
        """The streaming step of :class:`~cosemdepth.models.protocol.StreamingModel` (inputs are moved to the
        engine's device; no input checks: :class:`~cosemdepth.inference.FastModel` makes them)."""
        dev = self.device
        rot, trans, intrinsics = (t.to(dev, torch.float32) for t in (rot, trans, intrinsics))
        if reset is not None:
            reset = reset.to(dev)
        if (
            self.static
            and any(dec.temporal for dec in self.decoders.values())
            and not (state is not None and state.flatten())
        ):
            raise ValueError("a static engine needs an explicit state (zeros with reset=True for a first frame)")
        feats = self.encode(rgb)
        size = tuple(rgb.shape[-2:])
        result = decode_step(
            self.decoders,
            feats,
            rot,
            trans,
            intrinsics,
            reset,
            state,
            lambda x: upsample_nearest(x, size, half_pixel=True),
            self.ops,
            self.static,
            only=decoders,
            guide_depth=None if guide_depth is None else guide_depth.to(dev, torch.float32),
        )
        if self._calibrating:
            self._calibrating -= 1
            if not self._calibrating:
                self._finish_calibration()
        return result

    def zero_state(self, batch: int, height: int, width: int) -> StreamState:
        """An all-zero state for a ``batch x height x width`` input (use with ``reset=True`` on the first frame)."""
        shapes = self.state_shapes(batch, height, width).items()
        return StreamState(**{k: tuple(torch.zeros(s, device=self.device) for s in v) for k, v in shapes})
