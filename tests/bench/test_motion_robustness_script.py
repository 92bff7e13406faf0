"""benchmarks/motion_robustness.py: the acceptance checks on hand-made results (criterion e: the baseline policy must
not make the fly rows of the hover and yaw flights worse than every-frame), and the rows' segments."""

import importlib.util
import math
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "motion_robustness.py"


@pytest.fixture(scope="module")
def script():
    spec = importlib.util.spec_from_file_location("motion_robustness_script", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def figures(abs_rel, valid_abs_rel=None):
    v = abs_rel if valid_abs_rel is None else valid_abs_rel
    return {"abs_rel": abs_rel, "valid_abs_rel": v, "coverage": 0.98, "valid_nonpositive_pixels": 0}


def results(yaw_fly_baseline):
    """Hover and yaw flights whose still rows pass (a); the yaw flight's fly rows under the baseline policy as given
    (every-frame: 0.20)."""
    out = {}
    for regime, seg, fly_base in (("hover", "hover", 0.16), ("yaw", "yaw", yaw_fly_baseline)):
        out[regime] = {
            "baseline": {seg: figures(0.2), "fly": figures(fly_base)},
            "every-frame": {seg: figures(1.0, math.nan), "fly": figures(0.2 if regime == "yaw" else 0.17)},
        }
    return out


def test_fly_rows_no_worse_than_every_frame_within_one_percent(script):
    acc = script.acceptance(results(0.2019))  # 1.0095 x
    assert acc["e_fly"]["yaw"]["ratio"] == pytest.approx(0.2019 / 0.2)
    assert acc["e_fly"]["yaw"]["ok"] and acc["e_fly"]["hover"]["ok"] and acc["e_fly"]["ok"] and acc["all_ok"]
    acc = script.acceptance(results(0.2021))  # 1.0105 x: worse than every-frame beyond the 1 %
    assert not acc["e_fly"]["yaw"]["ok"] and acc["e_fly"]["hover"]["ok"]
    assert not acc["e_fly"]["ok"] and not acc["all_ok"] and acc["a_still"]["ok"]
    assert "yaw: fly rows AbsRel 0.2021 (baseline) vs 0.2000 (every-frame) = 1.010x" in script._acceptance_line(
        "e_fly", acc["e_fly"]
    )


def test_rows_belong_to_the_segment_that_holds_both_frames(script):
    meta = {
        "frame_step": 4,
        "frames": 200,
        "motion": {
            "segments": [
                {"segment": "fly", "frames": [0, 80]},
                {"segment": "yaw:40@90", "frames": [80, 120]},
                {"segment": "fly", "frames": [120, 200]},
            ]
        },
    }
    kind = script.row_kinds(meta)
    # row k joins frames 4k and 4k + 4
    assert [kind(k) for k in (0, 19, 20, 29, 30, 48)] == ["fly", "fly", "yaw", "yaw", "fly", "fly"]
