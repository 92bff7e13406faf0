"""Pictures and videos of predictions: colour-mapped depth, colourised labels, side-by-side panels, a flight video,
and the 16-bit depth PNG encoding.

Depth PNG (``depth_to_png16``): ``uint16 = round(depth_m * 256)``, saturating to ``[0, 65535]``: a resolution of
1/256 m (3.9 mm) up to 255.996 m; 0 means a depth <= 1/512 m (or a negative/NaN prediction). Decode with
``depth_m = png / 256`` (:func:`png16_to_depth`). This is the KITTI depth-map convention.

Depth colour map (``colorize_depth``): linear between ``near`` (default 0 m, red) and ``far`` (default 80 m, the
evaluation cap, dark blue), matplotlib's ``turbo``. The pictures of ``predict`` and ``demo`` (panels, captions, colour
bar, legend) are drawn by :mod:`cosemdepth.render.figures`, with one range per flight.
"""

from __future__ import annotations

import errno
import functools
import os
import shutil
import signal
import subprocess
import tempfile
import warnings
from fractions import Fraction
from pathlib import Path

import numpy as np
from PIL import Image

from ..defaults import DEPTH_CAP_M
from ..output_safety.atomic import atomic_open, atomic_path

#: Metres -> 16-bit PNG units: ``uint16 = round(depth_m * DEPTH_PNG_SCALE)``.
DEPTH_PNG_SCALE = 256.0
DEPTH_PNG_MAX_M = 65535 / DEPTH_PNG_SCALE


def depth_to_png16(depth: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """``[H, W]`` metres -> ``[H, W]`` uint16 ``round(depth * 256)`` saturated to [0, 65535]; NaN -> 0.

    With ``valid`` (``[H, W]`` bool): 0 is "no depth", written where ``valid`` is False, and the valid pixels are
    saturated to [1, 65535] (a valid depth under 1/512 m is written as 1, not as "no depth")."""
    d = np.nan_to_num(np.asarray(depth, dtype=np.float64), nan=0.0, posinf=DEPTH_PNG_MAX_M, neginf=0.0)
    v = np.rint(d * DEPTH_PNG_SCALE)
    if valid is None:
        return np.clip(v, 0, 65535).astype(np.uint16)
    return np.where(np.asarray(valid, dtype=bool), np.clip(v, 1, 65535), 0).astype(np.uint16)


def png16_to_depth(png: np.ndarray) -> np.ndarray:
    """Inverse of :func:`depth_to_png16`: ``[H, W]`` uint16 -> float32 metres."""
    return (np.asarray(png).astype(np.float32) / np.float32(DEPTH_PNG_SCALE)).astype(np.float32)


@functools.lru_cache(maxsize=8)
def _lut(name: str) -> np.ndarray:
    from matplotlib import colormaps  # deferred: matplotlib is heavy (~0.5 s) and only the colour maps need it

    return (colormaps[name](np.linspace(0.0, 1.0, 256))[:, :3] * 255.0 + 0.5).astype(np.uint8)


def depth_positions(depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """Depth (metres) -> float32 position on a linear colour scale, 0 at ``near`` and 1 at ``far``, clipped; NaN and
    +inf -> 1, -inf -> 0."""
    d = np.nan_to_num(np.asarray(depth, dtype=np.float32), nan=far, posinf=far, neginf=near)
    return (np.clip(d, near, far) - np.float32(near)) / np.float32(far - near)


def positions_to_rgb(pos: np.ndarray, cmap: str = "turbo") -> np.ndarray:
    """Positions on the depth scale (0 near .. 1 far) -> ``[..., 3]`` uint8: ``cmap`` reversed (near is its top)."""
    idx = np.clip(np.rint((1.0 - np.asarray(pos, dtype=np.float32)) * 255.0), 0, 255).astype(np.intp)
    return _lut(cmap)[idx]


def colorize_depth(depth: np.ndarray, near: float = 0.0, far: float = DEPTH_CAP_M, cmap: str = "turbo") -> np.ndarray:
    """``[H, W]`` metres -> ``[H, W, 3]`` uint8: linear scale, ``near`` at the top of ``cmap`` (red for turbo) to
    ``far`` at its bottom (dark blue); values outside are clipped, NaN shows as ``far``."""
    if not far > near:
        raise ValueError(f"colorize_depth: far ({far}) must be greater than near ({near})")
    return positions_to_rgb(depth_positions(depth, near, far), cmap)


def colorize_labels(labels: np.ndarray, palette: np.ndarray) -> np.ndarray:
    """``[H, W]`` class indices -> ``[H, W, 3]`` uint8 with ``palette [N, 3]``."""
    return np.asarray(palette, dtype=np.uint8)[np.asarray(labels, dtype=np.intp)]


def rgb_to_uint8(rgb: np.ndarray) -> np.ndarray:
    """``[3, H, W]`` floats in [0, 1] (values outside are clipped) -> ``[H, W, 3]`` uint8."""
    return (np.clip(np.asarray(rgb, dtype=np.float32), 0.0, 1.0).transpose(1, 2, 0) * 255.0 + 0.5).astype(np.uint8)


def save_png(path: str | os.PathLike, array: np.ndarray) -> None:
    """Write ``array`` (``[H, W]`` uint8/uint16 or ``[H, W, 3]`` uint8) as a PNG, atomically."""
    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(array)).save(tmp, format="PNG")


def save_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    """``np.save`` atomically."""
    with atomic_open(path, "wb") as f:
        np.save(f, np.ascontiguousarray(array))


def ffmpeg_exe() -> str | None:
    """Path of the ffmpeg binary of imageio-ffmpeg (or on PATH), or None."""
    try:
        import imageio_ffmpeg  # deferred: only videos need it (and it may be missing: GIF fallback)

        return imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:  # noqa: BLE001 - any failure means "no ffmpeg"
        return shutil.which("ffmpeg")


#: Video formats of :class:`VideoWriter` (``--video``; the commands add ``"none"``), the default one and frame rate.
VIDEO_FORMATS = ("mp4", "gif")
DEFAULT_VIDEO = "mp4"
DEFAULT_FPS = 8.0


class VideoWriter:
    """Stream frames (``[H, W, 3]`` uint8, all the same size) into an MP4 (H.264, imageio-ffmpeg's ffmpeg reading
    them on a pipe) or a GIF (Pillow).

    ``fmt="mp4"`` falls back to GIF (with a warning) when no ffmpeg is available; :attr:`path` is the file finally
    written. The file is written under a temporary name and renamed on :meth:`close`; :meth:`abort` deletes it.
    Odd frame sizes are padded by one black row/column for H.264.
    """

    def __init__(self, path: str | os.PathLike, fps: float = DEFAULT_FPS, fmt: str = DEFAULT_VIDEO) -> None:
        if fmt not in VIDEO_FORMATS:
            raise ValueError(f"video format must be 'mp4' or 'gif', got {fmt!r}")
        self.fps = float(fps)
        self.exe = ffmpeg_exe() if fmt == "mp4" else None
        if fmt == "mp4" and self.exe is None:
            warnings.warn("no ffmpeg found (imageio-ffmpeg); writing a GIF instead of an MP4", stacklevel=2)
            fmt = "gif"
        self.fmt = fmt
        self.path = Path(path).with_suffix("." + fmt)
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        self._proc: subprocess.Popen | None = None  # ffmpeg, for MP4
        self._log = None
        self._gif: list = []
        self._size: tuple[int, int] | None = None
        self.frames = 0

    def _start_ffmpeg(self, w: int, h: int) -> None:
        """Start ffmpeg reading raw RGB frames on its stdin (its messages go to a temporary file, read if it fails:
        a failed ffmpeg is an error naming the video, not lines on the console and a cut-short file)."""
        fps = str(Fraction(self.fps).limit_denominator())
        cmd = [
            self.exe,
            "-y",
            "-v",
            "error",
            "-f",
            "rawvideo",
            "-vcodec",
            "rawvideo",
            "-s",
            f"{w}x{h}",
            "-pix_fmt",
            "rgb24",
            "-r",
            fps,
            "-i",
            "-",
            "-an",
            "-vcodec",
            "libx264",
            "-pix_fmt",
            "yuv420p",
            "-crf",
            "20",
            "-preset",
            "veryfast",
            "-movflags",
            "+faststart",
            "-f",
            "mp4",
            str(self._tmp),
        ]
        self._log = tempfile.TemporaryFile()
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._log)

    def _ffmpeg_error(self, returncode: int | None) -> OSError:
        """The OSError naming the video for an ffmpeg that failed (exit status ``returncode``)."""
        self._log.seek(0)
        text = self._log.read().decode("utf-8", "replace")
        lines = [line.strip() for line in text.splitlines() if line.strip()]
        if returncode is not None and returncode < 0 and -returncode == getattr(signal, "SIGXFSZ", None):
            return OSError(errno.EFBIG, os.strerror(errno.EFBIG), str(self.path))
        for code in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EIO):
            if os.strerror(code) in text:
                return OSError(code, os.strerror(code), str(self.path))
        return OSError(
            errno.EIO,
            f"ffmpeg failed (exit status {returncode}): {lines[-1] if lines else 'no message'}",
            str(self.path),
        )

    def write(self, frame: np.ndarray) -> None:
        frame = np.asarray(frame, dtype=np.uint8)
        if self.fmt == "mp4":
            h, w = frame.shape[:2]
            frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)))
        size = (frame.shape[1], frame.shape[0])
        if self._size is None:
            self._size = size
            if self.fmt == "mp4":
                self._start_ffmpeg(*size)
        elif size != self._size:
            raise ValueError(f"video frames must all have the same size: {size} after {self._size}")
        if self.fmt == "mp4":
            assert self._proc is not None
            try:
                self._proc.stdin.write(np.ascontiguousarray(frame).tobytes())
            except OSError:  # ffmpeg stopped reading: it failed
                self._proc.kill()
                raise self._ffmpeg_error(self._proc.wait()) from None
        else:
            self._gif.append(Image.fromarray(frame).quantize(colors=255, method=Image.Quantize.MEDIANCUT))
        self.frames += 1

    def close(self) -> Path:
        """Finish the file and move it into place; returns its path."""
        try:
            if self.frames == 0:
                raise ValueError(f"{self.path}: no frame was written")
            if self.fmt == "mp4":
                assert self._proc is not None
                try:
                    self._proc.stdin.close()
                except OSError:
                    pass  # ffmpeg already exited: its status says why
                code = self._proc.wait()
                if code != 0:
                    raise self._ffmpeg_error(code)
                self._proc = None
            else:
                first, rest = self._gif[0], self._gif[1:]
                first.save(
                    self._tmp,
                    format="GIF",
                    save_all=True,
                    append_images=rest,
                    duration=max(int(round(1000 / self.fps)), 20),
                    loop=0,
                )
                self._gif = []
        except BaseException as e:
            self._ctx.__exit__(type(e), e, e.__traceback__)
            raise
        self._ctx.__exit__(None, None, None)
        return self.path

    def abort(self) -> None:
        """Stop and delete the temporary file."""
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait()
            self._proc = None
        err = RuntimeError("aborted")
        try:
            self._ctx.__exit__(RuntimeError, err, None)
        except RuntimeError:
            pass


__all__ = [
    "DEPTH_PNG_MAX_M",
    "DEPTH_PNG_SCALE",
    "VideoWriter",
    "colorize_depth",
    "colorize_labels",
    "depth_to_png16",
    "depth_positions",
    "ffmpeg_exe",
    "png16_to_depth",
    "positions_to_rgb",
    "rgb_to_uint8",
    "save_npy",
    "save_png",
]
