"""The pictures of a flight's predictions: one layout for the side-by-side pictures, the videos and the demo's
qualitative strip.

A frame is drawn as::

    +-------------------------------------------------------------------------------------------+
    |   RGB   | predicted depth | ground-truth depth | predicted labels | ground-truth labels    |  captions
    +---------+-----------------+--------------------+------------------+------------------------+
    | (image) |     (depth)     |      (depth)       |     (labels)     |       (labels)         |  one row per frame
    +---------+-----------------+--------------------+------------------+------------------------+
    |         | colour bar in metres (0 .. far)      | class legend (names and colours)          |  footer
    +-------------------------------------------------------------------------------------------+

Panels that a flight does not have (no ground truth, a depth-only or labels-only model) are left out; the order of
the others is always :data:`PANELS`. Every panel is upscaled by an integer factor to at least :data:`MIN_PANEL` pixels
on its shorter side (less for maps of extreme aspect ratios: at most :data:`MAX_UPSCALED_PANEL` pixels a panel, never
smaller than the map): labels by nearest neighbour (class borders stay sharp), RGB and depth bilinearly. Depth is colour
mapped linearly with matplotlib's ``turbo`` from ``near`` (red) to ``far`` (dark blue); depths beyond ``far`` (the
sky, the far background) show in the colour of ``far``. Depth pixels the prediction does not estimate (its validity
mask: reset frames, too little camera motion, ill-conditioned geometry) are drawn in :data:`INVALID_COLOR` (grey),
and the frame's title says when it has no estimate (``reset``) or carries its reference frame's (``held``). The range is fixed for a whole flight (colours compare across
frames) and chosen from its first frames by :func:`auto_depth_range` unless given; the colour bar states it.

:class:`FlightFigure` draws frames of one flight (the caption strip and the footer are drawn once and reused);
:class:`FlightPictures` chooses the depth range from the first frames of a stream and then draws every frame.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..defaults import DEPTH_CAP_M
from .visualize import depth_positions, positions_to_rgb, rgb_to_uint8

#: Panel keys and captions, in the order they are drawn (both in pictures and videos).
PANELS: tuple[tuple[str, str], ...] = (
    ("rgb", "RGB"),
    ("depth", "predicted depth"),
    ("gt_depth", "ground-truth depth"),
    ("labels", "predicted labels"),
    ("gt_labels", "ground-truth labels"),
)
CAPTIONS = dict(PANELS)
DEPTH_KEYS = ("depth", "gt_depth")
LABEL_KEYS = ("labels", "gt_labels")
#: Smallest side of a drawn panel, pixels.
MIN_PANEL = 384
#: Most pixels the upscaling makes of one panel: a map of an extreme aspect ratio (100000x8) is upscaled less (down to
#: not at all), so that its pictures stay the size of its maps instead of growing by the square of the factor.
MAX_UPSCALED_PANEL = 2048 * 2048
#: Depth colour map (reversed: near is red, far is dark blue).
DEPTH_CMAP = "turbo"
#: Depths above this are left out when choosing a flight's range (the evaluation cap: sky and far background).
AUTO_RANGE_CAP_M = DEPTH_CAP_M
#: Percentile of a flight's first depths (those below the cap) that sets the far end of the colour scale.
AUTO_RANGE_PERCENTILE = 90.0
#: Frames looked at before the range of a flight is fixed.
WARMUP_FRAMES = 8

BACKGROUND = (24, 24, 24)
#: The colour of predicted-depth pixels without an estimate (the validity mask); no turbo colour is grey.
INVALID_COLOR = (128, 128, 128)
FOREGROUND = (235, 235, 235)
GAP = 4


# ---------------------------------------------------------------------------------------------------- text


@functools.lru_cache(maxsize=16)
def font(size: int):
    """DejaVu Sans (matplotlib's copy) at ``size`` pixels; Pillow's default font when it is missing."""
    try:
        import matplotlib  # deferred: heavy, only for the font file; Pillow's font when it is missing

        return ImageFont.truetype(os.path.join(matplotlib.get_data_path(), "fonts", "ttf", "DejaVuSans.ttf"), size)
    except Exception:  # noqa: BLE001 - no matplotlib or no font file: Pillow's own font
        return ImageFont.load_default(size)


def text_size(text: str, size: int) -> tuple[int, int]:
    """Width and height in pixels of ``text`` in :func:`font` ``(size)``."""
    x0, y0, x1, y1 = font(size).getbbox(text)
    return x1 - x0, y1 - y0


def _draw_text(draw, xy: tuple[float, float], text: str, size: int, anchor: str = "la", fill=FOREGROUND) -> None:
    draw.text(xy, text, font=font(size), fill=fill, anchor=anchor)


# ---------------------------------------------------------------------------------------------------- scales


def nice_ceil(x: float) -> float:
    """The smallest of 1, 1.5, 2, 2.5, 3, 4, 5, 6, 8 x 10^k that is >= ``x`` (``x`` > 0)."""
    if not x > 0 or not math.isfinite(x):
        raise ValueError(f"nice_ceil needs a positive finite number, got {x}")
    k = math.floor(math.log10(x))
    for m in (1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0):
        v = m * 10.0**k
        if v >= x * (1 - 1e-12):
            return float(round(v, 10))
    return float(10.0 ** (k + 1))


def auto_depth_range(
    depths: Sequence[np.ndarray], cap: float = AUTO_RANGE_CAP_M, percentile: float = AUTO_RANGE_PERCENTILE
) -> tuple[float, float]:
    """The colour range ``(0, far)`` of a flight from some of its depth maps (metres).

    ``far`` is the ``percentile`` of the finite positive depths at most ``cap`` (the sky and the far background are
    left out), rounded up by :func:`nice_ceil`. When fewer than 5 % of the depths are below ``cap`` (a high flight),
    the percentile of all finite positive depths is used; with no such depth at all, ``(0, cap)``.
    """
    vals = [np.asarray(d, dtype=np.float64).ravel() for d in depths]
    v = np.concatenate(vals) if vals else np.zeros(0)
    v = v[np.isfinite(v) & (v > 0)]
    if v.size == 0:
        return 0.0, float(cap)
    near_ones = v[v <= cap]
    pool = near_ones if near_ones.size >= 0.05 * v.size else v
    return 0.0, nice_ceil(max(float(np.percentile(pool, percentile)), 1e-3))


def depth_ticks(near: float, far: float, max_ticks: int = 7) -> list[float]:
    """Round tick values from ``near`` to ``far`` at most ``max_ticks`` (about), ``far`` always the last one."""
    span = far - near
    for step in (m * 10.0**k for k in range(-2, 6) for m in (1, 2, 2.5, 5)):
        if span / step <= max_ticks - 1 + 1e-9:
            break
    first = math.ceil(near / step - 1e-9) * step
    ticks = []
    t = first
    while t <= far + 1e-9 * max(1.0, abs(far)):
        ticks.append(round(t, 6))
        t += step
    if not ticks or abs(ticks[-1] - far) > 1e-9 * max(1.0, abs(far)):  # the far end is always labelled
        if ticks and far - ticks[-1] < 0.5 * step:
            ticks.pop()
        ticks.append(float(far))
    return ticks


def _fmt_m(v: float) -> str:
    return f"{v:g}"


# ---------------------------------------------------------------------------------------------------- resizing


def panel_scale(height: int, width: int, min_panel: int = MIN_PANEL, max_pixels: int = MAX_UPSCALED_PANEL) -> int:
    """The integer upscaling factor that brings the shorter side of a ``height x width`` map to >= ``min_panel``,
    reduced (to 1 at least) while the upscaled panel would have more than ``max_pixels`` pixels."""
    k = max(1, math.ceil(min_panel / max(1, min(height, width))))
    if k > 1 and height * width * k * k > max_pixels:
        k = max(1, math.isqrt(max_pixels // max(1, height * width)))
    return k


def upscale_nearest(a: np.ndarray, k: int) -> np.ndarray:
    """Each pixel of ``a`` (``[H, W, ...]``) repeated ``k`` x ``k`` times."""
    if k == 1:
        return a
    return np.repeat(np.repeat(a, k, axis=0), k, axis=1)


def upscale_bilinear(a: np.ndarray, k: int) -> np.ndarray:
    """Bilinear upscaling by ``k`` (pixel centres aligned, edges clamped) of a ``[H, W]`` float or ``[H, W, 3]``
    uint8 array."""
    if k == 1:
        return a
    h, w = a.shape[:2]
    if a.ndim == 2:
        img = Image.fromarray(np.ascontiguousarray(a, dtype=np.float32), mode="F")
        return np.asarray(img.resize((w * k, h * k), Image.Resampling.BILINEAR), dtype=np.float32)
    img = Image.fromarray(np.ascontiguousarray(a, dtype=np.uint8))
    return np.asarray(img.resize((w * k, h * k), Image.Resampling.BILINEAR))


# ---------------------------------------------------------------------------------------------------- the figure


@dataclass
class FrameMaps:
    """The maps of one frame, at the model's resolution: ``rgb [H, W, 3]`` uint8; ``depth``/``gt_depth`` ``[H, W]``
    metres; ``labels``/``gt_labels`` ``[H, W]`` class indices; ``title``: drawn on the RGB panel (e.g. the frame);
    ``reset``: the first frame of a trajectory (its depth is the initial value, not a prediction); ``valid``:
    ``[H, W]`` bool, the predicted depth pixels that are estimates (None: all); ``status``: ``"estimated"``,
    ``"held"`` or ``"reset"`` (:mod:`cosemdepth.inference.policy`), or ``""``."""

    rgb: np.ndarray
    depth: np.ndarray | None = None
    gt_depth: np.ndarray | None = None
    labels: np.ndarray | None = None
    gt_labels: np.ndarray | None = None
    title: str = ""
    reset: bool = False
    valid: np.ndarray | None = None
    status: str = ""

    def keys(self) -> tuple[str, ...]:
        return tuple(k for k, _ in PANELS if getattr(self, k) is not None)


class FlightFigure:
    """The layout of one flight's pictures (see the module docstring): which panels, their size, the depth range,
    the classes. :meth:`frame` draws one frame (the picture and the video frame are the same image); :meth:`rows`
    draws several frames under one caption strip and one footer (the demo's qualitative strip).

    Args:
        keys: the panels (a subset of :data:`PANELS`' keys; drawn in :data:`PANELS`' order).
        size: ``(H, W)`` of the maps. depth_range: ``(near, far)`` metres. class_names, palette ``[N, 3]``: the
            legend and the label colours (needed when a label panel is drawn).
        min_panel: smallest side of a drawn panel.

    Attributes (pixels of a one-frame picture, ``(x0, y0, x1, y1)``, end excluded): ``colorbar_box`` (None without
    depth panels) and ``legend_boxes``, ``[(class index, swatch box), ...]`` in legend order.
    """

    def __init__(
        self,
        keys: Sequence[str],
        size: tuple[int, int],
        *,
        depth_range: tuple[float, float] = (0.0, DEPTH_CAP_M),
        class_names: Sequence[str] = (),
        palette: np.ndarray | None = None,
        min_panel: int = MIN_PANEL,
    ) -> None:
        unknown = [k for k in keys if k not in CAPTIONS]
        if unknown:
            raise ValueError(f"unknown panels {unknown}; known: {list(CAPTIONS)}")
        self.keys = tuple(k for k, _ in PANELS if k in keys)
        if not self.keys:
            raise ValueError("a figure needs at least one panel")
        near, far = (float(x) for x in depth_range)
        if not (math.isfinite(near) and math.isfinite(far) and far > near):
            raise ValueError(f"depth range must be finite with far > near, got {depth_range}")
        self.depth_range = (near, far)
        self.has_depth = any(k in DEPTH_KEYS for k in self.keys)
        self.has_labels = any(k in LABEL_KEYS for k in self.keys)
        if self.has_labels and palette is None:
            raise ValueError("label panels need a palette")
        self.class_names = tuple(class_names)
        self.palette = None if palette is None else np.asarray(palette, dtype=np.uint8)
        if self.has_labels and self.class_names and len(self.class_names) != len(self.palette):
            raise ValueError(f"{len(self.class_names)} class names for a palette of {len(self.palette)} colours")
        self.map_size = (int(size[0]), int(size[1]))
        self.scale = panel_scale(*self.map_size, min_panel=min_panel)
        self.panel_size = (self.map_size[0] * self.scale, self.map_size[1] * self.scale)
        ph, pw = self.panel_size
        self.width = len(self.keys) * pw + (len(self.keys) - 1) * GAP
        self.font_size = max(14, min(40, round(pw / 19)))
        self.small_size = max(12, round(self.font_size * 0.8))
        self.caption_height = round(self.font_size * 1.9)
        self.x = {k: i * (pw + GAP) for i, k in enumerate(self.keys)}
        self._caption = self._draw_captions()
        self._footer = self._draw_footer()
        top = self.caption_height + self.panel_size[0] + GAP  # the footer's first row in a one-frame picture
        if self.colorbar_box is not None:
            x0, y0, x1, y1 = self.colorbar_box
            self.colorbar_box = (x0, y0 + top, x1, y1 + top)
        self.legend_boxes = [(i, (x0, y0 + top, x1, y1 + top)) for i, (x0, y0, x1, y1) in self.legend_boxes]

    # ------------------------------------------------------------------------------------------ geometry

    @property
    def footer_height(self) -> int:
        return self._footer.shape[0]

    @property
    def frame_size(self) -> tuple[int, int]:
        """``(height, width)`` of :meth:`frame`'s image."""
        return self.caption_height + self.panel_size[0] + GAP + self.footer_height, self.width

    def rows_size(self, n: int) -> tuple[int, int]:
        """``(height, width)`` of :meth:`rows`'s image for ``n`` frames."""
        return self.caption_height + n * self.panel_size[0] + n * GAP + self.footer_height, self.width

    def _span(self, keys: Sequence[str]) -> tuple[int, int] | None:
        xs = [self.x[k] for k in keys if k in self.x]
        if not xs:
            return None
        return min(xs), max(xs) + self.panel_size[1]

    def metadata(self) -> dict[str, Any]:
        """What the pictures show (for ``predictions.json`` / ``metrics.json``)."""
        out: dict[str, Any] = {
            "panels": [CAPTIONS[k] for k in self.keys],
            "panel_size": list(self.panel_size),
            "upscale": self.scale,
            "frame_size": list(self.frame_size),
            # where each panel lies in a one-frame picture: [x0, y0, x1, y1], x1/y1 excluded
            "panel_boxes": [
                [
                    self.x[k],
                    self.caption_height,
                    self.x[k] + self.panel_size[1],
                    self.caption_height + self.panel_size[0],
                ]
                for k in self.keys
            ],
        }
        if self.has_depth:
            out["depth_range_m"] = list(self.depth_range)
            out["depth_ticks_m"] = depth_ticks(*self.depth_range)
            # the colour bar in a one-frame picture: column x0 is depth_range_m[0], column x1 - 1 depth_range_m[1]
            out["colorbar_box"] = list(self.colorbar_box) if self.colorbar_box else None
            out["depth_colormap"] = (
                f"{DEPTH_CMAP}, linear, {_fmt_m(self.depth_range[0])} m red to "
                f"{_fmt_m(self.depth_range[1])} m dark blue; farther depths (sky) dark blue; "
                f"predicted pixels without an estimate grey {list(INVALID_COLOR)}"
            )
        if self.has_labels:
            out["classes"] = list(self.class_names)
        return out

    # ------------------------------------------------------------------------------------------ static parts

    def _draw_captions(self) -> np.ndarray:
        img = Image.new("RGB", (self.width, self.caption_height), BACKGROUND)
        draw = ImageDraw.Draw(img)
        pw = self.panel_size[1]
        for k in self.keys:
            _draw_text(draw, (self.x[k] + pw / 2, self.caption_height / 2), CAPTIONS[k], self.font_size, anchor="mm")
        return np.asarray(img)

    def caption_strip(self) -> np.ndarray:
        """The caption band above the panels (``[caption_height, width, 3]``)."""
        return self._caption

    def _legend_layout(self, x0: int, x1: int) -> tuple[list[tuple[int, int, int]], int]:
        """Positions ``(class, x, y)`` of the legend entries in ``[x0, x1)`` (left to right, wrapped, each line
        centred), and the height used."""
        s = self.small_size
        sw = round(s * 1.1)  # swatch side
        space = round(s * 1.3)
        widths = [sw + round(s * 0.4) + text_size(n, s)[0] for n in self.class_names]
        avail = max(x1 - x0 - 2 * round(s * 0.5), max(widths))
        lines: list[list[int]] = [[]]
        used = 0
        for i, w in enumerate(widths):
            if lines[-1] and used + space + w > avail:
                lines.append([])
                used = 0
            used += (space if lines[-1] else 0) + w
            lines[-1].append(i)
        line_h = round(s * 1.6)
        top = round(s * 0.6)
        pos = []
        for r, line in enumerate(lines):
            total = sum(widths[i] for i in line) + space * (len(line) - 1)
            x = x0 + max(0, (x1 - x0 - total) // 2)
            for i in line:
                pos.append((i, x, top + r * line_h))
                x += widths[i] + space
        return pos, top + len(lines) * line_h + round(s * 0.3)

    def _colorbar_geometry(self, x0: int, x1: int) -> dict[str, int]:
        s = self.small_size
        margin = min(round(s * 1.6), max(0, (x1 - x0 - 1) // 2))  # narrow panels: a bar of at least one pixel
        top = round(s * 0.5)
        title_h = round(s * 1.5)
        bar_h = round(s * 1.1)
        return {
            "x0": x0 + margin,
            "x1": x1 - margin,
            "y0": top + title_h,
            "y1": top + title_h + bar_h,
            "height": top + title_h + bar_h + round(s * 0.5) + round(s * 1.5),
        }

    def _draw_footer(self) -> np.ndarray:
        parts = []
        depth_span = self._span(DEPTH_KEYS) if self.has_depth else None
        label_span = self._span(LABEL_KEYS) if self.has_labels and self.class_names else None
        if depth_span is not None:
            geom = self._colorbar_geometry(*depth_span)
            parts.append(geom["height"])
        if label_span is not None:
            legend, lh = self._legend_layout(*label_span)
            parts.append(lh)
        height = max(parts) if parts else 0
        img = Image.new("RGB", (self.width, height), BACKGROUND)
        if not height:
            self.colorbar_box = None
            self.legend_boxes = []
            return np.asarray(img)
        draw = ImageDraw.Draw(img)
        s = self.small_size
        self.colorbar_box = None
        if depth_span is not None:
            near, far = self.depth_range
            x0, x1, y0, y1 = geom["x0"], geom["x1"], geom["y0"], geom["y1"]
            bar = positions_to_rgb(np.linspace(0.0, 1.0, x1 - x0, dtype=np.float32))
            img.paste(
                Image.fromarray(np.ascontiguousarray(np.broadcast_to(bar[None], (y1 - y0, x1 - x0, 3)))), (x0, y0)
            )
            self.colorbar_box = (x0, y0, x1, y1)  # in the footer; moved to frame coordinates below
            title = (
                f"depth in metres, {_fmt_m(near)} to {_fmt_m(far)} m (fixed for this flight; "
                f"farther, e.g. sky: dark blue; grey: no estimate)"
            )
            if text_size(title, s)[0] > depth_span[1] - depth_span[0] - 8:
                title = f"depth (m), {_fmt_m(near)}-{_fmt_m(far)} m, fixed for the flight; grey: no estimate"
            if text_size(title, s)[0] > depth_span[1] - depth_span[0] - 8:
                title = f"depth (m), {_fmt_m(near)}-{_fmt_m(far)} m; grey: none"
            _draw_text(draw, ((depth_span[0] + depth_span[1]) / 2, y0 - round(s * 0.35)), title, s, anchor="md")
            ticks = depth_ticks(near, far)
            for t in ticks:
                x = x0 + (t - near) / (far - near) * (x1 - x0 - 1)
                draw.line([(x, y1), (x, y1 + round(s * 0.35))], fill=FOREGROUND, width=1)
                label = _fmt_m(t) + (" m" if t == ticks[-1] else "")
                _draw_text(draw, (x, y1 + round(s * 0.45)), label, s, anchor="ma")
        self.legend_boxes = []
        if label_span is not None:
            sw = round(s * 1.1)
            for i, x, y in legend:
                color = tuple(int(c) for c in self.palette[i])
                draw.rectangle([x, y, x + sw - 1, y + sw - 1], fill=color, outline=(200, 200, 200))
                _draw_text(draw, (x + sw + round(s * 0.4), y + sw / 2), self.class_names[i], s, anchor="lm")
                self.legend_boxes.append((i, (x, y, x + sw, y + sw)))
        return np.asarray(img)

    def footer(self) -> np.ndarray:
        """The band under the panels with the depth colour bar and the class legend (``[footer_height, width, 3]``)."""
        return self._footer

    # ------------------------------------------------------------------------------------------ drawing

    def panel(self, key: str, maps: FrameMaps) -> np.ndarray:
        """One panel at :attr:`panel_size`."""
        a = getattr(maps, key)
        if a is None:
            raise ValueError(f"the frame has no {CAPTIONS[key]}")
        if tuple(a.shape[:2]) != self.map_size:
            raise ValueError(f"{CAPTIONS[key]}: size {tuple(a.shape[:2])}, the figure's maps are {self.map_size}")
        k = self.scale
        if key == "rgb":
            return upscale_bilinear(np.asarray(a, dtype=np.uint8), k)
        if key in DEPTH_KEYS:
            # colour first, then interpolate the colours: a near/far edge blends its two colours instead of showing
            # a band of every depth in between
            colors = positions_to_rgb(depth_positions(a, *self.depth_range))
            if key == "depth" and maps.valid is not None:
                colors[~np.asarray(maps.valid, dtype=bool)] = INVALID_COLOR
            return upscale_bilinear(colors, k)
        lab = np.asarray(a).astype(np.intp)
        n = len(self.palette)
        # out-of-range classes (a corrupt ground truth) show black rather than failing
        colors = np.concatenate([self.palette, np.zeros((1, 3), np.uint8)])[np.where((lab >= 0) & (lab < n), lab, n)]
        return upscale_nearest(colors, k)

    def _row(self, canvas: np.ndarray, y: int, maps: FrameMaps) -> None:
        ph, pw = self.panel_size
        for key in self.keys:
            if getattr(maps, key) is None:  # e.g. a frame whose ground truth is missing: an empty panel, marked
                self._na(canvas, y, key)
                continue
            canvas[y : y + ph, self.x[key] : self.x[key] + pw] = self.panel(key, maps)
        if maps.title:
            self._title(canvas, y, maps.title)

    def _na(self, canvas: np.ndarray, y: int, key: str) -> None:
        ph, pw = self.panel_size
        img = Image.new("RGB", (pw, ph), (48, 48, 48))
        _draw_text(ImageDraw.Draw(img), (pw / 2, ph / 2), "not available", self.small_size, anchor="mm")
        canvas[y : y + ph, self.x[key] : self.x[key] + pw] = np.asarray(img)

    def _title(self, canvas: np.ndarray, y: int, title: str) -> None:
        s = self.small_size
        w, _ = text_size(title, s)
        pad = round(s * 0.35)
        box = Image.new("RGB", (w + 2 * pad, round(s * 1.5)), BACKGROUND)
        _draw_text(ImageDraw.Draw(box), (pad, box.height / 2), title, s, anchor="lm")
        b = np.asarray(box)
        bh, bw = min(b.shape[0], self.panel_size[0]), min(b.shape[1], self.panel_size[1])
        canvas[y : y + bh, self.x[self.keys[0]] : self.x[self.keys[0]] + bw] = b[:bh, :bw]

    def frame(self, maps: FrameMaps) -> np.ndarray:
        """One frame: captions, the panels, the footer; ``[frame_size[0], frame_size[1], 3]`` uint8."""
        return self.rows([maps])

    def rows(self, frames: Sequence[FrameMaps]) -> np.ndarray:
        """Several frames, one row each, under one caption strip and over one footer."""
        h, w = self.rows_size(len(frames))
        canvas = np.empty((h, w, 3), dtype=np.uint8)
        canvas[...] = BACKGROUND
        canvas[: self.caption_height] = self._caption
        y = self.caption_height
        for maps in frames:
            self._row(canvas, y, maps)
            y += self.panel_size[0] + GAP
        canvas[y:] = self._footer
        return canvas


class FlightPictures:
    """Draws the frames of one flight as they come, with a depth range fixed for the whole flight.

    Without an explicit ``depth_range`` the first ``warmup`` frames are held back; the range is then chosen by
    :func:`auto_depth_range` from their ground-truth depth (or, without one, from their predicted depth outside
    reset frames), and the held frames are drawn. ``emit(context, image)`` receives every drawn frame in order.
    """

    def __init__(
        self,
        emit: Callable[[Any, np.ndarray], None],
        *,
        class_names: Sequence[str] = (),
        palette: np.ndarray | None = None,
        depth_range: tuple[float, float] | None = None,
        warmup: int = WARMUP_FRAMES,
        min_panel: int = MIN_PANEL,
    ) -> None:
        self.emit = emit
        self.class_names = tuple(class_names)
        self.palette = palette
        self.depth_range = depth_range
        self.warmup = max(1, int(warmup))
        self.min_panel = min_panel
        self.figure: FlightFigure | None = None
        self._held: list[tuple[Any, FrameMaps]] = []

    def add(self, maps: FrameMaps, context: Any = None) -> None:
        if self.figure is not None:
            self.emit(context, self.figure.frame(maps))
            return
        self._held.append((context, maps))
        if self.depth_range is not None or len(self._held) >= self.warmup:
            self._start()

    def _start(self) -> None:
        first = self._held[0][1]
        rng = self.depth_range
        if rng is None:
            gt = [m.gt_depth for _, m in self._held if m.gt_depth is not None]
            pred = [
                m.depth if m.valid is None else m.depth[m.valid]
                for _, m in self._held
                if m.depth is not None and not m.reset
            ]
            rng = auto_depth_range(gt or pred)
        self.figure = FlightFigure(
            first.keys(),
            first.rgb.shape[:2],
            depth_range=rng,
            class_names=self.class_names,
            palette=self.palette,
            min_panel=self.min_panel,
        )
        held, self._held = self._held, []
        for context, maps in held:
            self.emit(context, self.figure.frame(maps))

    def finish(self) -> FlightFigure | None:
        """Draw the frames still held; returns the figure (None when no frame came)."""
        if self.figure is None and self._held:
            self._start()
        return self.figure


def frame_maps(batch, b: int, *, title: str = "", labels_ok: Callable[[np.ndarray], bool] | None = None) -> FrameMaps:
    """The :class:`FrameMaps` of sample ``b`` of a :class:`~cosemdepth.streaming.frames.StreamBatch`."""

    def arr(t, idx):
        return None if t is None else t[idx].detach().cpu().numpy()

    gt_labels = arr(batch.gt_labels, b)
    if gt_labels is not None and labels_ok is not None and not labels_ok(gt_labels):
        gt_labels = None
    depth = None if batch.depth is None else batch.depth[b, 0].detach().float().cpu().numpy()
    gt_depth = None if batch.gt_depth is None else batch.gt_depth[b, 0].detach().float().cpu().numpy()
    reset = bool(batch.reset[b])
    valid = getattr(batch, "valid", None)
    valid = None if valid is None or depth is None else valid[b, 0].detach().cpu().numpy().astype(bool)
    statuses = getattr(batch, "status", None) or []
    status = statuses[b] if b < len(statuses) else ""
    if title and depth is not None and (reset or status == "reset"):
        title += " (reset: no depth yet)"
    elif title and depth is not None and status == "held":
        title += " (held: too little motion)"
    elif reset and title:
        title += " (reset)"
    return FrameMaps(
        rgb=rgb_to_uint8(batch.rgb[b].float().cpu().numpy()),
        depth=None if depth is None else depth.astype(np.float32),
        gt_depth=None if gt_depth is None else gt_depth.astype(np.float32),
        labels=arr(batch.labels, b),
        gt_labels=gt_labels,
        title=title,
        reset=reset,
        valid=valid,
        status=status,
    )


__all__ = [
    "CAPTIONS",
    "FlightFigure",
    "FlightPictures",
    "FrameMaps",
    "INVALID_COLOR",
    "MAX_UPSCALED_PANEL",
    "MIN_PANEL",
    "PANELS",
    "WARMUP_FRAMES",
    "auto_depth_range",
    "depth_ticks",
    "frame_maps",
    "nice_ceil",
    "panel_scale",
    "upscale_bilinear",
    "upscale_nearest",
]
