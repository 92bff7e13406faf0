"""Feature normalisation (design 5.2)."""

from __future__ import annotations

import torch

#: Guard on the squared norm of a feature group: an all-zero group gives 0 instead of NaN (the original divides by
#: the plain norm). Squared norms of real features are many orders of magnitude above it.
NORM_SQ_EPS = 1e-30


def grouped_l2_normalize(x: torch.Tensor, groups: int, guard: bool = True) -> torch.Tensor:
    """Split the channels into ``groups`` contiguous groups and divide each group by its per-pixel L2 norm.

    With autograd the backward is hand-written (:class:`_GroupedL2`: two passes over the map instead of autograd's
    chain through the square, sum, clamp, square root and division); the forward is the same ops either way.

    Args:
        x: ``[B, C, H, W]`` with ``C`` divisible by ``groups``.
        groups: number of groups ``K`` (1 = normalise over all channels).
        guard: avoid 0/0 for an all-zero group.
    Returns:
        ``[B, C, H, W]``.
    """
    b, c, h, w = x.shape
    if c % groups:
        raise ValueError(f"{c} channels cannot be split into {groups} groups")
    if (
        torch.is_grad_enabled()
        and x.requires_grad
        and not torch.jit.is_tracing()
        and not torch.onnx.is_in_onnx_export()
    ):
        return _GroupedL2.apply(x, groups, guard)
    return _grouped_l2_forward(x, groups, guard)[0]


def _grouped_l2_forward(x: torch.Tensor, groups: int, guard: bool) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(y, norm, kept)``: the normalised map, the per-pixel group norms ``[B, K, 1, H, W]`` and where the squared
    norm is above the guard (where it depends on ``x``)."""
    b, c, h, w = x.shape
    g = x.reshape(b, groups, c // groups, h, w)
    sq = (g * g).sum(dim=2, keepdim=True)
    kept = sq > NORM_SQ_EPS if guard else None
    if guard:
        sq = sq.clamp_min(NORM_SQ_EPS)
    norm = torch.sqrt(sq)
    return (g / norm).reshape(b, c, h, w), norm, kept


class _GroupedL2(torch.autograd.Function):
    """``y = x / r``, ``r = sqrt(max(sum_group x^2, eps))``; backward
    ``dx = (dy - y * sum_group(dy * y)) / r`` (the second term only where the guard is inactive)."""

    @staticmethod
    def forward(ctx, x, groups, guard):
        y, norm, kept = _grouped_l2_forward(x, groups, guard)
        ctx.save_for_backward(y, norm, kept)
        ctx.groups = groups
        return y

    @staticmethod
    def backward(ctx, gy):
        y, norm, kept = ctx.saved_tensors
        b, c, h, w = y.shape
        yg = y.reshape(b, ctx.groups, c // ctx.groups, h, w)
        gg = gy.reshape(yg.shape)
        dot = (gg * yg).sum(dim=2, keepdim=True)
        if kept is not None:
            dot = dot * kept
        gx = torch.addcmul(gg, yg, dot, value=-1.0).div_(norm)
        return gx.reshape(b, c, h, w), None, None


#: DINL's guards (design 4.2): added to the per-channel variance; the lower bound of the per-pixel norm over channels
#: (the original's ``max(sum z^2, 1e-12)`` under the square root).
DINL_VAR_EPS = 1e-12
DINL_NORM_MIN = 1e-6


def dinl(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """Domain-invariant normalisation (design 4.2) in few passes over the map, with a hand-written backward.

    Per image and channel ``z = (x - mean) / (var + 1e-12)`` (the variance, not the std), then ``n = z / max(|z|,
    1e-6)`` with ``|z|`` the L2 norm over the channels per pixel, then ``weight * n + bias``. Computed in float32 for
    bfloat16 / float16 inputs (the parameters' dtype decides the output's, as ``n * weight + bias`` would).

    Args:
        x: ``[B, C, H, W]`` (any memory format); weight, bias: ``[C]``.
    Returns:
        ``[B, C, H, W]`` in ``promote_types(x.dtype, weight.dtype)``.
    """
    if torch.is_grad_enabled() and (x.requires_grad or weight.requires_grad or bias.requires_grad):
        return _DINL.apply(x, weight, bias)
    return _dinl_forward(x, weight, bias)[0]


def _channel_norm(z: torch.Tensor) -> torch.Tensor:
    """The per-pixel L2 norm over the channels, ``[B, 1, H, W]``: ``torch.linalg.vector_norm`` on channels-last
    maps (and in an ONNX export: one ReduceL2); on NCHW maps, where the norm's kernel walks the strided channel axis
    one pixel at a time (several times slower), the square root of a channel sum of squares accumulated in float64.

    The float64 accumulator keeps the NCHW form as exact as ``vector_norm`` in training: ``z = (x - mean) / (var +
    1e-12)`` spans many orders of magnitude across channels (a channel of tiny variance gives ``|z|`` up to
    ``sqrt(H W) / (2 sqrt(1e-12))``), and the first convolution's gradient, which flows back through this norm, is
    sensitive to a float32 sum's rounding; the float64 sum costs one more cast of a ``[B, 1, H, W]`` map."""
    if torch.onnx.is_in_onnx_export() or (z.dim() == 4 and z.is_contiguous(memory_format=torch.channels_last)):
        return torch.linalg.vector_norm(z, dim=1, keepdim=True)
    return (z * z).sum(dim=1, keepdim=True, dtype=torch.float64).sqrt_().to(z.dtype)


def _dinl_forward(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor):
    dtype = torch.promote_types(torch.promote_types(x.dtype, torch.float32), weight.dtype)
    z = x.to(dtype)
    z = z - z.mean(dim=(2, 3), keepdim=True)
    a = (z * z).mean(dim=(2, 3), keepdim=True).add_(DINL_VAR_EPS).reciprocal_()  # 1 / (var + eps), [B, C, 1, 1]
    z.mul_(a)
    norm = _channel_norm(z)  # [B, 1, H, W]
    r = norm.clamp_min(DINL_NORM_MIN).reciprocal_()
    n = z.mul_(r)
    c = x.shape[1]
    y = torch.addcmul(bias.to(dtype).view(1, c, 1, 1), n, weight.to(dtype).view(1, c, 1, 1))
    return y, n, a, r, norm


class _DINL(torch.autograd.Function):
    """Backward of :func:`dinl`, with ``n = z r`` (``r = 1 / max(|z|, 1e-6)``), ``z = (x - mean) a``
    (``a = 1 / (var + eps)``), ``N = H W``:

    * ``dn = dy weight``; ``dz = r (dn - n sum_c(dn n))`` (the second term only where ``|z| > 1e-6``);
    * ``d(x - mean) = a dz - (2 / N) z sum_p(dz z)`` (through ``a`` and the variance);
    * ``dx = d(x - mean) - mean_p(d(x - mean))``.
    """

    @staticmethod
    def forward(ctx, x, weight, bias):
        y, n, a, r, norm = _dinl_forward(x, weight, bias)
        ctx.save_for_backward(n, a, r, norm > DINL_NORM_MIN, weight)
        ctx.x_dtype = x.dtype
        return y

    @staticmethod
    def backward(ctx, gy):
        n, a, r, active, weight = ctx.saved_tensors
        c = n.shape[1]
        gy = gy.to(n.dtype)
        gw = (gy * n).sum(dim=(0, 2, 3)).to(weight.dtype)
        gb = gy.sum(dim=(0, 2, 3)).to(weight.dtype)
        dn = gy * weight.to(n.dtype).view(1, c, 1, 1)
        proj = (dn * n).sum(dim=1, keepdim=True).mul_(active)
        dz = dn.sub_(n * proj).mul_(r)
        z = n / r
        dzz = (dz * z).sum(dim=(2, 3), keepdim=True).mul_(2.0 / (n.shape[2] * n.shape[3]))
        dc = dz.mul_(a).sub_(z.mul_(dzz))
        dx = dc.sub_(dc.mean(dim=(2, 3), keepdim=True))
        return dx.to(ctx.x_dtype), gw, gb
