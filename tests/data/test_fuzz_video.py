"""Fuzz tests of the video reader on damaged files (MP4 with its index at the end or first, Matroska).

Allowed outcomes (tests/fuzzing.py): frames that pass the invariant checks below (and, when the file is unchanged,
all of them with their written times), or a CosemdepthError naming the file.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from _videos import pattern, write_pyav
from fuzzing import fuzz_settings, mutate_bytes, outcome, write
from hypothesis import given
from hypothesis import strategies as st

from cosemdepth.data.video import open_video

N = 8
TIMES = np.arange(N) * 0.04


def _encoded(name: str, **kw) -> bytes:
    with tempfile.TemporaryDirectory() as d:
        path = write_pyav(Path(d) / name, [pattern(k, 32, 48) for k in range(N)], TIMES, **kw)
        return path.read_bytes()


VALID = {"mp4": _encoded("v.mp4", pix_fmt="yuv420p"), "mkv": _encoded("v.mkv", pix_fmt="yuv420p")}


def read_all(path: Path):
    video = open_video(path)
    return video, list(video.frames())


def check(result, raw: bytes, fmt: str) -> None:
    video, frames = result
    h, w = video.size
    pts = [f.pts_s for f in frames]
    assert all(np.isfinite(pts)) and all(b > a for a, b in zip(pts, pts[1:]))
    assert [f.index for f in frames] == list(range(len(frames)))
    for f in frames:
        assert f.image.shape == (h, w, 3) and f.image.dtype in (np.uint8, np.uint16)
    if raw == VALID[fmt]:
        assert pts == TIMES.tolist()


@pytest.mark.parametrize("fmt", ["mp4", "mkv"])
@fuzz_settings(max_examples=20)
@given(data=st.data())
def test_damaged_videos(tmp_path_factory, fmt, data):
    raw = data.draw(st.one_of(st.just(VALID[fmt]), mutate_bytes(VALID[fmt])))
    path = write(tmp_path_factory.mktemp("fuzz") / f"clip.{fmt}", raw)
    outcome(lambda: read_all(path), [path], lambda r: check(r, raw, fmt))
