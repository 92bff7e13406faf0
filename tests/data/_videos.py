"""Test videos written by independent writers: PyAV (exact presentation times, variable frame rate), imageio-ffmpeg
(ffmpeg's own command line, constant rate), and ffmpeg's ``-display_rotation`` for rotation metadata."""

from __future__ import annotations

import subprocess
from fractions import Fraction
from pathlib import Path

import numpy as np


def pattern(k: int, h: int = 48, w: int = 64) -> np.ndarray:
    """Frame ``k`` of a test video: a gradient, a white block whose place says ``k`` and a red top-left corner (so
    that every rotation and flip is visible)."""
    img = np.zeros((h, w, 3), np.uint8)
    img[..., 1] = np.linspace(0, 160, w, dtype=np.uint8)[None, :]
    img[..., 2] = np.linspace(0, 160, h, dtype=np.uint8)[:, None]
    x = (8 * k) % (w - 8)
    img[h // 2 : h // 2 + 8, x : x + 8] = 255
    img[:6, :10] = (255, 0, 0)
    return img


def write_pyav(
    path: Path, frames, times_s, *, codec: str = "libx264", pix_fmt: str = "yuv444p", tb=1000, metadata=None
):
    """``frames`` [N] of ``[H, W, 3]`` uint8 at presentation times ``times_s`` (seconds, a multiple of ``1/tb``);
    ``metadata``: the container's tags (``creation_time``...)."""
    import av

    base = Fraction(1, tb)
    with av.open(str(path), "w") as c:
        c.metadata.update(metadata or {})
        h, w = frames[0].shape[:2]
        s = c.add_stream(codec, rate=25)
        s.width, s.height, s.pix_fmt = w, h, pix_fmt
        s.time_base = base
        s.codec_context.time_base = base
        if codec == "libx264":
            s.options = {"crf": "0"}
        for img, t in zip(frames, times_s):
            f = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            f.pts = round(t * tb)
            f.time_base = base
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


def write_imageio(path: Path, frames, fps: float):
    """Constant-rate video through imageio-ffmpeg (the ffmpeg command line), high quality."""
    import imageio_ffmpeg

    h, w = frames[0].shape[:2]
    writer = imageio_ffmpeg.write_frames(
        str(path), (w, h), fps=fps, codec="libx264", quality=None, output_params=["-crf", "0"], macro_block_size=1
    )
    writer.send(None)
    for img in frames:
        writer.send(np.ascontiguousarray(img))
    writer.close()
    return path


def ffmpeg() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def with_rotation(src: Path, dst: Path, degrees: float) -> Path:
    """``src`` remuxed (no re-encoding) with display-matrix rotation metadata of ``degrees`` counter-clockwise."""
    subprocess.run(
        [ffmpeg(), "-y", "-v", "error", "-display_rotation", f"{degrees:g}", "-i", str(src), "-c", "copy", str(dst)],
        check=True,
    )
    return dst


def ffmpeg_frames(path: Path, size_hw: tuple[int, int]) -> np.ndarray:
    """Every frame as ffmpeg's command line decodes it, rotation metadata applied (its autorotate default):
    ``[N, H, W, 3]`` uint8."""
    out = subprocess.run(
        [ffmpeg(), "-v", "error", "-i", str(path), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
        check=True,
        capture_output=True,
    ).stdout
    h, w = size_hw
    return np.frombuffer(out, np.uint8).reshape(-1, h, w, 3)


def ffmpeg_vfr(path: Path, pts_expr: str, frames: int, size: str = "64x48") -> Path:
    """A video written by ffmpeg's command line from its test source, frame ``N`` at ``pts_expr`` milliseconds
    (an ffmpeg ``setpts`` expression in ``N``), passed through unchanged (variable frame rate)."""
    subprocess.run(
        [
            ffmpeg(), "-y", "-v", "error", "-f", "lavfi", "-i", f"testsrc=size={size}:rate=25", "-frames:v",
            str(frames), "-vf", f"settb=1/1000,setpts={pts_expr}", "-fps_mode", "passthrough",
            "-enc_time_base:v", "1/1000", "-c:v", "libx264", "-video_track_timescale", "1000", str(path),
        ],
        check=True,
    )  # fmt: skip
    return path
