"""int8 refiners for the fast CPU path (``SceneModel.optimize("fast", "int8")``): oneDNN quantized convolutions.

What is quantised: the six hidden 3x3 convolutions of the semantic decoder's refiners by default (see
``engine.INT8_KEEP_FLOAT``; any refiner's hidden convolutions can be), with per-output-channel symmetric int8
weights and per-tensor asymmetric uint8 activations whose ranges are calibrated statically (min / max of each
convolution's input and pre-activation output over calibration frames). The activations stay uint8 from the first
hidden convolution to the last one (consecutive convolutions share the quantisation parameters: no requantisation
between them); each convolution runs as one oneDNN primitive (``torch.ops.onednn.qconv2d_pointwise``, VNNI / AMX where the CPU has them) and the LeakyReLU(0.1), which
oneDNN's quantized convolution cannot fuse, runs in place on its uint8 output (a quantized view of the same memory),
requantising to the next convolution's input range. Quantising on entry and dequantising on exit are one pass each
(PyTorch's quantized copy / dequantize kernels on such views).

Measured on the shipped SynthAir weights (62 frames of a 128x128 SynthAir flight, seed 77, calibration on 14 frames
of another flight): with every refiner int8, mIoU +0.12 points but AbsRel +9.1 % relative to fast fp32; keeping
the depth refiners' first convolution float32 +2.7 %, their first and last +1.7 %, all of them float32 +0.0 %. Per-tensor
activation ranges are too coarse for the depth refiners (their output is a log-parallax), so the depth decoder's
refiners stay float by default: in bfloat16 on a CPU with native bf16 (AVX512-BF16 / AMX), else float32
(``FastEngine(int8_float_dtype=...)``).

What stays float32: the encoder and its DINL normalisation, the grouped L2 feature normalisation, the cost volumes of
the normalised features (SNCV, PSCV), the warps and the geometry, the last convolution of each refiner (it produces
the log-parallax and the logits), the softmax and the state. The refiner's input (the concatenation of features,
cost volumes and coarse estimates) is quantised once, per tensor, on entry.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch

from ..models.layers import NEGATIVE_SLOPE
from ..ops.padding import Conv2dSame
from .convs import PackedConv

_CL = torch.channels_last


def has_int8() -> bool:
    """Whether this PyTorch build has the oneDNN quantized convolution used here."""
    try:
        return torch.backends.mkldnn.is_available() and hasattr(torch.ops.onednn, "qconv2d_pointwise")
    except (AttributeError, RuntimeError):  # pragma: no cover - exotic builds
        return False


@dataclass
class Range:
    """Running min / max of a tensor over the calibration frames."""

    lo: float = float("inf")
    hi: float = float("-inf")

    def update(self, x: torch.Tensor) -> None:
        lo, hi = torch.aminmax(x.detach())
        self.lo, self.hi = min(self.lo, float(lo)), max(self.hi, float(hi))

    def qparams(self) -> tuple[float, int]:
        """``(scale, zero_point)`` of uint8 affine quantisation covering ``[min(lo, 0), max(hi, 0)]`` (0 exact)."""
        if self.lo > self.hi:
            raise RuntimeError("int8 calibration saw no data for this convolution")
        lo, hi = min(self.lo, 0.0), max(self.hi, 0.0)
        scale = max((hi - lo) / 255.0, 1e-8)
        return scale, int(min(255, max(0, round(-lo / scale))))


@dataclass
class QTensor:
    """A uint8 channels-last tensor with its per-tensor affine parameters (real = scale * (q - zero_point))."""

    q: torch.Tensor
    scale: float
    zero_point: int

    def dequantize(self) -> torch.Tensor:
        return quantized_view(self.q, self.scale, self.zero_point).dequantize()


def quantized_view(u: torch.Tensor, scale: float, zero_point: int) -> torch.Tensor:
    """A ``quint8`` tensor over the memory of the uint8 tensor ``u`` (no copy; writes to either show in both)."""
    with warnings.catch_warnings():  # quantized tensors are deprecated in PyTorch (2.13); their kernels still run
        warnings.simplefilter("ignore")
        q = torch._empty_affine_quantized([0], scale=scale, zero_point=zero_point, dtype=torch.quint8,
                                          device=u.device)
    return q.set_(u.untyped_storage(), u.storage_offset(), u.shape, u.stride())


def quantize(x: torch.Tensor, scale: float, zero_point: int) -> QTensor:
    """Float ``x`` -> channels-last uint8 ``round(x / scale) + zero_point`` clamped to [0, 255], in one pass."""
    q = torch.empty(x.shape, dtype=torch.uint8, device=x.device, memory_format=_CL)
    quantized_view(q, scale, zero_point).copy_(x.contiguous(memory_format=_CL))
    return QTensor(q, scale, zero_point)


def quantize_weight(w: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-output-channel symmetric int8 weights: ``(w_int8, scales)`` with ``w ~= scales[o] * w_int8[o]``."""
    amax = w.detach().abs().amax(dim=(1, 2, 3)).float()
    scales = torch.where(amax > 0, amax / 127.0, torch.ones_like(amax))
    q = torch.round(w.detach().float() / scales.view(-1, 1, 1, 1)).clamp_(-127, 127).to(torch.int8)
    return q, scales


class QuantConv:
    """One stride-1 "same" 3x3 convolution followed by LeakyReLU(0.1), in int8: uint8 in, uint8 out.

    Args:
        conv: the source convolution (stride 1, symmetric padding).
        x_range: calibrated range of its input; y_range: of its output before the activation.
    """

    def __init__(self, conv: Conv2dSame, x_range: Range, y_range: Range):
        if conv.stride[0] != 1 or not conv.symmetric:
            raise ValueError("QuantConv handles stride-1 convolutions with symmetric padding only")
        self.qw, self.w_scales = quantize_weight(conv.weight)
        self.w_zp = torch.zeros(self.qw.shape[0], dtype=torch.int32)
        self.bias = None if conv.bias is None else conv.bias.detach().float().contiguous()
        self.padding = conv.kernel_size[0] // 2
        self.x_scale, self.x_zp = x_range.qparams()
        self.y_scale, self.y_zp = y_range.qparams()
        # after LeakyReLU the range shrinks on the negative side: requantise to it (finer steps for the next conv)
        self.out_scale, self.out_zp = Range(NEGATIVE_SLOPE * min(y_range.lo, 0.0), max(y_range.hi, 0.0)).qparams()
        self._packed: dict[tuple[int, ...], torch.Tensor] = {}

    def _weight(self, shape: tuple[int, ...]) -> torch.Tensor:
        w = self._packed.get(shape)
        if w is None:
            p = [self.padding] * 2
            w = torch.ops.onednn.qconv_prepack(self.qw, self.w_scales, self.x_scale, self.x_zp, [1, 1], p, [1, 1], 1,
                                               list(shape))
            self._packed[shape] = w
        return w

    def __call__(self, x: QTensor | torch.Tensor) -> QTensor:
        if not isinstance(x, QTensor):
            x = quantize(x, self.x_scale, self.x_zp)
        elif (x.scale, x.zero_point) != (self.x_scale, self.x_zp):
            x = quantize(x.dequantize(), self.x_scale, self.x_zp)
        p = [self.padding] * 2
        y = torch.ops.onednn.qconv2d_pointwise(
            x.q, self.x_scale, self.x_zp, self._weight(tuple(x.q.shape)), self.w_scales, self.w_zp, self.bias,
            [1, 1], p, [1, 1], 1, self.y_scale, self.y_zp, None, "none", [], "",
        )
        # LeakyReLU in place: read y at its scale, write it back at the (finer) post-activation scale
        torch.ops.aten.leaky_relu.out(quantized_view(y, self.y_scale, self.y_zp), NEGATIVE_SLOPE,
                                      out=quantized_view(y, self.out_scale, self.out_zp))
        return QTensor(y, self.out_scale, self.out_zp)


class RangeRecorder:
    """Calibration twin of a float32 packed refiner: runs it convolution by convolution and records the range of
    every hidden convolution's input and pre-activation output."""

    def __init__(self, refiner):
        self.refiner = refiner
        self.dtype = refiner.dtype
        self.x_ranges = [Range() for _ in refiner.hidden]
        self.y_ranges = [Range() for _ in refiner.hidden]

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        for conv, rx, ry in zip(self.refiner.hidden, self.x_ranges, self.y_ranges):
            rx.update(x)
            x = conv(x)
            lo, hi = torch.aminmax(x)  # fused LeakyReLU(0.1) is invertible: pre-activation = y / 0.1 where y < 0
            lo = float(lo)
            ry.update(torch.tensor([lo / NEGATIVE_SLOPE if lo < 0 else lo, float(hi)]))
        return self.refiner.last(x)


class QuantRefiner:
    """int8 refiner: the hidden convolutions as :class:`QuantConv` (uint8 between them), the last one float32.

    ``keep_float`` hidden convolutions run as packed float convolutions in ``float_dtype`` (float32, or bfloat16 on
    a CPU with native bf16). Consecutive int8 convolutions share their quantisation parameters: the input of one is
    the requantised output of the previous one (no dequantise / quantise pass between them)."""

    def __init__(self, source_refiner, recorder: RangeRecorder, keep_float: tuple[int, ...] = (),
                 float_dtype: torch.dtype = torch.float32):
        convs = list(source_refiner.convs)
        packed = recorder.refiner.hidden
        self.hidden = [
            (packed[k] if float_dtype == packed[k].dtype else
             PackedConv(c, float_dtype, packed[k].device, act=True, use_mkldnn=packed[k].use_mkldnn))
            if k in keep_float else QuantConv(c, rx, ry)
            for k, (c, rx, ry) in enumerate(zip(convs[:-1], recorder.x_ranges, recorder.y_ranges))
        ]
        for a, b in zip(self.hidden, self.hidden[1:]):
            if isinstance(a, QuantConv) and isinstance(b, QuantConv):
                # calibrated on the same tensor up to rounding: adopt the producer's exactly
                b.x_scale, b.x_zp = a.out_scale, a.out_zp
        self.last = recorder.refiner.last
        self.dtype = torch.float32

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        for conv in self.hidden:
            if isinstance(x, QTensor) and not isinstance(conv, QuantConv):
                x = x.dequantize().contiguous(memory_format=_CL)
            x = conv(x)
        if isinstance(x, QTensor):
            x = x.dequantize().contiguous(memory_format=_CL)
        return self.last(x)
