"""Stamp units: image names and pose stamps in s, ms, us or ns, read as seconds; the hint when they do not match."""

from __future__ import annotations

import numpy as np
import pytest

from cosemdepth.data.stamps import (
    epoch_unit,
    parse_stamp,
    parse_stamp_unit,
    posed_count,
    read_side,
    to_seconds,
    unit_hint,
)
from cosemdepth.errors import ConfigError

# 2023-11-14 22:13:20 UTC in each unit
EPOCH = {"s": 1700000000, "ms": 1700000000 * 10**3, "us": 1700000000 * 10**6, "ns": 1700000000 * 10**9}


@pytest.mark.parametrize("unit", list(EPOCH))
def test_dates_since_1970_name_their_unit(unit):
    values = [EPOCH[unit], EPOCH[unit] + 5 * {"s": 1, "ms": 10**3, "us": 10**6, "ns": 10**9}[unit]]
    assert epoch_unit(values) == unit
    side = read_side(values, "auto", "pose stamps")
    assert (side.unit, side.how) == (unit, "epoch")
    np.testing.assert_allclose(side.seconds, [1700000000.0, 1700000005.0], rtol=0, atol=1e-6)


def test_stamps_from_zero_are_seconds_unless_given():
    assert epoch_unit([0, 40_000_000, 80_000_000]) is None  # relative nanoseconds: not dates in any unit
    side = read_side([0, 40_000_000], "auto", "image names")
    assert (side.unit, side.how, side.seconds.tolist()) == ("s", "assumed", [0.0, 40_000_000.0])
    side = read_side([0, 40_000_000], "ns", "image names")
    assert (side.unit, side.how, side.seconds.tolist()) == ("ns", "given", [0.0, 0.04])
    # one value outside every unit's range of dates: not dates
    assert epoch_unit([1700000000, 17]) is None


def test_nanosecond_integers_convert_exactly():
    # 19 digits do not fit a float64: parsed as int, divided exactly, rounded once
    assert parse_stamp("1403636579758555392") == 1403636579758555392
    assert to_seconds([1403636579758555392], "ns")[0] == 1403636579758555392 / 10**9
    assert parse_stamp("1305031102.175304") == 1305031102.175304
    assert parse_stamp("000042") == 42 and parse_stamp("img_3") is None and parse_stamp("nan") is None


def test_stamp_unit_option():
    assert parse_stamp_unit("auto") == ("auto", "auto")
    assert parse_stamp_unit("ns") == ("ns", "ns")
    assert parse_stamp_unit("ns,s") == ("ns", "s")
    for bad in ("h", "ns,s,ms", "ns,"):
        with pytest.raises(ConfigError, match="--stamp-unit must be one of auto, s, ms, us, ns or IMAGES,POSES"):
            parse_stamp_unit(bad)


def test_posed_count_by_hand():
    poses = np.array([0.0, 0.1, 0.2, 0.5])
    # 0.05: between 0 and 0.1 (gap 0.1); 0.3: gap 0.3 > 0.1; 0.5: exact; 0.6: past the end
    assert posed_count(np.array([0.05, 0.3, 0.5, 0.6]), poses, max_gap=0.1) == 2
    assert posed_count(np.array([0.05, 0.3, 0.5, 0.6]), poses, max_gap=0.3) == 3


def test_hint_names_the_units_that_match():
    # both sides in nanoseconds from 0, images between poses: read as seconds, the poses are 1e7 "s" apart and
    # nothing interpolates; in ns they are 10 ms apart
    images = read_side([k * 40_000_000 + 5_000_000 for k in range(4)], "auto", "image names")
    poses = read_side([i * 10_000_000 for i in range(16)], "auto", "pose stamps")
    text = unit_hint(images, poses, 0.1)
    assert "image names 5000000..125000000 read as s (the default" in text
    assert "pose stamps 0..150000000 read as s" in text and "one every 10000000 s (median)" in text
    assert text.endswith("4 of 4 images would have a pose: pass --stamp-unit ns")
    # image names in ns from 0, pose stamps in s from 0
    poses = read_side([i * 0.01 for i in range(16)], "auto", "pose stamps")
    assert unit_hint(images, poses, 0.1).endswith("pass --stamp-unit ns,s")
    # nothing fits: other clocks
    far = read_side([5e6 + k for k in range(4)], "auto", "image names")
    assert "no other units match more images" in unit_hint(far, poses, 0.1)
