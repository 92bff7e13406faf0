"""Pictures for TensorBoard: colourised depth and labels, and a strip RGB | each decoder's maps (true, predicted)."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from ..data.midair.format import PALETTE_7

#: Depth range of the colour map (metres, log scale).
DEPTH_VIS_RANGE = (0.5, 200.0)


def depth_to_rgb(
    depth: torch.Tensor | np.ndarray, lo: float = DEPTH_VIS_RANGE[0], hi: float = DEPTH_VIS_RANGE[1]
) -> np.ndarray:
    """``[H, W]`` metres -> ``[H, W, 3]`` uint8, log scale from ``lo`` (bright) to ``hi`` (dark), "magma" colours.
    Non-finite values are black."""
    from matplotlib import colormaps  # deferred: matplotlib is heavy to import and only needed for TensorBoard images

    d = np.asarray(depth.detach().float().cpu() if isinstance(depth, torch.Tensor) else depth, dtype=np.float64)
    finite = np.isfinite(d)
    x = (np.log(np.clip(np.where(finite, d, hi), lo, hi)) - np.log(lo)) / (np.log(hi) - np.log(lo))
    rgb = colormaps["magma"](1.0 - x)[..., :3]
    rgb[~finite] = 0.0
    return (rgb * 255.0 + 0.5).astype(np.uint8)


def palette(num_classes: int) -> np.ndarray:
    """``[N, 3]`` uint8 colours: the Mid-Air palette (design 10.5) for up to 7 classes, "tab20" beyond."""
    if num_classes <= len(PALETTE_7):
        return PALETTE_7[:num_classes]
    from matplotlib import colormaps  # deferred (see depth_to_rgb)

    cols = colormaps["tab20"](np.arange(num_classes) % 20)[:, :3]
    return (cols * 255.0 + 0.5).astype(np.uint8)


def labels_to_rgb(labels: torch.Tensor | np.ndarray, num_classes: int) -> np.ndarray:
    """``[H, W]`` class indices -> ``[H, W, 3]`` uint8; out-of-range labels are black."""
    lab = np.asarray(labels.detach().cpu() if isinstance(labels, torch.Tensor) else labels).astype(np.int64)
    pal = palette(num_classes)
    ok = (lab >= 0) & (lab < num_classes)
    out = pal[np.clip(lab, 0, num_classes - 1)]
    out[~ok] = 0
    return out


def image_to_rgb(rgb: torch.Tensor) -> np.ndarray:
    """``[3, H, W]`` float (about [0, 1]) -> ``[H, W, 3]`` uint8."""
    x = rgb.detach().float().cpu().clamp(0, 1).permute(1, 2, 0).numpy()
    return (x * 255.0 + 0.5).astype(np.uint8)


def example_strip(rgb: torch.Tensor, panels: Sequence[np.ndarray] = ()) -> np.ndarray:
    """``[H, (1 + n) W, 3]`` uint8: RGB (``[3, H, W]``) then the ``n`` panels (``[H, W, 3]`` uint8, e.g. each decoder's
    true and predicted maps: :meth:`cosemdepth.tasks.DecoderTask.strip_panels`), all at the same size."""
    return np.concatenate([image_to_rgb(rgb), *panels], axis=1)


__all__ = ["DEPTH_VIS_RANGE", "depth_to_rgb", "example_strip", "image_to_rgb", "labels_to_rgb", "palette"]
