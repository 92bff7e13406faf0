"""Per-frame tensors shared by the readers: image -> tensor conversion, resizing rules and intrinsics.

Resizing rules (design 10.6, 3.1-3.4): colour and metric depth use BL2 (TF2 bilinear, half-pixel centres, no
antialias); label maps use a nearest rule chosen by the reader (NN1 = OpenCV/legacy-TF nearest for Mid-Air, whose
labels the authors resized with OpenCV; NN2 = TF2 half-pixel nearest for TopAir/Aeroscapes, whose loaders call
``tf.image.resize(..., "nearest")``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from ..errors import ConfigError
from ..operating_point import size_for_focal
from ..ops.resample import resize_bl2, resize_nn1, resize_nn2

Size = tuple[int, int]

NEAREST = {"nn1": resize_nn1, "nn2": resize_nn2}


def as_size(size: int | tuple[int, int] | list[int] | None, what: str = "size") -> Size | None:
    """``int`` -> ``(s, s)``; ``(H, W)`` -> ``(H, W)``; ``None`` stays ``None``. Raises ConfigError otherwise."""
    if size is None:
        return None
    if isinstance(size, (int, np.integer)) and not isinstance(size, bool):
        h = w = int(size)
    elif isinstance(size, (tuple, list)) and len(size) == 2 and all(isinstance(s, (int, np.integer)) for s in size):
        h, w = int(size[0]), int(size[1])
    else:
        raise ConfigError(f"{what} must be an int or a pair (H, W) of ints, got {size!r}")
    if h < 1 or w < 1:
        raise ConfigError(f"{what} must be positive, got {size!r}")
    return h, w


@dataclass(frozen=True)
class FocalSize:
    """A size rule instead of a size: the output size at which the input's horizontal focal length is ``focal_px``
    pixels, keeping the input's aspect ratio (:func:`cosemdepth.operating_point.size_for_focal`). Every reader
    applies it to its own camera: ``open_dataset("synthair", root, size=FocalSize(64.0))`` opens a split at the
    size where its 90-degree camera has a focal length of 64 px (128x128 for square images)."""

    focal_px: float

    def __post_init__(self) -> None:
        f = self.focal_px
        if isinstance(f, bool) or not isinstance(f, (int, float)) or not np.isfinite(f) or f <= 0:
            raise ConfigError(f"FocalSize needs a positive focal length in pixels, got {f!r}")

    def __call__(self, native: Size, native_fx: float) -> Size:
        return size_for_focal(native, native_fx, float(self.focal_px))


def resolve_size(size, native: Callable[[], tuple[Size, float]], what: str = "size") -> Size | None:
    """A reader's output size: ``size`` as :func:`as_size` takes it, or a :class:`FocalSize` applied to the native
    camera; ``native()`` gives ``((H, W), fx)`` of the native images (called only for a rule)."""
    if isinstance(size, FocalSize):
        shape, fx = native()
        return size(shape, fx)
    return as_size(size, what)


def midair_intrinsics(size: Size) -> torch.Tensor:
    """Intrinsics ``[4] = (fx, fy, cx, cy)`` of a 90-degree-FOV centred pinhole at ``size = (H, W)`` (design 2.1):
    ``fx = W/2, fy = H/2, cx = W/2, cy = H/2``."""
    h, w = size
    return torch.tensor([w / 2, h / 2, w / 2, h / 2], dtype=torch.float32)


#: Full scale of the colour images the readers return, by dtype: 8-bit and 16-bit images map to the same 0..1.
RGB_FULL_SCALE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}


def rgb_to_tensor(rgb: np.ndarray, size: Size | None) -> torch.Tensor:
    """``[H, W, 3]`` uint8 or uint16 -> ``[3, H', W']`` float32 in [0, 1] (``/255`` or ``/65535``, then BL2 to
    ``size``)."""
    rgb = np.ascontiguousarray(rgb)
    scale = RGB_FULL_SCALE.get(rgb.dtype)
    if scale is None:
        raise TypeError(f"colour images must be uint8 or uint16, got {rgb.dtype}")
    x = torch.from_numpy(rgb.astype(np.int32) if rgb.dtype == np.uint16 else rgb).permute(2, 0, 1)
    x = x.to(torch.float32).div_(scale)
    if size is not None and tuple(x.shape[-2:]) != tuple(size):
        x = resize_bl2(x[None], size)[0]
    return x.contiguous()


def depth_to_tensor(depth: np.ndarray | torch.Tensor, size: Size | None, rule: str = "bl2") -> torch.Tensor:
    """``[H, W]`` float depth (metres; an array or a tensor) -> ``[1, H', W']`` float32, resized with BL2 (or
    ``"nn1"``/``"nn2"``)."""
    if isinstance(depth, torch.Tensor):
        x = depth.to(torch.float32).contiguous()[None]
    else:
        x = torch.from_numpy(np.ascontiguousarray(depth, dtype=np.float32))[None]
    if size is not None and tuple(x.shape[-2:]) != tuple(size):
        x = resize_bl2(x[None], size)[0] if rule == "bl2" else NEAREST[rule](x, size)
    return x.contiguous()


#: Label dtypes the nearest resize gathers as they are (torch has them); others are widened first.
_GATHER_DTYPES = (np.dtype(np.uint8), np.dtype(np.int16), np.dtype(np.int32), np.dtype(np.int64))


def labels_to_tensor(labels: np.ndarray, size: Size | None, rule: str) -> torch.Tensor:
    """``[H, W]`` integer labels -> ``[H', W']`` int64, nearest-resized with ``rule`` (``"nn1"`` or ``"nn2"``).
    The resize picks pixels, so it runs on the stored integers and only its output is widened to int64."""
    labels = np.ascontiguousarray(labels)
    if labels.dtype not in _GATHER_DTYPES:
        labels = labels.astype(np.int32 if labels.dtype.itemsize <= 2 else np.int64)
    x = torch.from_numpy(labels)
    if size is not None and tuple(x.shape) != tuple(size):
        x = NEAREST[rule](x, size)
    return x.to(torch.int64).contiguous()
