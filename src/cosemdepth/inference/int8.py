"""int8 refiners for the fast CPU path (``FastModel(model, "int8")``): oneDNN quantized convolutions.

What is quantised: the six hidden 3x3 convolutions of the semantic decoder's refiners by default (see
``engine.INT8_KEEP_FLOAT``; any refiner's hidden convolutions can be), with per-output-channel symmetric int8
weights and per-tensor asymmetric uint8 activations whose ranges are calibrated statically (min / max of each
convolution's input and pre-activation output over calibration frames). The activations stay uint8 from the first
hidden convolution to the last one (consecutive convolutions share the quantisation parameters: no requantisation
between them); each convolution runs as one oneDNN primitive (``torch.ops.onednn.qconv2d_pointwise``, VNNI / AMX where the CPU has them) and the LeakyReLU(0.1), which
oneDNN's quantized convolution cannot fuse, runs in place on its uint8 output (a quantized view of the same memory),
requantising to the next convolution's input range. Quantising on entry and dequantising on exit are one pass each
(PyTorch's quantized copy / dequantize kernels on such views).

Before quantising, every activation that an int8 convolution reads or writes is equalised channel by channel
(:func:`equalize_chain`, SmoothQuant's rule with ``alpha = 0.5``): the refiner's input concatenates features, cost
volumes and coarse estimates whose ranges differ by orders of magnitude, and one per-tensor range loses the small
ones. Between convolutions the scales fold into the weights (free); on the refiner's input they cost one
multiplication.

The depth metrics of this recurrent model move by a few percent either way under small changes of quantisation
(the equalisation's alpha, which convolutions are int8), while the semantic ones hardly move, so the depth decoder's
refiners stay float by default: in bfloat16 on a CPU with native bf16 (AVX512-BF16 / AMX), else float32
(``FastEngine(int8_float_dtype=...)``), and float32 on the coarse levels whatever the precision
(``engine.FLOAT32_FROM_LEVEL``). The accuracy of each mode against fast fp32 is what ``cosemdepth fast-accuracy``
measures (its current report: docs/benchmarks.md); whether int8 pays over bf16 depends on the CPU's int8 and bf16
convolution speeds (``benchmarks/conv_peak.py``), the LeakyReLU being a separate pass in int8.

What stays float32: the encoder and its DINL normalisation, the grouped L2 feature normalisation, the cost volumes of
the normalised features (SNCV, PSCV), the warps and the geometry, the last convolution of each refiner (it produces
the log-parallax and the logits), the softmax and the state. The refiner's input (the concatenation of features,
cost volumes and coarse estimates) is quantised once, per tensor, on entry.
"""

from __future__ import annotations

import copy
import functools
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


@functools.cache
def activation_qmax() -> int:
    """The largest uint8 activation value the int8 convolutions may use here: 255, or 127 where oneDNN's kernel
    sums pairs of uint8 x int8 products in saturating 16-bit arithmetic (x86 without VNNI: AVX2's ``vpmaddubsw``,
    where 255 * 127 * 2 overflows), as PyTorch's ``reduce_range`` does. Found by running one convolution whose exact
    result such a kernel cannot reach (all inputs 255, all weights 127), once per process."""
    x = torch.full((1, 8, 3, 3), 255, dtype=torch.uint8).contiguous(memory_format=_CL)
    w = torch.full((1, 8, 3, 3), 127, dtype=torch.int8)
    one = torch.ones(1)
    packed = torch.ops.onednn.qconv_prepack(w, one, 1.0, 0, [1, 1], [0, 0], [1, 1], 1, list(x.shape))
    y = torch.ops.onednn.qconv2d_pointwise(
        x,
        1.0,
        0,
        packed,
        one,
        torch.zeros(1, dtype=torch.int32),
        None,
        [1, 1],
        [0, 0],
        [1, 1],
        1,
        1e5,
        0,
        None,
        "none",
        [],
        "",
    )
    exact = round(255 * 127 * 72 / 1e5)  # 23; pairs saturated at 32767 give 12
    return 255 if int(y.flatten()[0]) == exact else 127


@dataclass
class Range:
    """Running min / max of a tensor over the calibration frames."""

    lo: float = float("inf")
    hi: float = float("-inf")

    def update(self, x: torch.Tensor) -> None:
        lo, hi = torch.aminmax(x.detach())
        self.lo, self.hi = min(self.lo, float(lo)), max(self.hi, float(hi))

    def qparams(self, qmax: int = 255) -> tuple[float, int]:
        """``(scale, zero_point)`` of affine quantisation to ``[0, qmax]`` covering ``[min(lo, 0), max(hi, 0)]``
        (0 exact); ``qmax`` 255 (uint8) or 127 (:func:`activation_qmax` on a CPU whose int8 products saturate)."""
        if self.lo > self.hi:
            raise RuntimeError("int8 calibration saw no data for this convolution")
        lo, hi = min(self.lo, 0.0), max(self.hi, 0.0)
        scale = max((hi - lo) / qmax, 1e-8)
        return scale, int(min(qmax, max(0, round(-lo / scale))))


class ChannelRange:
    """Running per-channel min / max of ``[B, C, H, W]`` tensors over the calibration frames."""

    def __init__(self, lo: torch.Tensor | None = None, hi: torch.Tensor | None = None):
        self.lo, self.hi = lo, hi

    def update(self, x: torch.Tensor) -> None:
        x = x.detach().float()
        lo, hi = x.amin(dim=(0, 2, 3)), x.amax(dim=(0, 2, 3))
        self.lo = lo if self.lo is None else torch.minimum(self.lo, lo)
        self.hi = hi if self.hi is None else torch.maximum(self.hi, hi)

    def scaled(self, s: torch.Tensor) -> "ChannelRange":
        """The range of ``x / s`` (``s [C]`` positive)."""
        return ChannelRange(self.lo / s, self.hi / s)

    def absmax(self) -> torch.Tensor:
        return torch.maximum(self.lo.abs(), self.hi.abs())

    def tensor(self) -> Range:
        """The per-tensor range."""
        if self.lo is None:
            return Range()
        return Range(float(self.lo.min()), float(self.hi.max()))


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
        q = torch._empty_affine_quantized([0], scale=scale, zero_point=zero_point, dtype=torch.quint8, device=u.device)
    return q.set_(u.untyped_storage(), u.storage_offset(), u.shape, u.stride())


def quantize(x: torch.Tensor, scale: float, zero_point: int) -> QTensor:
    """Float ``x`` -> channels-last uint8 ``round(x / scale) + zero_point`` clamped to [0, 255], in one pass."""
    q = torch.empty(x.shape, dtype=torch.uint8, device=x.device, memory_format=_CL)
    quantized_view(q, scale, zero_point).copy_(x.float().contiguous(memory_format=_CL))
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
        qmax = activation_qmax()  # the activations a convolution reads: 7 bits where 8 would overflow
        self.x_scale, self.x_zp = x_range.qparams(qmax)
        self.y_scale, self.y_zp = y_range.qparams()
        # after LeakyReLU the range shrinks on the negative side: requantise to it (finer steps for the next conv)
        self.out_scale, self.out_zp = Range(NEGATIVE_SLOPE * min(y_range.lo, 0.0), max(y_range.hi, 0.0)).qparams(qmax)
        self._packed: dict[tuple[int, ...], torch.Tensor] = {}

    def _weight(self, shape: tuple[int, ...]) -> torch.Tensor:
        w = self._packed.get(shape)
        if w is None:
            p = [self.padding] * 2
            w = torch.ops.onednn.qconv_prepack(
                self.qw, self.w_scales, self.x_scale, self.x_zp, [1, 1], p, [1, 1], 1, list(shape)
            )
            self._packed[shape] = w
        return w

    def __call__(self, x: QTensor | torch.Tensor) -> QTensor:
        if not isinstance(x, QTensor):
            x = quantize(x, self.x_scale, self.x_zp)
        elif (x.scale, x.zero_point) != (self.x_scale, self.x_zp):
            x = quantize(x.dequantize(), self.x_scale, self.x_zp)
        p = [self.padding] * 2
        y = torch.ops.onednn.qconv2d_pointwise(
            x.q,
            self.x_scale,
            self.x_zp,
            self._weight(tuple(x.q.shape)),
            self.w_scales,
            self.w_zp,
            self.bias,
            [1, 1],
            p,
            [1, 1],
            1,
            self.y_scale,
            self.y_zp,
            None,
            "none",
            [],
            "",
        )
        # LeakyReLU in place: read y at its scale, write it back at the (finer) post-activation scale
        torch.ops.aten.leaky_relu.out(
            quantized_view(y, self.y_scale, self.y_zp),
            NEGATIVE_SLOPE,
            out=quantized_view(y, self.out_scale, self.out_zp),
        )
        return QTensor(y, self.out_scale, self.out_zp)


class RangeRecorder:
    """Calibration twin of a float32 packed refiner: runs it convolution by convolution and records the per-channel
    range of every hidden convolution's input and pre-activation output."""

    def __init__(self, refiner):
        self.refiner = refiner
        self.dtype = refiner.dtype
        self.x_ranges = [ChannelRange() for _ in refiner.hidden]
        self.y_ranges = [ChannelRange() for _ in refiner.hidden]

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        for conv, rx, ry in zip(self.refiner.hidden, self.x_ranges, self.y_ranges):
            rx.update(x)
            x = conv(x)
            # the fused LeakyReLU(0.1) is invertible: pre-activation = y / 0.1 where y < 0
            ry.update(torch.where(x < 0, x / NEGATIVE_SLOPE, x))
        return self.refiner.last(x)


def equalization_scales(x_absmax: torch.Tensor, w: torch.Tensor, alpha: float) -> torch.Tensor:
    """Per-input-channel scales ``s`` that move activation range into the weights (SmoothQuant's rule):
    ``s_c = max|x_c|^alpha / max|w[:, c]|^(1 - alpha)``, 1 for a channel that is zero in either.

    Dividing channel ``c`` of the activation by ``s_c`` and multiplying the weights' input channel ``c`` by it leaves
    the convolution unchanged in exact arithmetic and evens out the channels' ranges before per-tensor quantisation.

    Args:
        x_absmax: ``[C]`` calibrated ``max |x_c|``; w: ``[O, C, kh, kw]`` the consuming convolution's weights.
    Returns:
        ``[C]`` positive scales.
    """
    w_absmax = w.detach().abs().amax(dim=(0, 2, 3)).float()
    live = (x_absmax > 0) & (w_absmax > 0)
    s = x_absmax.clamp_min(1e-12).pow(alpha) / w_absmax.clamp_min(1e-12).pow(1.0 - alpha)
    return torch.where(live, s, torch.ones_like(s))


def _scaled_conv(conv: Conv2dSame, out_div: torch.Tensor | None = None, in_mul: torch.Tensor | None = None):
    """A copy of ``conv`` computing ``conv(x * in_mul) / out_div`` per channel (weights and bias rescaled)."""
    c = copy.deepcopy(conv)
    with torch.no_grad():
        if in_mul is not None:
            c.weight.mul_(in_mul.to(c.weight).view(1, -1, 1, 1))
        if out_div is not None:
            c.weight.div_(out_div.to(c.weight).view(-1, 1, 1, 1))
            if c.bias is not None:
                c.bias.div_(out_div.to(c.bias))
    return c


def equalize_chain(convs: list, x_ranges: list, y_ranges: list, quantised: list[bool], alpha: float):
    """Equalise, channel by channel, every activation of a refiner that an int8 convolution reads or writes.

    ``convs`` are the refiner's convolutions (hidden ones with LeakyReLU, then the last one), ``x_ranges[k]`` /
    ``y_ranges[k]`` the calibrated :class:`ChannelRange` of hidden convolution ``k``'s input / pre-activation output,
    ``quantised[k]`` whether hidden convolution ``k`` runs in int8. At the boundary ``k`` (the input of ``convs[k]``,
    the output of ``convs[k - 1]``) the activation is divided by :func:`equalization_scales` ``s``: folded into the
    producer's weights and bias (LeakyReLU commutes with a positive scale) and the consumer's input channels, or,
    on the refiner's input, returned as the multiplier ``1 / s`` to apply before the first convolution.

    Returns:
        ``(convs, x_ranges, y_ranges, in_mult)``: new lists (inputs untouched), ``in_mult [1, C, 1, 1]`` or None.
        In exact arithmetic the chain computes the same function as before.
    """
    convs, xr, yr = list(convs), list(x_ranges), list(y_ranges)
    n = len(convs) - 1
    in_mult = None
    for k in range(n + 1):
        if not ((k < n and quantised[k]) or (k > 0 and quantised[k - 1])):
            continue  # neither side of this boundary is quantised
        if k < n:
            x_abs = xr[k].absmax()
        else:  # the last convolution's input: the last hidden one's output after LeakyReLU
            x_abs = torch.maximum(yr[k - 1].lo.abs() * NEGATIVE_SLOPE, yr[k - 1].hi.abs())
        s = equalization_scales(x_abs, convs[k].weight, alpha)
        convs[k] = _scaled_conv(convs[k], in_mul=s)
        if k < n:
            xr[k] = xr[k].scaled(s)
        if k == 0:
            in_mult = (1.0 / s).view(1, -1, 1, 1)
        else:
            convs[k - 1] = _scaled_conv(convs[k - 1], out_div=s)
            yr[k - 1] = yr[k - 1].scaled(s)
    return convs, xr, yr, in_mult


class QuantRefiner:
    """int8 refiner: the hidden convolutions as :class:`QuantConv` (uint8 between them), the last one float32.

    ``keep_float`` hidden convolutions run as packed float convolutions in ``float_dtype`` (float32, or bfloat16 on
    a CPU with native bf16). Consecutive int8 convolutions share their quantisation parameters: the input of one is
    the requantised output of the previous one (no dequantise / quantise pass between them).

    With ``alpha`` (default 0.5), the activations that int8 convolutions read or write are equalised channel by
    channel first (:func:`equalize_chain`): free between convolutions, one multiplication on the refiner's input (a
    concatenation of features, cost volumes and estimates with very different ranges). ``alpha=None`` quantises the
    calibrated activations as they are."""

    def __init__(
        self,
        source_refiner,
        recorder: RangeRecorder,
        keep_float: tuple[int, ...] = (),
        float_dtype: torch.dtype = torch.float32,
        alpha: float | None = 0.5,
    ):
        convs = list(source_refiner.convs)
        n = len(convs) - 1
        packed = recorder.refiner.hidden
        xr, yr = recorder.x_ranges, recorder.y_ranges
        quantised = [k not in keep_float for k in range(n)]
        self.in_mult = None
        if alpha is not None:
            convs, xr, yr, self.in_mult = equalize_chain(convs, xr, yr, quantised, alpha)
        changed = [a is not b for a, b in zip(convs, source_refiner.convs)]
        dev = packed[0].device

        def float_conv(k: int, dtype: torch.dtype, act: bool, like):
            if not changed[k] and like.dtype == dtype:
                return like
            return PackedConv(convs[k], dtype, dev, act=act, use_mkldnn=like.use_mkldnn)

        self.hidden = [
            QuantConv(convs[k], xr[k].tensor(), yr[k].tensor())
            if quantised[k]
            else float_conv(k, float_dtype, True, packed[k])
            for k in range(n)
        ]
        for a, b in zip(self.hidden, self.hidden[1:]):
            if isinstance(a, QuantConv) and isinstance(b, QuantConv):
                # calibrated on the same tensor up to rounding: adopt the producer's exactly
                b.x_scale, b.x_zp = a.out_scale, a.out_zp
        self.last = float_conv(n, torch.float32, False, recorder.refiner.last)
        if self.in_mult is not None:
            self.in_mult = self.in_mult.to(dev)
        self.dtype = torch.float32

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        if self.in_mult is not None:
            x = x * self.in_mult
        for conv in self.hidden:
            if isinstance(x, QTensor) and not isinstance(conv, QuantConv):
                x = x.dequantize().contiguous(memory_format=_CL)
            x = conv(x)
        if isinstance(x, QTensor):
            x = x.dequantize().contiguous(memory_format=_CL)
        return self.last(x)
