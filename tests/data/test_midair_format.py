"""Mid-Air encodings: float16 disparity bits in 16-bit PNGs, disparity -> depth, and the 14 -> 7 class mapping."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from cosemdepth.data.midair import format as fmt
from cosemdepth.data.midair.dataset import read_depth, read_disparity
from cosemdepth.errors import DatasetError


def all_finite_float16() -> np.ndarray:
    bits = np.arange(65536, dtype=np.uint32).astype(np.uint16)
    values = bits.view(np.float16)
    return values[np.isfinite(values)]


def test_disparity_round_trip_through_png_is_bit_exact(tmp_path):
    values = all_finite_float16()
    assert values.size == 63488  # 65536 minus 2 infinities and 2046 NaN patterns
    image = values.reshape(248, 256)
    path = tmp_path / "disp.PNG"
    Image.fromarray(fmt.encode_disparity(image)).save(path)
    with Image.open(path) as im:  # the file really is a 16-bit gray PNG
        assert im.mode == "I;16"
    decoded = read_disparity(path)
    assert decoded.dtype == np.float32
    np.testing.assert_array_equal(decoded.astype(np.float16).view(np.uint16), image.view(np.uint16))
    # every float16 is exactly representable in float32: values are equal, signed zeros included
    np.testing.assert_array_equal(decoded, image.astype(np.float32))
    assert np.signbit(decoded).sum() == np.signbit(image).sum()


def test_depth_is_512_over_disparity_at_any_png_size(tmp_path):
    # Mid-Air's convention (design 10.2, the authors' loader): 512 / disparity whatever the PNG's width. The old
    # reader computed (W / 2) / disparity, wrong for any PNG not at 1024 px.
    disp = np.array([[1.0, 2.0, 0.5, 64.0], [3.0, 0.125, 100.0, 7.5]], dtype=np.float16)
    path = tmp_path / "d.PNG"
    Image.fromarray(disp.view(np.uint16)).save(path)
    depth = read_depth(path)
    expected = np.float32(512.0) / disp.astype(np.float32)
    np.testing.assert_array_equal(depth, expected)
    assert depth[0, 0] == 512.0 and depth[1, 1] == 4096.0


def test_depth_at_1024_is_512_over_disparity(tmp_path):
    disp = np.full((2, 1024), 4.0, dtype=np.float16)
    disp[0, 0] = 0.25
    path = tmp_path / "d.PNG"
    Image.fromarray(disp.view(np.uint16)).save(path)
    depth = read_depth(path)
    assert depth[1, 5] == 128.0 and depth[0, 0] == 2048.0


def test_a_midair_png_downsized_by_a_user_reads_with_unchanged_values(tmp_path):
    """A user resizes a 1024 px Mid-Air disparity PNG (nearest neighbour: the stored values are kept, as image tools
    do); the depths read from the small file are the values of the big one at the kept pixels."""
    rng = np.random.default_rng(3)
    big = (512.0 / rng.uniform(2.0, 900.0, size=(1024, 1024))).astype(np.float16)
    big_path, small_path = tmp_path / "big.PNG", tmp_path / "small.PNG"
    Image.fromarray(big.view(np.uint16)).save(big_path)
    with Image.open(big_path) as im:
        im.resize((256, 256), Image.NEAREST).save(small_path)
    with Image.open(small_path) as im:
        assert im.size == (256, 256) and im.mode == "I;16"
    small_raw = big.view(np.uint16)[2::4, 2::4]  # Pillow's nearest picks the centre pixel of each 4x4 block
    np.testing.assert_array_equal(read_disparity(small_path).astype(np.float16).view(np.uint16), small_raw)
    full, small = read_depth(big_path), read_depth(small_path)
    np.testing.assert_array_equal(small, full[2::4, 2::4])
    np.testing.assert_array_equal(small, np.float32(512.0) / small_raw.view(np.float16).astype(np.float32))


def test_zero_disparity_gives_a_large_finite_depth(tmp_path):
    disp = np.array([[0.0, -0.0, 1.0]], dtype=np.float16)
    path = tmp_path / "d.PNG"
    Image.fromarray(disp.view(np.uint16)).save(path)
    depth = read_depth(path)
    assert np.isfinite(depth).all()
    assert depth[0, 0] == depth[0, 1] == np.float32(512.0) / np.float32(2.0**-24)
    assert depth[0, 2] == 512.0


@pytest.mark.parametrize("bad", [-1.0, np.nan, np.inf])
def test_negative_or_nan_disparity_is_an_error(tmp_path, bad):
    disp = np.array([[1.0, bad], [2.0, 3.0]], dtype=np.float16)
    path = tmp_path / "bad.PNG"
    Image.fromarray(disp.view(np.uint16)).save(path)
    with pytest.raises(DatasetError, match=r"bad\.PNG.*disparity"):
        read_depth(path)


def test_8bit_disparity_png_is_rejected(tmp_path):
    path = tmp_path / "eight.PNG"
    Image.fromarray(np.zeros((4, 4), np.uint8)).save(path)
    with pytest.raises(DatasetError, match=r"eight\.PNG.*16-bit"):
        read_disparity(path)


def test_14_to_7_mapping_matches_spec_9_5():
    # design 10.5, written out independently: Mid-Air ID -> Co-SemDepth class
    spec_table = {0: 0, 1: 6, 2: 2, 3: 3, 4: 3, 5: 3, 6: 4, 7: 6, 8: 1, 9: 6, 10: 5, 11: 6, 12: 6, 13: 6}
    ids = np.arange(14)
    np.testing.assert_array_equal(fmt.map_labels(ids), [spec_table[i] for i in ids])
    assert fmt.CLASSES_7 == ("sky", "water", "trees", "land", "boulders", "road", "others")
    with pytest.raises(ValueError):
        fmt.map_labels(np.array([14]))
