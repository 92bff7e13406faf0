"""A video file as a flight's frames: decoded as a stream with each frame's presentation time (PyAV).

``open_video(path)`` reads the container's header and its first frame (so that an unreadable file fails before any
work starts) and returns a :class:`VideoReader`; :meth:`VideoReader.frames` decodes the file from the start and
yields ``(index, pts_s, image)`` one frame at a time (memory stays flat over long videos):

* ``index``: the frame's 0-based position in decoding order (the order the decoder returns frames, which is
  presentation order); with ``frame_skip = k`` the frames ``0, k, 2k, ...`` are yielded and keep their index;
* ``pts_s``: the frame's presentation time in seconds on the container's clock, ``pts * time_base`` exactly (a
  variable frame rate is kept as recorded; nothing is resampled to a nominal rate). Times must increase;
* ``image``: ``[H, W, 3]`` RGB as displayed: the container's rotation metadata (the display matrix; PyAV reports it as
  ``frame.rotation``, counter-clockwise degrees, without applying it) is applied, so a phone's portrait video is read
  portrait and :attr:`VideoReader.size` is the displayed size. uint8 for 8-bit video, uint16 (every bit, scaled by
  :func:`cosemdepth.data.frames.rgb_to_tensor` with ``/65535``) for video of more than 8 bits per sample.

Bad files are one-line :class:`~cosemdepth.errors.DatasetError` naming the file: missing, not a video (no video
stream, no decodable frame), corrupt or truncated data met while decoding (a decoding error, or fewer frames than
the container's index lists), presentation times that do not increase, frames whose size changes, rotation metadata
other than a multiple of 90 degrees.
"""

from __future__ import annotations

import datetime
import math
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import ConfigError, DatasetError

#: Suffixes read as video files (``--images FILE``); a folder is read as images.
VIDEO_EXTENSIONS = (".mp4", ".mov", ".mkv", ".m4v", ".avi", ".webm")
#: Frames the decoder may deliver fewer than the container's index lists before the file counts as truncated
#: (a container's count can include frames an edit list hides).
_COUNT_SLACK = 2


def is_video(path: str | Path) -> bool:
    """Whether ``path`` names a video file by its suffix (:data:`VIDEO_EXTENSIONS`, any case)."""
    return Path(path).suffix.lower() in VIDEO_EXTENSIONS


def _av():
    from ..optional import require

    return require("av", "reading a video")


def _rotation_steps(degrees: float, path: Path) -> int:
    """Counter-clockwise quarter turns of a display rotation (``frame.rotation``) -> 0..3."""
    d = float(degrees or 0)
    steps = round(d / 90.0)
    if not math.isfinite(d) or abs(d - 90.0 * steps) > 1e-3:
        raise DatasetError(
            f"{path}: rotation metadata of {d:g} degrees is not supported (only multiples of 90 degrees)"
        )
    return steps % 4


def _utc_seconds(text: str | None) -> float | None:
    """A container's ``creation_time`` (ISO 8601, e.g. ``2026-05-01T10:11:12.000000Z``) -> Unix seconds (UTC)."""
    if not text:
        return None
    try:
        t = datetime.datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=datetime.timezone.utc)
    return t.timestamp()


@dataclass(frozen=True)
class VideoFrame:
    """One decoded frame: ``index`` (0-based, decoding order), ``pts_s`` (seconds), ``image`` ``[H, W, C]``."""

    index: int
    pts_s: float
    image: np.ndarray

    def __iter__(self):  # unpacks as (index, pts_s, image)
        return iter((self.index, self.pts_s, self.image))


class VideoReader:
    """A video file opened for streaming (see the module docstring). Attributes known from the header and the
    first frame: ``size`` ``(H, W)`` as displayed, ``rotation`` (counter-clockwise degrees applied, 0/90/180/270),
    ``count_hint`` (the container's frame count, None when it has none), ``duration_s`` (None when unknown),
    ``start_s`` (the first frame's presentation time), ``creation_time_utc`` (Unix seconds of the container's
    ``creation_time`` tag, None without one), ``codec``, ``bits`` (8 or 16: the dtype the frames come in)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        av = _av()
        if not self.path.is_file():
            raise DatasetError(f"{self.path}: video file not found")
        try:
            with av.open(str(self.path)) as container:
                if not container.streams.video:
                    raise DatasetError(f"{self.path}: no video stream in the file")
                stream = container.streams.video[0]
                self.codec = stream.codec_context.name
                self.count_hint = int(stream.frames) if stream.frames else None
                if stream.duration is not None and stream.time_base is not None:
                    self.duration_s = float(stream.duration * stream.time_base)
                elif container.duration is not None:
                    self.duration_s = container.duration / 1e6
                else:
                    self.duration_s = None
                meta = {**container.metadata, **stream.metadata}
                self.creation_time_utc = _utc_seconds(meta.get("creation_time"))
                first = next(iter(container.decode(stream)), None)
                if first is None:
                    raise DatasetError(f"{self.path}: the video stream has no decodable frame")
                self.rotation = 90 * _rotation_steps(first.rotation, self.path)
                self._format = _rgb_format(first.format)
                self.bits = 16 if self._format == "rgb48le" else 8
                h, w = first.height, first.width
                self.size = (w, h) if self.rotation in (90, 270) else (h, w)
                self.start_s = _seconds(first, self.path, 0)
        except DatasetError:
            raise
        except av.error.FFmpegError as e:
            raise DatasetError(f"{self.path}: cannot read the video ({_ffmpeg_message(e)})") from None

    def __repr__(self) -> str:
        return (
            f"VideoReader({str(self.path)!r}, size={self.size}, rotation={self.rotation}, "
            f"count_hint={self.count_hint}, duration_s={self.duration_s})"
        )

    def frames(
        self, frame_skip: int = 1, *, size: tuple[int, int] | None = None, gray: bool = False
    ) -> Iterator[VideoFrame]:
        """Decode the file from its start, yielding every ``frame_skip``-th frame (see the module docstring).

        ``size`` ``(H, W)`` (displayed orientation) has the decoder's scaler (swscale, area averaging) shrink the
        frames, and ``gray`` gives ``[H, W, 1]`` luma: a cheap picture for measuring image motion; the model's frames
        use neither (full-size RGB, resized by the data pipeline's BL2 like any image)."""
        if not isinstance(frame_skip, int) or frame_skip < 1:
            raise ConfigError(f"frame_skip must be a positive integer, got {frame_skip!r}")
        av = _av()
        index = -1
        last = -math.inf
        stored = None
        try:
            with av.open(str(self.path)) as container:
                stream = container.streams.video[0]
                stream.thread_type = "AUTO"
                for frame in container.decode(stream):
                    index += 1
                    pts = _seconds(frame, self.path, index)
                    if not pts > last:
                        raise DatasetError(
                            f"{self.path}: frame {index} has presentation time {pts:.6f} s, not after the previous "
                            f"frame's {last:.6f} s (presentation times must increase)"
                        )
                    last = pts
                    if stored is None:
                        stored = (frame.height, frame.width)
                    elif (frame.height, frame.width) != stored:
                        raise DatasetError(
                            f"{self.path}: frame {index} is {frame.width}x{frame.height}, the first frame "
                            f"{stored[1]}x{stored[0]}; a flight's frames must have one size"
                        )
                    if index % frame_skip:
                        continue
                    steps = _rotation_steps(frame.rotation, self.path)
                    if 90 * steps != self.rotation:
                        raise DatasetError(
                            f"{self.path}: frame {index} has rotation metadata {frame.rotation} degrees, the first "
                            f"frame {self.rotation}"
                        )
                    yield VideoFrame(index, pts, self._image(frame, steps, size, gray))
        except DatasetError:
            raise
        except av.error.FFmpegError as e:
            raise DatasetError(
                f"{self.path}: cannot decode the video after frame {index} ({_ffmpeg_message(e)}): "
                "the file is corrupt or truncated"
            ) from None
        decoded = index + 1
        if self.count_hint is not None and decoded < self.count_hint - _COUNT_SLACK:
            raise DatasetError(
                f"{self.path}: decoded {decoded} frames of the {self.count_hint} the container lists: the file is "
                "truncated or corrupt"
            )

    def _image(self, frame, steps: int, size: tuple[int, int] | None, gray: bool) -> np.ndarray:
        fmt = ("gray16le" if self.bits == 16 else "gray") if gray else self._format
        if size is not None:
            h, w = (size[1], size[0]) if steps % 2 else size
            arr = frame.reformat(width=w, height=h, format=fmt, interpolation="AREA").to_ndarray()
        else:
            arr = frame.to_ndarray(format=fmt)
        if arr.ndim == 2:
            arr = arr[..., None]
        if steps:
            arr = np.rot90(arr, steps)
        return np.ascontiguousarray(arr)


def _rgb_format(fmt) -> str:
    """``"rgb48le"`` for a pixel format (PyAV ``VideoFormat``) of more than 8 bits per sample (``yuv420p10le``,
    ``p010le``, ``gray12le``...), else ``"rgb24"``."""
    return "rgb48le" if max((c.bits for c in fmt.components), default=8) > 8 else "rgb24"


def _seconds(frame, path: Path, index: int) -> float:
    """A frame's presentation time in seconds (``pts * time_base``, exactly, then rounded to float once)."""
    pts = frame.pts if frame.pts is not None else frame.dts
    if pts is None or frame.time_base is None:
        raise DatasetError(f"{path}: frame {index} has no presentation time")
    return float(Fraction(pts) * Fraction(frame.time_base))


def _ffmpeg_message(e: Exception) -> str:
    text = getattr(e, "strerror", None) or str(e)
    return text.splitlines()[0][:200] if text else type(e).__name__


def open_video(path: str | Path) -> VideoReader:
    """Open a video file for streaming (PyAV); a one-line :class:`~cosemdepth.errors.DatasetError` when it cannot
    be read (see the module docstring)."""
    return VideoReader(path)


__all__ = ["VIDEO_EXTENSIONS", "VideoFrame", "VideoReader", "is_video", "open_video"]
