"""The file stem of a frame's source: what predict names its outputs after."""

from __future__ import annotations

import pytest

from cosemdepth.streaming.sinks.files import file_stem


@pytest.mark.parametrize(
    "source, stem",
    [
        ("/flights/a/img_000123.png", "img_000123"),  # an image: its own stem
        ("/flights/clip.MP4#000042", "000042"),  # a video frame: its 0-based index, 6 digits
        ("clip.mkv#1234567", "1234567"),  # more than a million frames: the index as is
        ("t0#002", "t0#002"),  # not a video's frame name: kept
        ("notes.txt#000001", "notes.txt#000001"),  # '#<digits>' after a file that is not a video: kept
        ("/flights/shot#000007.png", "shot#000007"),  # a '#' inside an image's name
    ],
)
def test_file_stem(source, stem):
    assert file_stem(source) == stem
