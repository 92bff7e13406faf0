"""Cost volumes of the depth decoder (design 5.5): the parallax-sweeping cost volume (PSCV) and the spatial
neighbourhood cost volume (SNCV).

Both correlate channel groups: for group ``g`` of ``n_g`` channels, ``corr = (1 / n_g) sum_{c in g} a_c b_c``, i.e. the
cosine similarity of normalised group vectors divided by ``n_g``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..geometry.warp import sample_bilinear, sample_bilinear_pixels


def group_correlation(a: torch.Tensor, b: torch.Tensor, groups: int, half: bool = False) -> torch.Tensor:
    """Mean over each channel group of ``a * b``.

    Args:
        a: ``[B, C, ...]``; b: broadcastable to ``a``'s shape with the same C.
        half: multiply in float16 like the original's PSCV (the sum is accumulated in float32 and the mean rounded to
            float16 before casting back).
    Returns:
        ``[B, groups, ...]`` in ``a``'s dtype.
    """
    c = a.shape[1]
    n = c // groups
    if half:
        prod = (a.half() * b.half()).float()
        out = prod.unflatten(1, (groups, n)).sum(dim=2) / n
        return out.half().to(a.dtype)
    prod = a * b
    return prod.unflatten(1, (groups, n)).mean(dim=2)


#: Maps smaller than this (the coarse levels: many channels, few pixels) correlate in the product form (one
#: ``[B, C, S, H, W]`` product, then the group means); larger ones in the channel loop, which was the faster of the
#: two there while the product form won on the small maps.
PSCV_LOOP_MIN_PIXELS = 1024


def parallax_sweep_cost_volume(
    feat: torch.Tensor,
    prev: torch.Tensor,
    points: torch.Tensor,
    groups: int,
    half: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """PSCV: correlate the current features with the previous ones warped along the parallax hypotheses.

    The previous features and the previous parallax are warped together, with one bilinear sampling call for all
    hypotheses (they are stacked along the sampled grid's rows).

    Args:
        feat: ``[B, C, H, W]`` current normalised features.
        prev: ``[B, C + 1, H, W]`` previous normalised features with the previous parallax as last channel.
        points: ``[B, S, 2, H, W]`` sampling positions (x, y) in the previous frame, one per hypothesis.
        groups: number of channel groups ``K``.
        half: float16 products like the original.
    Returns:
        ``pscv [B, K*S, H, W]`` with channel ``g*S + s`` (group-major), and ``warped_parallax [B, S, H, W]``.
    """
    b, c, h, w = feat.shape
    s = points.shape[1]
    pts = points.permute(0, 2, 1, 3, 4).reshape(b, 2, s * h, w)
    if torch.onnx.is_in_onnx_export() and not half:
        return _sweep_correlation_traceable(feat, prev, pts, groups)
    # channels-last input: the CPU sampler reads each tap's C + 1 values contiguously (several times faster here)
    warped = sample_bilinear(prev.contiguous(memory_format=torch.channels_last), pts).contiguous()
    warped = warped.view(b, c + 1, s, h, w)
    if half or torch.onnx.is_in_onnx_export() or h * w < PSCV_LOOP_MIN_PIXELS:
        # the product form: float16 products like the original / plain traceable ops / small maps
        corr = group_correlation(feat.unsqueeze(2), warped[:, :c], groups, half=half)  # [B,K,S,H,W]
        return corr.reshape(b, groups * s, h, w), warped[:, c]
    if torch.is_grad_enabled() and (feat.requires_grad or warped.requires_grad):
        return _SweepCorrelation.apply(feat, warped, groups)
    return _sweep_correlation_loop(feat, warped, groups), warped[:, c]


def _sweep_correlation_traceable(
    feat: torch.Tensor, prev: torch.Tensor, pts: torch.Tensor, groups: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """The PSCV of :func:`parallax_sweep_cost_volume` (``pts``: its points stacked as ``[B, 2, S*H, W]``) as plain
    traceable ops: the form the ONNX export records. The warped maps stay channels-last, as the row gathers give
    them, so that each group's mean reduces the innermost axis; only the small volume is transposed."""
    b, c, h, w = feat.shape
    s = pts.shape[2] // h
    n = c // groups
    warped = sample_bilinear_pixels(prev, pts).reshape(b, s, h, w, c + 1)
    fcl = feat.permute(0, 2, 3, 1).reshape(b, 1, h, w, groups, n)
    corr = (warped[..., :c].reshape(b, s, h, w, groups, n) * fcl).mean(dim=-1)  # [B, S, H, W, K]
    return corr.permute(0, 4, 1, 2, 3).reshape(b, groups * s, h, w), warped[..., c]


def _sweep_correlation_loop(feat: torch.Tensor, warped: torch.Tensor, groups: int) -> torch.Tensor:
    """``feat [B, C, H, W]``, ``warped [B, C + 1, S, H, W]`` -> ``[B, K*S, H, W]`` group means of ``feat * warped``
    (group-major), one channel at a time (``out[g] += warped[c] * feat[c]``), in the promoted dtype."""
    b, c, h, w = feat.shape
    s = warped.shape[2]
    n = c // groups
    dtype = torch.promote_types(torch.promote_types(feat.dtype, warped.dtype), torch.float32)
    f = feat.to(dtype).contiguous()
    wp = warped.to(dtype)
    corr = f.new_zeros(b, groups, s, h, w)
    for ch in range(c):
        corr[:, ch // n].addcmul_(wp[:, ch], f[:, ch, None])
    return corr.mul_(1.0 / n).view(b, groups * s, h, w)


class _SweepCorrelation(torch.autograd.Function):
    """``(feat [B, C, H, W], warped [B, C + 1, S, H, W]) -> (pscv [B, K*S, H, W], warped[:, C])`` by
    :func:`_sweep_correlation_loop`. Backward: ``d feat_c = (1/n) sum_s G[g, s] warped_{c, s}``,
    ``d warped_{c, s} = (1/n) G[g, s] feat_c``, written with the parallax channel's gradient into one buffer."""

    @staticmethod
    def forward(ctx, feat, warped, groups):
        c = feat.shape[1]
        ctx.save_for_backward(feat, warped)
        ctx.groups = groups
        return _sweep_correlation_loop(feat, warped, groups), warped[:, c].clone()

    @staticmethod
    def backward(ctx, g_corr, g_para):
        feat, warped = ctx.saved_tensors
        groups = ctx.groups
        b, c, h, w = feat.shape
        s = warped.shape[2]
        n = c // groups
        dtype = torch.promote_types(torch.promote_types(feat.dtype, warped.dtype), torch.float32)
        f = feat.to(dtype).contiguous().view(b, groups, n, 1, h, w)
        g = g_corr.to(dtype).reshape(b, groups, 1, s, h, w) * (1.0 / n)
        g_feat = g_warped = None
        if ctx.needs_input_grad[1]:
            g_warped = torch.empty(b, c + 1, s, h, w, dtype=warped.dtype)
            torch.mul(g, f, out=g_warped[:, :c].view(b, groups, n, s, h, w))
            if g_para is None:
                g_warped[:, c].zero_()
            else:
                g_warped[:, c].copy_(g_para)
        if ctx.needs_input_grad[0]:
            wv = warped[:, :c].to(dtype).view(b, groups, n, s, h, w)
            g_feat = (wv * g).sum(dim=3).view(b, c, h, w).to(feat.dtype)
        return g_feat, g_warped, None


def spatial_cost_volume(feat: torch.Tensor, groups: int, radius: int = 3, negative_slope: float = 0.1) -> torch.Tensor:
    """SNCV: self-correlation of the features over a ``(2r+1)^2`` window with zero padding, then LeakyReLU.

    ``corr[o, g](p) = (1 / n_g) sum_{c in g} f_c(p) f_c(p + d_o)`` for the window offsets ``d_o``, zero where
    ``p + d_o`` leaves the image. Runs the channel loop of :func:`spatial_cost_volume_fast`, with gradients through
    a backward that loops over the window offsets (memory: the output only); the ONNX export traces the same sums as
    plain ops instead. Low-precision inputs (bfloat16 / float16 under autocast) are correlated in float32 and the
    result rounded once to their dtype.

    Args:
        feat: ``[B, C, H, W]`` normalised features.
        groups: number of channel groups ``K``.
        radius: search range ``r`` (3 gives a 7x7 window).
    Returns:
        ``[B, (2r+1)^2 * K, H, W]`` with channel ``((dy + r)(2r + 1) + (dx + r)) * K + g`` (offset-major).
    """
    b, c, h, w = feat.shape
    if c % groups:
        raise ValueError(f"{c} channels cannot be split into {groups} groups")
    if torch.onnx.is_in_onnx_export():  # plain ops the exporter traces (no strided views, no writes into slices)
        vol = _spatial_correlation_traceable(feat, groups, radius)
    elif torch.is_grad_enabled() and feat.requires_grad:
        vol = _SpatialCorrelation.apply(feat, groups, radius)
    else:  # the same loop without autograd bookkeeping
        vol = _sncv_channel_loop(feat.to(_compute_dtype(feat.dtype)).contiguous(), groups, radius).to(feat.dtype)
    return F.leaky_relu(vol, negative_slope)


def _spatial_correlation_traceable(feat: torch.Tensor, groups: int, radius: int) -> torch.Tensor:
    """``[B, C, H, W] -> [B, (2r+1)^2 * K, H, W]`` group-mean correlation, offset-major, before the activation, as
    plain traceable ops: the form the ONNX export records. Channels-last, so that every window offset's group sums
    reduce the innermost, contiguous axis (ONNX Runtime reduces a middle axis several times slower)."""
    b, c, h, w = feat.shape
    n = c // groups
    k = 2 * radius + 1
    f = feat.permute(0, 2, 3, 1)  # [B, H, W, C]
    padded = F.pad(f, (0, 0, radius, radius, radius, radius))
    fv = f.reshape(b, h, w, groups, n)
    out = torch.cat(
        [
            (padded[:, i : i + h, j : j + w].reshape(b, h, w, groups, n) * fv).sum(dim=-1)
            for i in range(k)
            for j in range(k)
        ],
        dim=-1,
    )  # [B, H, W, k*k*K], offset-major
    return out.permute(0, 3, 1, 2) * (1.0 / n)


def _compute_dtype(dtype: torch.dtype) -> torch.dtype:
    """float32 for bfloat16 / float16 inputs, the input's dtype otherwise (float32, float64)."""
    return torch.promote_types(dtype, torch.float32)


class _SpatialCorrelation(torch.autograd.Function):
    """``[B, C, H, W] -> [B, (2r+1)^2 * K, H, W]`` group-mean correlation with the window offsets (no activation),
    offset-major; forward by the channel loop of :func:`spatial_cost_volume_fast`.

    Backward: ``dL/df_c(q) = (1/n) [ sum_o G[o,g](q) f_c(q + d_o) + sum_o G[o,g](q - d_o) f_c(q - d_o) ]``; renaming
    ``o -> -o`` in the second sum gives ``(1/n) sum_o H[o,g](q) f_c(q + d_o)`` with ``H[o](q) = G[o](q) + G[-o](q +
    d_o)`` (zero where ``q + d_o`` leaves the image): ``H`` is one addition of ``G`` and a strided view of the
    offset-mirrored, zero-padded ``G``; then one in-place multiply-add per offset, reading the padded features
    shifted by ``d_o``.
    """

    @staticmethod
    def forward(ctx, feat: torch.Tensor, groups: int, radius: int) -> torch.Tensor:
        f = feat.to(_compute_dtype(feat.dtype)).contiguous()
        out = _sncv_channel_loop(f, groups, radius)
        ctx.save_for_backward(feat)
        ctx.groups, ctx.radius = groups, radius
        return out.to(feat.dtype)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (feat,) = ctx.saved_tensors
        groups, r = ctx.groups, ctx.radius
        b, c, h, w = feat.shape
        n = c // groups
        k = 2 * r + 1
        f = feat.to(_compute_dtype(feat.dtype)).contiguous()
        g = grad.to(f.dtype).reshape(b, k, k, groups, h, w)
        # mirror[b, i, j, g, y, x] = G[-o](q + d_o) for o = (i, j), d_o = (i - r, j - r), q = (y, x)
        gp = F.pad(g.flip(1, 2), (r, r, r, r))
        s0, s1, s2, s3, s4, s5 = gp.stride()
        mirror = gp.as_strided((b, k, k, groups, h, w), (s0, s1 + s4, s2 + s5, s3, s4, s5), gp.storage_offset())
        hh = (g + mirror).unsqueeze(4)  # H: [B, k, k, K, 1, H, W]
        fpad = F.pad(f, (r, r, r, r)).view(b, groups, n, h + 2 * r, w + 2 * r)
        out = f.new_zeros(b, groups, n, h, w)
        for i in range(k):
            for j in range(k):
                out.addcmul_(hh[:, i, j], fpad[..., i : i + h, j : j + w])  # H_o(q) f(q + d_o)
        return out.view(b, c, h, w).mul_(1.0 / n).to(feat.dtype), None, None


def _sncv_channel_loop(f: torch.Tensor, groups: int, radius: int) -> torch.Tensor:
    """``[B, C, H, W]`` (contiguous) ``-> [B, (2r+1)^2 * K, H, W]`` group-mean correlation, offset-major, before the
    activation: the loop of :func:`spatial_cost_volume_fast`."""
    b, c, h, w = f.shape
    n = c // groups
    k = 2 * radius + 1
    padded = F.pad(f, (radius, radius, radius, radius))
    s_b, s_c, s_h, s_w = padded.stride()
    # window[b, c, i, j, y, x] = padded[b, c, y + radius + i, x + j]: offsets dy = i >= 0, dx = j - radius.
    window = padded.as_strided(
        (b, c, radius + 1, k, h, w), (s_b, s_c, s_h, s_w, s_h, s_w), padded.storage_offset() + radius * s_h
    )
    out = f.new_zeros(b, k, k, groups, h, w)
    half = out[:, radius:].permute(0, 3, 1, 2, 4, 5)  # [B, K, r+1, 2r+1, H, W] view: accumulate in place
    for ch in range(c):
        half[:, ch // n].addcmul_(window[:, ch], f[:, ch, None, None])
    for dy in range(1, radius + 1):
        if dy >= h:
            continue  # every target pixel would be outside the image: stays zero
        for dx in range(-radius, radius + 1):
            x0, x1 = max(dx, 0), w + min(dx, 0)
            if x1 <= x0:
                continue
            # out[-dy, -dx][y, x] = out[dy, dx][y - dy, x - dx]
            out[:, radius - dy, radius - dx, :, dy:, x0:x1] = out[
                :, radius + dy, radius + dx, :, : h - dy, x0 - dx : x1 - dx
            ]
    return out.reshape(b, k * k * groups, h, w).mul_(1.0 / n)


def spatial_cost_volume_fast(
    feat: torch.Tensor, groups: int, radius: int = 3, negative_slope: float = 0.1
) -> torch.Tensor:
    """The SNCV of :func:`spatial_cost_volume` (same values up to float rounding, same channel order), faster.

    Instead of one multiply and one group mean per window offset (``(2r+1)^2`` Python iterations over the whole
    map), it loops over the channels: every channel adds its products for all offsets at once, read from a
    zero-copy strided window view of the padded features. It computes only the offsets with ``dy >= 0`` and mirrors
    the others, using ``corr_{-d}(p) = corr_d(p - d)`` (zero where ``p - d`` leaves the image, as the zero padding
    gives). The training forward (:func:`spatial_cost_volume` with gradients) runs the same loop.

    Args:
        feat: ``[B, C, H, W]`` normalised features (any memory format).
        groups: number of channel groups ``K``.
        radius: search range ``r``.
    Returns:
        ``[B, (2r+1)^2 * K, H, W]``, channel ``((dy + r)(2r + 1) + (dx + r)) * K + g``, contiguous (NCHW).
    """
    c = feat.shape[1]
    if c % groups:
        raise ValueError(f"{c} channels cannot be split into {groups} groups")
    return F.leaky_relu_(_sncv_channel_loop(feat.contiguous(), groups, radius), negative_slope)
