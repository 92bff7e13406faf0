"""Pictures and videos: colour maps and the 16-bit depth PNG (:mod:`~cosemdepth.render.visualize`), the side-by-side
frames, colour bar and legend of ``predict`` and ``demo`` (:mod:`~cosemdepth.render.figures`), and the training
pictures of TensorBoard (:mod:`~cosemdepth.render.examples`).

Attributes are imported lazily (importing the package loads none of its modules)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "FlightPictures": ".figures",
    "frame_maps": ".figures",
    "VideoWriter": ".visualize",
    "colorize_depth": ".visualize",
    "colorize_labels": ".visualize",
    "save_png": ".visualize",
    "example_strip": ".examples",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
