"""Fuzz tests of the calibration readers: every fixture layout (ROS, OpenCV FileStorage, Kalibr, COLMAP) damaged by
text-token and byte mutations gives a checked Calibration or a one-line CosemdepthError naming the file
(tests/fuzzing.py)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from fuzzing import fuzz_settings, mutate_bytes, outcome, text_file_bytes, write
from hypothesis import given
from hypothesis import strategies as st

from cosemdepth.camera import Undistorter, load_calibration

FIXTURES = sorted((Path(__file__).parent / "fixtures").iterdir())
VALID = [p for p in FIXTURES if "folding" not in p.name]


def check(cal) -> None:
    """A result is a usable camera: positive size, finite positive focal lengths, a lens that does not fold."""
    h, w = cal.size
    assert h > 0 and w > 0 and cal.fx > 0 and cal.fy > 0
    assert all(math.isfinite(v) for v in (*cal.k, *cal.coefficients))
    cal.check()


@pytest.mark.parametrize("fixture", FIXTURES, ids=[p.name for p in FIXTURES])
@fuzz_settings(25, deadline_s=15.0)
@given(data=st.data())
def test_damaged_calibration_files(tmp_path_factory, fixture, data):
    text = fixture.read_text()
    raw = data.draw(st.one_of(text_file_bytes(text), mutate_bytes(text.encode())))
    path = write(tmp_path_factory.mktemp("f") / fixture.name, raw)
    outcome(lambda: load_calibration(path), [path], check)


@pytest.mark.parametrize("fixture", VALID, ids=[p.name for p in VALID])
def test_every_valid_fixture_builds_an_undistorter(fixture):
    cal = load_calibration(fixture)
    und = Undistorter(cal, focal_px=32.0)
    assert und.valid.shape == und.size and 0 < und.valid_fraction <= 1
