"""JPEG decoding as the original does it (tf.io.decode_jpeg's default: libjpeg-turbo's fast integer IDCT, fancy
upsampling), checked against pixels decoded by an independent tool, libjpeg-turbo's ``djpeg`` command
(``tests/data/fixtures/jpeg/make_fixtures.py``: ``djpeg -dct fast`` and ``djpeg -dct int``)."""

from __future__ import annotations

import shutil
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageOps

from cosemdepth.data import open_dataset
from cosemdepth.data.decode import decode_jpeg, decode_rgb, image_size, read_channel0, read_rgb
from cosemdepth.data.frames import rgb_to_tensor
from cosemdepth.errors import ConfigError, DatasetError

FIXTURES = Path(__file__).parent / "fixtures" / "jpeg"
CASES = [("rgb444", "ppm", (24, 40)), ("rgb420", "ppm", (23, 37)), ("gray", "pgm", (21, 30))]


def read_pnm(path: Path) -> np.ndarray:
    """Minimal binary PPM/PGM (P6/P5, maxval 255) reader -> [H, W, 3] uint8 (gray replicated)."""
    data = path.read_bytes()
    fields, pos = [], 0
    while len(fields) < 4:  # magic, width, height, maxval (djpeg writes no comments)
        while data[pos : pos + 1].isspace():
            pos += 1
        end = pos
        while not data[end : end + 1].isspace():
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


@pytest.mark.parametrize(
    "content,pattern",
    [
        (b"", "not a JPEG"),
        (b"hello, not an image", "not a JPEG"),
        (b"\x89PNG\r\n\x1a\n" + b"\0" * 40, "not a JPEG"),
        (b"\xff\xd8\xff", "corrupt JPEG"),
    ],
)
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


# ------------------------------------------------------------------------------------------ EXIF orientation


def _photo(h=12, w=20):
    """A picture whose rows and columns are all different (a transposition cannot go unnoticed)."""
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([y * 20, x * 12, (x * 7 + y * 3) % 256], axis=2).astype(np.uint8)


def _save_with_orientation(img: Image.Image, path: Path, orientation: int | None, **kw) -> Path:
    exif = Image.Exif()
    if orientation is not None:
        exif[0x0112] = orientation
    img.save(path, exif=exif.tobytes(), **kw)
    return path


def test_jpeg_orientation_6_gives_the_pixels_rotated_90_degrees_clockwise(tmp_path):
    img = Image.fromarray(_photo())
    plain = read_rgb(_save_with_orientation(img, tmp_path / "plain.jpg", None, quality=95))
    tagged = _save_with_orientation(img, tmp_path / "tagged.jpg", 6, quality=95)
    got = read_rgb(tagged)
    assert plain.shape == (12, 20, 3) and got.shape == (20, 12, 3)
    np.testing.assert_array_equal(got, np.rot90(plain, -1))  # rotate 90 clockwise: column 0 becomes the top row
    np.testing.assert_array_equal(got[0, :, :], plain[::-1, 0, :])
    assert image_size(tagged) == (20, 12)
    assert image_size(tmp_path / "plain.jpg") == (12, 20)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_every_orientation_matches_pillows_exif_transpose(tmp_path, orientation):
    """JPEG (accurate IDCT, Pillow's) and PNG (eXIf chunk): the arrays equal Pillow's own transposition."""
    img = Image.fromarray(_photo())
    jpg = _save_with_orientation(img, tmp_path / "a.jpg", orientation, quality=95)
    png = _save_with_orientation(img, tmp_path / "a.png", orientation)
    for path, kw in ((jpg, {"jpeg_idct": "accurate"}), (png, {})):
        want = np.asarray(ImageOps.exif_transpose(Image.open(path)).convert("RGB"))
        got = read_rgb(path, **kw)
        np.testing.assert_array_equal(got, want)
        assert image_size(path) == want.shape[:2]
    labels = Image.fromarray(_photo()[..., 0])
    lab = _save_with_orientation(labels, tmp_path / "l.png", orientation)
    np.testing.assert_array_equal(read_channel0(lab), np.asarray(ImageOps.exif_transpose(Image.open(lab))))


def test_compressed_image_bytes_are_oriented_too(tmp_path):
    path = _save_with_orientation(Image.fromarray(_photo()), tmp_path / "a.jpg", 8, quality=95)
    plain = read_rgb(_save_with_orientation(Image.fromarray(_photo()), tmp_path / "b.jpg", 1, quality=95))
    np.testing.assert_array_equal(decode_rgb(path.read_bytes(), "msg"), np.rot90(plain, 1))


def test_flight_sees_the_displayed_size_for_intrinsics(tmp_path):
    """A flight of portrait photos stored landscape with orientation 6: native size, intrinsics and tensors are
    the portrait ones (hfov 90: fx = W/2 = 6, cx = 6, cy = 10)."""
    folder = tmp_path / "f"
    folder.mkdir()
    for k in range(2):
        _save_with_orientation(Image.fromarray(_photo()), folder / f"{k}.jpg", 6, quality=95)
    (folder / "poses.txt").write_text("0 0 0 0 0 0 0 1\n1 0 0 1 0 0 0 1\n")
    ds = open_dataset("flight", folder, fov=90.0)
    it = ds[0]
    assert it["rgb"].shape == (1, 3, 20, 12)
    assert it["intrinsics"].tolist() == [6.0, 6.0, 6.0, 10.0]
    np.testing.assert_allclose(it["rgb"][0].permute(1, 2, 0).numpy() * 255, read_rgb(folder / "0.jpg"), atol=1e-3)


# ------------------------------------------------------------------------------------------ 16-bit images


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def png16(arr: np.ndarray) -> bytes:
    """A 16-bit PNG written by hand (the PNG spec: IHDR, zlib IDAT, each row filtered with filter type
    ``row % 5``: None, Sub, Up, Average, Paeth), so that every unfilter path of the reader is exercised.
    ``arr``: ``[H, W]`` gray, ``[H, W, 3]`` RGB or ``[H, W, 4]`` RGBA uint16."""
    h, w = arr.shape[:2]
    ch = 1 if arr.ndim == 2 else arr.shape[2]
    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[ch]
    bpp = 2 * ch
    rows, prior = [], np.zeros(w * bpp, np.int64)
    for i in range(h):
        cur = np.frombuffer(np.ascontiguousarray(arr[i]).astype(">u2").tobytes(), np.uint8).astype(np.int64)
        left = np.concatenate([np.zeros(bpp, np.int64), cur[:-bpp]])
        upleft = np.concatenate([np.zeros(bpp, np.int64), prior[:-bpp]])
        f = i % 5
        if f == 0:
            pred = np.zeros_like(cur)
        elif f == 1:
            pred = left
        elif f == 2:
            pred = prior
        elif f == 3:
            pred = (left + prior) // 2
        else:
            p = left + prior - upleft
            pa, pb, pc = abs(p - left), abs(p - prior), abs(p - upleft)
            pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, prior, upleft))
        rows.append(bytes([f]) + ((cur - pred) % 256).astype(np.uint8).tobytes())
        prior = cur
    ihdr = struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", ihdr)
        + _chunk(b"IDAT", zlib.compress(b"".join(rows)))
        + _chunk(b"IEND", b"")
    )


RGB16 = np.random.default_rng(1).integers(0, 65536, (9, 11, 3), dtype=np.uint16)


def test_16bit_rgb_png_keeps_every_bit_and_scales_by_65535(tmp_path):
    p = tmp_path / "a.png"
    p.write_bytes(png16(RGB16))
    got = read_rgb(p)
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, RGB16)
    assert np.count_nonzero(got & 0xFF)  # the low bytes are there (Pillow alone keeps only the high ones)
    np.testing.assert_allclose(rgb_to_tensor(got, None).numpy(), RGB16.transpose(2, 0, 1) / 65535.0, atol=1e-7)
    rgba = np.concatenate([RGB16, np.full((9, 11, 1), 7, np.uint16)], axis=2)
    p.write_bytes(png16(rgba))
    np.testing.assert_array_equal(read_rgb(p), RGB16)  # alpha dropped


def test_16bit_gray_png_is_read_with_full_precision(tmp_path):
    gray = RGB16[..., 0]
    p = tmp_path / "g.png"
    p.write_bytes(png16(gray))
    got = read_rgb(p)
    assert got.dtype == np.uint16
    np.testing.assert_array_equal(got, np.repeat(gray[..., None], 3, axis=2))


def test_16bit_images_reach_the_model_input_at_full_precision(tmp_path):
    """A flight of 16-bit RGB PNGs: the dataset's tensor is value / 65535 (not the 8-bit truncation)."""
    folder = tmp_path / "f"
    folder.mkdir()
    for k in range(2):
        (folder / f"{k}.png").write_bytes(png16(RGB16))
    (folder / "poses.txt").write_text("0 0 0 0 0 0 0 1\n1 0 0 1 0 0 0 1\n")
    rgb = open_dataset("flight", folder, fov=90.0)[0]["rgb"][0].numpy()
    np.testing.assert_allclose(rgb, RGB16.transpose(2, 0, 1) / 65535.0, atol=1e-7)


def test_16bit_gray_alpha_and_16bit_colour_maps_are_refused_naming_the_file(tmp_path):
    p = tmp_path / "ga.png"
    p.write_bytes(png16(RGB16[..., :2]))
    with pytest.raises(DatasetError, match=r"ga\.png: 16-bit gray\+alpha PNGs are not supported"):
        read_rgb(p)
    p = tmp_path / "label.png"
    p.write_bytes(png16(RGB16))
    with pytest.raises(DatasetError, match=r"label\.png: 16-bit colour PNGs are not supported for label/depth"):
        read_channel0(p)


def test_corrupt_16bit_rgb_png_is_a_dataset_error(tmp_path):
    data = png16(RGB16)
    p = tmp_path / "c.png"
    p.write_bytes(data[:60] + bytes(20) + data[80:])
    with pytest.raises(DatasetError, match=r"c\.png: corrupt image"):
        read_rgb(p)


# ------------------------------------------------------------------------------------------ reduced-size decoding


def _smooth_jpeg(h=48, w=64) -> bytes:
    import io

    y, x = np.mgrid[0:h, 0:w]
    img = np.stack([y * 5, x * 4, (x * 2 + y * 3) % 256], axis=2).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, "JPEG", quality=95)
    return buf.getvalue()


@pytest.mark.parametrize(
    "min_size,shape",
    [
        ((16, 16), (18, 24)),
        ((18, 24), (18, 24)),
        ((19, 24), (24, 32)),
        ((1, 1), (6, 8)),
        ((40, 10), (42, 56)),
        ((48, 64), (48, 64)),
        ((100, 100), (48, 64)),
    ],
)
def test_reduced_decoding_picks_the_smallest_eighth_scale_at_least_the_size(min_size, shape):
    """48 x 64 at M/8 is ceil(6 M) x 8 M: the smallest M with both sides at least ``min_size`` (full size when none
    is smaller)."""
    got = decode_jpeg(_smooth_jpeg(), "x.jpg", min_size=min_size)
    assert got.shape == (*shape, 3) and got.dtype == np.uint8


def test_reduced_decoding_at_full_scale_is_the_plain_decode_and_smaller_is_close_to_it():
    data = _smooth_jpeg()
    plain = decode_jpeg(data, "x.jpg")
    np.testing.assert_array_equal(decode_jpeg(data, "x.jpg", min_size=(48, 64)), plain)
    np.testing.assert_array_equal(decode_jpeg(data, "x.jpg", min_size=(60, 1)), plain)
    # at 1/2 a pixel is about the mean of its 2x2 block of the full decode (a smooth picture: a few levels)
    half = decode_jpeg(data, "x.jpg", min_size=(24, 32)).astype(np.float64)
    blocks = plain.astype(np.float64).reshape(24, 2, 32, 2, 3).mean(axis=(1, 3))
    assert half.shape == blocks.shape and np.abs(half - blocks).mean() < 2.0


def test_reduced_decoding_chooses_the_scale_on_the_displayed_size(tmp_path):
    """Stored 64 wide x 32 high, EXIF 6 (displayed 32 x 64): at least 24 high x 8 wide as displayed needs the stored
    width >= 24 (M = 3: 24 x 12, displayed 24 x 12); on the stored size it would be M = 6 (displayed 48 x 24)."""
    img = Image.fromarray(_photo(32, 64))
    path = _save_with_orientation(img, tmp_path / "t.jpg", 6, quality=95)
    assert read_rgb(path).shape == (64, 32, 3)
    assert read_rgb(path, min_size=(24, 8)).shape == (24, 12, 3)


def test_training_decodes_reduced_and_validation_exactly(tmp_path):
    """``data.train_decode``: the training dataset's loader decodes at the reduced size, the validation one never;
    ``exact`` gives the plain pixels; the option is refused as a dataset option and when unknown."""
    from _writers import write_midair

    from cosemdepth.data.midair.splits import generate_splits
    from cosemdepth.models.config import ModelConfig
    from cosemdepth.training.config import DataConfig, DatasetSource
    from cosemdepth.training.data import build_train_dataset, build_val_dataset

    root = tmp_path / "ds"
    write_midair(root, {("Kite_training", "sunny"): [0, 1], ("Kite_training", "cloudy"): [2]}, frames=24, size=64)
    generate_splits(root, root / "splits")
    src = DatasetSource(name="synthair", root=str(root), split_dir=str(root / "splits"))
    model = ModelConfig()

    def loaders(**kw):
        data = DataConfig(
            train=(src,), val=src, size=(16, 16), augment=False, seq_len=2, val_seq_len=2, val_split="test", **kw
        )
        return build_train_dataset(data, model, 0), build_val_dataset(data, model, 0)

    train, val = loaders()
    assert DataConfig(train=(src,)).train_decode == "reduced"
    assert train.load_frame.reduced_decode is True and val.load_frame.reduced_decode is False
    exact_train, exact_val = loaders(train_decode="exact")
    assert exact_train.load_frame.reduced_decode is False
    assert torch_equal(val[0]["rgb"], exact_val[0]["rgb"])
    # 64 px sources at 16 px: the training loader decodes at 2/8 (16 px), the validation one at full size
    rec = train.trajectories[0].frame(0)
    small = read_rgb(rec.rgb, min_size=(16, 16))
    assert small.shape == (16, 16, 3)
    assert torch_equal(train.load_frame(rec)["rgb"], rgb_to_tensor(small, (16, 16)))
    assert torch_equal(exact_train.load_frame(rec)["rgb"], rgb_to_tensor(read_rgb(rec.rgb), (16, 16)))
    with pytest.raises(ConfigError, match="data.train_decode"):
        DataConfig(train=(src,), train_decode="fast")
    bad = DatasetSource(
        name="synthair", root=str(root), split_dir=str(root / "splits"), options={"reduced_decode": True}
    )
    with pytest.raises(ConfigError, match=r"options.reduced_decode"):
        build_train_dataset(DataConfig(train=(bad,), size=(16, 16), augment=False), model, 0)


def torch_equal(a, b) -> bool:
    import torch

    return bool(torch.equal(a, b))


def _png16_rgb(height: int, width: int, idat: bytes | None = None) -> bytes:
    """A 16-bit RGB PNG of the given declared size; ``idat`` the compressed rows (default: all zero rows)."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    if idat is None:
        idat = zlib.compress(b"".join(b"\x00" + bytes(6 * width) for _ in range(height)))
    ihdr = struct.pack(">IIBBBBB", width, height, 16, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


@pytest.mark.parametrize(
    "data",
    [
        _png16_rgb(4, 9)[:33],  # the header alone
        _png16_rgb(65535, 65535, idat=b""),  # a declared size far beyond any image (4.3 gigapixels)
        _png16_rgb(4, 9, idat=zlib.compress(b"\x00" * 7)),  # fewer rows than declared
    ],
    ids=["header-only", "huge", "short-rows"],
)
def test_damaged_16_bit_colour_pngs_are_dataset_errors_naming_the_file(tmp_path, data):
    np.testing.assert_array_equal(decode_rgb(_png16_rgb(4, 9), "ok.png"), np.zeros((4, 9, 3), np.uint16))
    path = tmp_path / "000004.png"
    path.write_bytes(data)
    with pytest.raises(DatasetError, match="000004.png"):
        read_rgb(path)
