"""The operating point's typed form: the size rule of a focal length and the warning of a far-off size."""

import math

import pytest

from cosemdepth.errors import ConfigError
from cosemdepth.operating_point import FOCAL_WARN_FACTOR, MotionStats, OperatingPoint, size_for_focal

SHIPPED = OperatingPoint((128, 128), (64.0, 64.0))


def test_the_size_of_a_focal_length_keeps_the_aspect_ratio_and_rounds_half_up():
    assert size_for_focal((720, 1280), 640.0, 64.0) == (72, 128)  # a 90-degree 720p camera at the shipped focal
    assert size_for_focal((1024, 1024), 512.0, 192.0) == (384, 384)  # Mid-Air at the official checkpoints'
    assert size_for_focal((30, 40), 20.0, 5.0) == (8, 10)  # 7.5 -> 8
    assert size_for_focal((3, 3), 100.0, 1.0) == (1, 1)  # never below one pixel
    with pytest.raises(ConfigError):
        size_for_focal((30, 40), 0.0, 5.0)


def test_input_size_and_focal_ratio():
    op = OperatingPoint((96, 128), (64.0, 48.0))
    assert op.focal == 64.0 and op.hfov_deg == pytest.approx(90.0)
    assert op.input_size((480, 640), 320.0) == (96, 128)
    assert op.focal_ratio(128.0) == op.focal_ratio(32.0) == 2.0


def test_a_size_far_from_the_model_s_focal_length_gets_one_warning_line_naming_both():
    msg = SHIPPED.size_warning((384, 384), 192.0, default_size=(128, 128))
    assert msg is not None and "\n" not in msg
    for part in ("--size 384x384", "192.0 px", "64.0 px (128x128)", "(without --size this input runs at 128x128)"):
        assert part in msg, part
    assert "without" not in SHIPPED.size_warning((384, 384), 192.0)  # the caller did not say: nothing made up
    # within the factor, either way: no warning; just beyond it: a warning
    assert SHIPPED.size_warning((160, 160), 64.0 * FOCAL_WARN_FACTOR) is None
    assert SHIPPED.size_warning((103, 103), 64.0 / FOCAL_WARN_FACTOR) is None
    assert SHIPPED.size_warning((161, 161), 80.5) is not None
    assert SHIPPED.size_warning((100, 100), 50.0, what="--size").startswith("warning: --size 100x100")


def test_the_dict_form_round_trips_and_keeps_unknown_keys():
    motion = MotionStats.from_samples([1.0, 2.0, 3.0])
    op = OperatingPoint((128, 96), (48.0, 64.0), motion, "a run", extra={"note": "kept"})
    d = op.to_dict()
    assert d["note"] == "kept" and d["size"] == [128, 96] and d["step_translation_m"]["median"] == 2.0
    back = OperatingPoint.from_dict(d)
    assert back == op and back.extra == {"note": "kept"}
    assert math.isclose(OperatingPoint.for_hfov((128, 128), 90.0).focal, 64.0)
