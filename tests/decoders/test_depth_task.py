"""The depth task's warning for runs without usable depth (the same for predict, evaluate and demo)."""

import pytest

from cosemdepth.decoders.depth.task import no_depth_warning


@pytest.mark.parametrize(
    "frames, estimated, held, valid, start",
    [
        (1, 0, 0, 0.0, "no depth was produced: the input has 1 frame: the first frame of a flight is a reset"),
        (3, 0, 0, None, "no depth was produced: all 3 frames are resets (the first frame of each trajectory"),
        (5, 4, 0, 0.0, "no valid depth: not one pixel of the 4 frames with depth is valid: the camera barely moved"),
        (2, 0, 1, 0.0, "no valid depth: not one pixel of the 1 frame with depth is valid"),
    ],
)
def test_why_there_is_no_depth(frames, estimated, held, valid, start):
    assert no_depth_warning(frames, estimated, held, valid).startswith(start)


def test_no_warning_when_some_depth_is_valid():
    assert no_depth_warning(5, 4, 0, 0.01) is None
    assert no_depth_warning(5, 1, 3, None) is None  # valid fraction unknown: frames with depth are enough
    assert no_depth_warning(0, 0, 0, None) is None
