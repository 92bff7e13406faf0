"""Per-sequence training augmentations (design 9.3): flips, transpose and colour jitter, drawn once per sequence.

A *sample* is a dict as produced by the readers (one sequence, no batch axis):

* ``rgb`` ``[T, 3, H, W]`` float, ``depth`` ``[T, 1, H, W]`` (optional), ``semantic`` ``[T, H, W]`` (optional);
* ``rot`` ``[T, 4]`` (w, x, y, z) and ``trans`` ``[T, 3]``: relative motion, ``X_prev = R(q) X_curr + t``;
* ``intrinsics`` ``[4] = (fx, fy, cx, cy)`` in pixels, principal point in the convention of design 2.1
  (pixel ``(i, j)`` has centred coordinates ``u = j + 0.5 - cx``, ``v = i + 0.5 - cy``).

Geometric operations (applied in this order, each with its own probability):

=================  =====================  =========================  ===============================================
operation          images                 motion                     intrinsics
=================  =====================  =========================  ===============================================
vertical flip      reverse rows           q -> (w, -x, y, -z),        cy -> H - cy
                                          t -> (tx, -ty, tz)
horizontal flip    reverse columns        q -> (w, x, -y, -z),        cx -> W - cx
                                          t -> (-tx, ty, tz)
transpose          swap H and W           q -> (w, -y, -x, -z),       fx <-> fy and cx <-> cy (a fix, design 9.3;
(square only)                             t -> (ty, tx, tz)           the original swapped neither)
=================  =====================  =========================  ===============================================

Each is the conjugation of the motion by the mirror ``S`` of the camera axes that the image operation applies
(``X' = S X``, ``R' = S R S``, ``t' = S t``), so a flipped sample stays geometrically consistent.

Colour operations, on ``rgb`` only, with TensorFlow ``tf.image`` semantics written out explicitly:

* brightness: ``x + delta``, ``delta ~ U[-0.2, 0.2]``;
* contrast: ``(x - mean) * f + mean``, mean per frame and per channel over H, W, ``f ~ U[0.75, 1.25]``;
* saturation: RGB -> HSV, ``S <- clip(S * f, 0, 1)``, HSV -> RGB, ``f ~ U[0.75, 1.25]``;
* hue: ``H <- (H + delta) mod 1`` keeping each pixel's max and min (TF's hue kernel; unlike an HSV round trip it
  also rotates pixels whose channels are all <= 0), ``delta ~ U[-0.4, 0.4]``;
* inversion ``x -> 1 - x`` with probability 0.5 (in the code, not in the paper).

No clipping follows (design 9.3, reproduced), so values can leave [0, 1]. The HSV conversion follows TF's kernel:
``V = max``, ``S = (max - min) / V`` if ``V > 0`` else 0 (so saturation turns a pixel with all channels <= 0 grey,
as TF does), hue in [0, 1) (0 for gray pixels).

Randomness comes only from the ``torch.Generator`` passed in: the draws are ``torch.rand(8)`` in the order
vflip, hflip, transpose, brightness, contrast, saturation, hue, inversion (all eight are drawn even when an
operation is disabled or impossible, so that the stream of draws does not depend on the image shape).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping

import torch

from ..errors import ConfigError

Sample = dict[str, torch.Tensor]


@dataclass(frozen=True)
class AugmentConfig:
    """Probabilities and ranges of the augmentations. The defaults are the paper's training settings (design 9.3)."""

    p_vflip: float = 0.5
    p_hflip: float = 0.5
    p_transpose: float = 0.5
    brightness: float = 0.2  # delta ~ U[-b, b]
    contrast: tuple[float, float] = (0.75, 1.25)
    saturation: tuple[float, float] = (0.75, 1.25)
    hue: float = 0.4  # delta ~ U[-h, h]
    p_invert: float = 0.5

    def __post_init__(self) -> None:
        for name in ("p_vflip", "p_hflip", "p_transpose", "p_invert"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ConfigError(f"augmentation {name} must be a probability in [0, 1], got {p!r}")
        for name in ("contrast", "saturation"):
            lo, hi = getattr(self, name)
            if not 0.0 <= lo <= hi:
                raise ConfigError(f"augmentation {name} must be a range 0 <= lo <= hi, got {(lo, hi)!r}")
        if self.brightness < 0 or self.hue < 0 or self.hue > 0.5:
            raise ConfigError("augmentation brightness must be >= 0 and hue in [0, 0.5]")

    @classmethod
    def train(cls) -> "AugmentConfig":
        """The paper's training augmentation (design 9.3)."""
        return cls()

    @classmethod
    def finetune(cls) -> "AugmentConfig":
        """The original ``finetune`` mode: no flips/transpose, contrast/saturation in [0.8, 1.2], hue 0.2."""
        return cls(p_vflip=0.0, p_hflip=0.0, p_transpose=0.0, contrast=(0.8, 1.2), saturation=(0.8, 1.2), hue=0.2)

    @classmethod
    def geometric_only(cls) -> "AugmentConfig":
        """Flips and transpose only; colours untouched."""
        return cls(brightness=0.0, contrast=(1.0, 1.0), saturation=(1.0, 1.0), hue=0.0, p_invert=0.0)


def resolve_augment(augment: "bool | str | AugmentConfig | Mapping | None") -> AugmentConfig | None:
    """``False``/``None`` -> no augmentation; ``True``/``"train"`` -> :meth:`AugmentConfig.train`;
    ``"finetune"``; ``"geometric"``; an :class:`AugmentConfig`; or a mapping of its fields."""
    if augment is None or augment is False:
        return None
    if augment is True:
        return AugmentConfig.train()
    if isinstance(augment, AugmentConfig):
        return augment
    if isinstance(augment, str):
        presets = {
            "train": AugmentConfig.train,
            "finetune": AugmentConfig.finetune,
            "geometric": AugmentConfig.geometric_only,
            "none": lambda: None,
        }
        if augment not in presets:
            raise ConfigError(f"augment must be a bool, an AugmentConfig or one of {sorted(presets)}, got {augment!r}")
        return presets[augment]()
    if isinstance(augment, Mapping):
        try:
            return replace(AugmentConfig(), **dict(augment))
        except TypeError as e:
            raise ConfigError(f"bad augment settings {dict(augment)!r}: {e}") from None
    raise ConfigError(f"augment must be a bool, a preset name, an AugmentConfig or a mapping, got {augment!r}")


@dataclass(frozen=True)
class AugmentParams:
    """One draw of the per-sequence augmentation parameters."""

    vflip: bool = False
    hflip: bool = False
    transpose: bool = False
    brightness: float = 0.0
    contrast: float = 1.0
    saturation: float = 1.0
    hue: float = 0.0
    invert: bool = False


def draw_params(cfg: AugmentConfig, generator: torch.Generator, square: bool) -> AugmentParams:
    """Draw the parameters of one sequence (8 uniform numbers from ``generator``; see the module docstring)."""
    u = torch.rand(8, generator=generator, dtype=torch.float64).tolist()

    def between(lo: float, hi: float, x: float) -> float:
        return lo + (hi - lo) * x

    return AugmentParams(
        vflip=u[0] < cfg.p_vflip,
        hflip=u[1] < cfg.p_hflip,
        transpose=square and u[2] < cfg.p_transpose,
        brightness=between(-cfg.brightness, cfg.brightness, u[3]),
        contrast=between(*cfg.contrast, u[4]),
        saturation=between(*cfg.saturation, u[5]),
        hue=between(-cfg.hue, cfg.hue, u[6]),
        invert=u[7] < cfg.p_invert,
    )


# --------------------------------------------------------------------------------------------------------------
# Geometric operations (pure functions; a new dict is returned, the input is not modified)


def _flip_maps(sample: Mapping[str, torch.Tensor], dims_rgb: tuple[int, ...], dims_sem: tuple[int, ...]) -> Sample:
    out = dict(sample)
    out["rgb"] = sample["rgb"].flip(dims_rgb)
    if "depth" in sample:
        out["depth"] = sample["depth"].flip(dims_rgb)
    if "semantic" in sample:
        out["semantic"] = sample["semantic"].flip(dims_sem)
    return out


def vflip(sample: Mapping[str, torch.Tensor]) -> Sample:
    """Reverse the rows: ``q -> (w, -x, y, -z)``, ``t -> (tx, -ty, tz)``, ``cy -> H - cy``."""
    out = _flip_maps(sample, (-2,), (-2,))
    h = sample["rgb"].shape[-2]
    out["rot"] = sample["rot"] * sample["rot"].new_tensor([1.0, -1.0, 1.0, -1.0])
    out["trans"] = sample["trans"] * sample["trans"].new_tensor([1.0, -1.0, 1.0])
    k = sample["intrinsics"].clone()
    k[..., 3] = h - k[..., 3]
    out["intrinsics"] = k
    return out


def hflip(sample: Mapping[str, torch.Tensor]) -> Sample:
    """Reverse the columns: ``q -> (w, x, -y, -z)``, ``t -> (-tx, ty, tz)``, ``cx -> W - cx``."""
    out = _flip_maps(sample, (-1,), (-1,))
    w = sample["rgb"].shape[-1]
    out["rot"] = sample["rot"] * sample["rot"].new_tensor([1.0, 1.0, -1.0, -1.0])
    out["trans"] = sample["trans"] * sample["trans"].new_tensor([-1.0, 1.0, 1.0])
    k = sample["intrinsics"].clone()
    k[..., 2] = w - k[..., 2]
    out["intrinsics"] = k
    return out


def transpose(sample: Mapping[str, torch.Tensor]) -> Sample:
    """Swap H and W: ``q -> (w, -y, -x, -z)``, ``t -> (ty, tx, tz)``, ``fx <-> fy``, ``cx <-> cy``."""
    out = dict(sample)
    out["rgb"] = sample["rgb"].transpose(-1, -2).contiguous()
    if "depth" in sample:
        out["depth"] = sample["depth"].transpose(-1, -2).contiguous()
    if "semantic" in sample:
        out["semantic"] = sample["semantic"].transpose(-1, -2).contiguous()
    q = sample["rot"]
    out["rot"] = torch.stack([q[..., 0], -q[..., 2], -q[..., 1], -q[..., 3]], dim=-1)
    t = sample["trans"]
    out["trans"] = torch.stack([t[..., 1], t[..., 0], t[..., 2]], dim=-1)
    k = sample["intrinsics"]
    out["intrinsics"] = torch.stack([k[..., 1], k[..., 0], k[..., 3], k[..., 2]], dim=-1)
    return out


# --------------------------------------------------------------------------------------------------------------
# Colour operations on [..., 3, H, W] tensors


def adjust_brightness(rgb: torch.Tensor, delta: float) -> torch.Tensor:
    """``x + delta`` (TF ``adjust_brightness``; additive, unlike torchvision)."""
    return rgb + delta


def adjust_contrast(rgb: torch.Tensor, factor: float) -> torch.Tensor:
    """``(x - mean) * factor + mean`` with the mean per image and per channel over H, W (TF ``adjust_contrast``)."""
    mean = rgb.mean(dim=(-2, -1), keepdim=True)
    return (rgb - mean) * factor + mean


def _hue(rgb: torch.Tensor, mx: torch.Tensor, mn: torch.Tensor) -> torch.Tensor:
    """Hue in [0, 1) of ``[..., 3, H, W]`` RGB whose channel max and min are ``mx``, ``mn`` (0 where they are equal)."""
    r, g, b = rgb.unbind(dim=-3)
    rng = mx - mn
    inv = 1.0 / (6 * torch.where(rng > 0, rng, torch.ones_like(rng)))
    h = torch.where(r == mx, (g - b) * inv, torch.where(g == mx, (b - r) * inv + 1.0 / 3.0, (r - g) * inv + 2.0 / 3.0))
    h = torch.where(rng > 0, h, torch.zeros_like(h))
    return torch.where(h < 0, h + 1, h)


def _saturation(mx: torch.Tensor, mn: torch.Tensor) -> torch.Tensor:
    """HSV saturation ``(max - min) / max``, 0 where ``max <= 0``."""
    return torch.where(mx > 0, (mx - mn) / torch.where(mx > 0, mx, torch.ones_like(mx)), torch.zeros_like(mx))


def rgb_to_hsv(rgb: torch.Tensor) -> torch.Tensor:
    """``[..., 3, H, W]`` RGB -> HSV with H in [0, 1) (TF kernel semantics, valid for values outside [0, 1] too)."""
    v = torch.amax(rgb, dim=-3)
    mn = torch.amin(rgb, dim=-3)
    return torch.stack([_hue(rgb, v, mn), _saturation(v, mn), v], dim=-3)


def hsv_to_rgb(hsv: torch.Tensor) -> torch.Tensor:
    """``[..., 3, H, W]`` HSV (H in [0, 1)) -> RGB: chroma ``C = S V``, ``m = V - C``."""
    h, s, v = hsv.unbind(dim=-3)
    c = s * v
    return _hue_chroma_to_rgb(h, c, v - c)


#: Per channel (r, g, b), the offset n of the closed form below, in sixths of the hue circle.
_CHANNEL_OFFSETS = (5.0, 3.0, 1.0)


def _hue_chroma_to_rgb(h: torch.Tensor, c: torch.Tensor, m: torch.Tensor, inverted: bool = False) -> torch.Tensor:
    """Hue ``h`` in [0, 1), chroma ``c = max - min`` and ``m = min`` -> ``[..., 3, H, W]`` RGB, in closed form: channel
    ``n`` is ``m + c (1 - clip(min(k, 4 - k), 0, 1))`` with ``k = (n + 6 h) mod 6`` (the six-sector table of the TF
    kernel: one channel at the max, one at the min, the third interpolated). ``inverted``: ``1 -`` that, in the
    same pass."""
    k = torch.remainder(h.unsqueeze(-3) * 6 + h.new_tensor(_CHANNEL_OFFSETS).view(3, 1, 1), 6)
    t = torch.minimum(k, 4 - k).clamp_(0.0, 1.0)
    top = m + c
    if inverted:
        return torch.addcmul(1.0 - top.unsqueeze(-3), c.unsqueeze(-3), t)
    return torch.addcmul(top.unsqueeze(-3), c.unsqueeze(-3), t, value=-1.0)


def adjust_saturation(rgb: torch.Tensor, factor: float) -> torch.Tensor:
    """HSV saturation times ``factor``, clipped to [0, 1] (TF ``adjust_saturation``)."""
    v = torch.amax(rgb, dim=-3)
    mn = torch.amin(rgb, dim=-3)
    c = (_saturation(v, mn) * factor).clamp(0.0, 1.0) * v
    return _hue_chroma_to_rgb(_hue(rgb, v, mn), c, v - c)


def adjust_hue(rgb: torch.Tensor, delta: float) -> torch.Tensor:
    """Hue plus ``delta``, wrapped to [0, 1), keeping each pixel's max and min (TF ``adjust_hue``).

    TF's hue kernel works on (hue, min, max) rather than HSV, so a pixel whose channels are all <= 0 (possible after
    the brightness shift) keeps its colour and is rotated like any other, where an HSV round trip (S = 0 when
    V <= 0) would turn it grey. For V > 0 both are the same."""
    mx = torch.amax(rgb, dim=-3)
    mn = torch.amin(rgb, dim=-3)
    return _hue_chroma_to_rgb(torch.remainder(_hue(rgb, mx, mn) + delta, 1.0), mx - mn, mn)


def invert(rgb: torch.Tensor) -> torch.Tensor:
    """``1 - x``."""
    return 1.0 - rgb


def adjust_colour(rgb: torch.Tensor, p: AugmentParams) -> torch.Tensor:
    """The colour operations of ``p`` in order (brightness, contrast, saturation, hue, inversion), as the functions
    above applied one after the other, up to float rounding, in fewer passes over the pixels:

    * brightness and contrast are one affine map per frame and channel, ``f x + (1 - f) mean(x) + delta`` (the
      mean of ``x + delta`` is ``mean(x) + delta``);
    * saturation keeps each pixel's hue and max, so saturation and hue share one hue computation: the new chroma
      is ``clip(S f, 0, 1) V`` (``max - min`` when saturation is off: the hue kernel keeps max and min, also for
      pixels with every channel <= 0), the hue is shifted, and the picture is rebuilt once;
    * the inversion ``1 - x`` is folded into the last of these (the affine map, or the rebuild).
    """
    colour = p.saturation != 1.0 or p.hue != 0.0
    invert_now = p.invert and not colour
    x = rgb
    if p.contrast != 1.0:
        f = p.contrast
        shift = rgb.mean(dim=(-2, -1), keepdim=True) * (1.0 - f) + p.brightness
        if invert_now:  # 1 - (f x + shift)
            x = torch.add(1.0 - shift, rgb, alpha=-f)
        else:
            x = torch.add(shift, rgb, alpha=f)
    elif p.brightness != 0.0:
        x = (1.0 - p.brightness) - rgb if invert_now else rgb + p.brightness
    elif invert_now:
        x = 1.0 - rgb
    if not colour:
        return x
    mx = torch.amax(x, dim=-3)
    mn = torch.amin(x, dim=-3)
    h = _hue(x, mx, mn)
    if p.saturation != 1.0:
        c = (_saturation(mx, mn) * p.saturation).clamp_(0.0, 1.0) * mx
        m = mx - c
    else:
        c, m = mx - mn, mn
    if p.hue != 0.0:
        h = torch.remainder(h + p.hue, 1.0)
    return _hue_chroma_to_rgb(h, c, m, inverted=p.invert)


# --------------------------------------------------------------------------------------------------------------


def apply_params(sample: Mapping[str, torch.Tensor], p: AugmentParams) -> Sample:
    """Apply one draw of parameters to a sample (geometric then colour, in the order of design 9.3)."""
    out = dict(sample)
    if p.vflip:
        out = vflip(out)
    if p.hflip:
        out = hflip(out)
    if p.transpose:
        if out["rgb"].shape[-1] != out["rgb"].shape[-2]:
            raise ValueError("transpose augmentation needs square images")
        out = transpose(out)
    out["rgb"] = adjust_colour(out["rgb"], p)
    return out


def augment_sample(sample: Mapping[str, torch.Tensor], cfg: AugmentConfig, generator: torch.Generator) -> Sample:
    """Draw per-sequence parameters from ``generator`` and apply them; returns the augmented sample."""
    h, w = sample["rgb"].shape[-2:]
    return apply_params(sample, draw_params(cfg, generator, square=(h == w)))
