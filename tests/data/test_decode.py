"""JPEG decoding as the original does it (tf.io.decode_jpeg's default: libjpeg-turbo's fast integer IDCT, fancy
upsampling), checked against pixels decoded by an independent tool, libjpeg-turbo's ``djpeg`` command
(``tests/data/fixtures/jpeg/make_fixtures.py``: ``djpeg -dct fast`` and ``djpeg -dct int``)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cosemdepth.data import open_dataset
from cosemdepth.data.decode import decode_jpeg, read_rgb
from cosemdepth.errors import ConfigError, DatasetError

FIXTURES = Path(__file__).parent / "fixtures" / "jpeg"
CASES = [("rgb444", "ppm", (24, 40)), ("rgb420", "ppm", (23, 37)), ("gray", "pgm", (21, 30))]


def read_pnm(path: Path) -> np.ndarray:
    """Minimal binary PPM/PGM (P6/P5, maxval 255) reader -> [H, W, 3] uint8 (gray replicated)."""
    data = path.read_bytes()
    fields, pos = [], 0
    while len(fields) < 4:  # magic, width, height, maxval (djpeg writes no comments)
        while data[pos:pos + 1].isspace():
            pos += 1
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        fields.append(data[pos:end])
        pos = end
    pos += 1  # the single whitespace byte after maxval
    magic, w, h, maxval = fields[0], int(fields[1]), int(fields[2]), int(fields[3])
    assert maxval == 255 and magic in (b"P5", b"P6")
    ch = 3 if magic == b"P6" else 1
    arr = np.frombuffer(data, np.uint8, count=h * w * ch, offset=pos).reshape(h, w, ch)
    return np.ascontiguousarray(np.repeat(arr, 3, axis=2) if ch == 1 else arr)


@pytest.mark.parametrize("name,ext,shape", CASES)
def test_default_decoding_is_djpeg_fast_idct_bit_for_bit(name, ext, shape):
    expected = read_pnm(FIXTURES / f"{name}.ifast.{ext}")
    got = read_rgb(FIXTURES / f"{name}.jpg")
    assert got.shape == (*shape, 3) and got.dtype == np.uint8
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("name,ext,shape", CASES)
def test_accurate_option_is_djpeg_accurate_idct_and_differs_from_fast(name, ext, shape):
    accurate = read_pnm(FIXTURES / f"{name}.islow.{ext}")
    np.testing.assert_array_equal(read_rgb(FIXTURES / f"{name}.jpg", jpeg_idct="accurate"), accurate)
    fast = read_pnm(FIXTURES / f"{name}.ifast.{ext}")
    assert np.count_nonzero(fast != accurate) > fast.size // 10  # the two IDCTs really differ on these files


def test_a_jpeg_is_decoded_by_content_not_by_name(tmp_path):
    p = tmp_path / "frame.png"  # a JPEG with a misleading name
    shutil.copy(FIXTURES / "rgb420.jpg", p)
    np.testing.assert_array_equal(read_rgb(p), read_pnm(FIXTURES / "rgb420.ifast.ppm"))


def test_png_colour_images_still_decode_with_pillow(tmp_path):
    rgb = np.random.default_rng(0).integers(0, 256, (5, 7, 3), dtype=np.uint8)
    Image.fromarray(rgb).save(tmp_path / "a.png")
    np.testing.assert_array_equal(read_rgb(tmp_path / "a.png"), rgb)


@pytest.mark.parametrize("content,pattern", [
    (b"", "not a JPEG"),
    (b"hello, not an image", "not a JPEG"),
    (b"\x89PNG\r\n\x1a\n" + b"\0" * 40, "not a JPEG"),
    (b"\xff\xd8\xff", "corrupt JPEG"),
])
def test_bad_jpeg_files_are_dataset_errors_naming_the_file(tmp_path, content, pattern):
    p = tmp_path / "bad.JPEG"
    p.write_bytes(content)
    with pytest.raises(DatasetError, match=rf"bad\.JPEG: .*{pattern}"):
        read_rgb(p)


def test_truncated_and_damaged_jpegs_are_dataset_errors(tmp_path):
    data = (FIXTURES / "rgb420.jpg").read_bytes()
    for k, blob in enumerate([data[: len(data) // 2], data[:600] + bytes(200), data[:-2]]):
        p = tmp_path / f"t{k}.jpg"
        p.write_bytes(blob)
        with pytest.raises(DatasetError, match=rf"t{k}\.jpg: corrupt JPEG"):
            read_rgb(p)
    with pytest.raises(DatasetError, match="file not found"):
        read_rgb(tmp_path / "missing.jpg")
    with pytest.raises(DatasetError, match="is a folder"):
        read_rgb(tmp_path)


def test_bad_idct_option_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="jpeg_idct"):
        read_rgb(FIXTURES / "gray.jpg", jpeg_idct="islow")
    with pytest.raises(ConfigError, match="jpeg_idct"):
        decode_jpeg(b"", "x.jpg", jpeg_idct="float")


def test_dataset_readers_decode_jpegs_the_original_way_by_default(tmp_path):
    """A Mid-Air-format set whose colour frames are the fixture JPEG: the dataset item holds the IFAST pixels / 255
    (native size, no resize), and ``jpeg_idct="accurate"`` gives the ISLOW ones."""
    from _writers import write_midair

    from cosemdepth.data.midair.splits import generate_splits

    root = tmp_path / "ds"
    write_midair(root, {("Kite_training", "sunny"): [0]}, frames=12, size=16)
    generate_splits(root, root / "splits")
    jpgs = sorted(root.rglob("*.JPEG"))
    assert jpgs
    for j in jpgs:
        shutil.copy(FIXTURES / "rgb444.jpg", j)
    fast, accurate = read_pnm(FIXTURES / "rgb444.ifast.ppm"), read_pnm(FIXTURES / "rgb444.islow.ppm")
    for idct, expected in (("fast", fast), (None, fast), ("accurate", accurate)):
        kw = {} if idct is None else {"jpeg_idct": idct}
        ds = open_dataset("synthair", root, split="test", seq_len=1, size=(24, 40), modalities=(), **kw)
        rgb = ds[0]["rgb"][0].permute(1, 2, 0).numpy()
        np.testing.assert_allclose(rgb * 255.0, expected.astype(np.float32), atol=1e-3)
    with pytest.raises(ConfigError, match="jpeg_idct"):
        open_dataset("synthair", root, split="test", jpeg_idct="slow")
