"""Fuzz tests of the image readers: colour JPEG/PNG, Mid-Air disparity PNGs (float16 bit patterns in uint16),
segmentation PNGs (Mid-Air, TopAir, Aeroscapes), TopAir 8-bit depth, and a flight's ``.npy``/``.png`` depth.

Files are written in the right format and in wrong ones (other bit depths and colour types, written from the PNG
definition by tests/fuzzing.py, not by the reader's library), then byte-mutated or given huge declared sizes.
Allowed outcomes (tests/fuzzing.py): a result with the right shape, dtype and value range (equal to what was
written when the file is a valid, unchanged one), or a CosemdepthError naming the file. Everything goes through
the readers' public functions.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
from fuzzing import fuzz_settings, jpeg_with_size, mutate_bytes, outcome, png_bytes, png_with_size, write
from hypothesis import event, given
from hypothesis import strategies as st
from PIL import Image

from cosemdepth.data.aeroscapes import AeroscapesFrameLoader
from cosemdepth.data.decode import image_size, read_rgb
from cosemdepth.data.flight import FlightFrameLoader
from cosemdepth.data.midair.dataset import read_depth, read_labels
from cosemdepth.data.sequence import FrameRecord
from cosemdepth.data.topair import read_depth8
from cosemdepth.errors import DatasetError

GRAY, RGB, PALETTE, GRAY_ALPHA, RGBA = 0, 2, 3, 4, 6
CHANNELS = {GRAY: 1, RGB: 3, PALETTE: 1, GRAY_ALPHA: 2, RGBA: 4}
#: (bit depth, colour type) pairs the PNG standard allows.
PNG_FORMATS = [
    (1, GRAY),
    (2, GRAY),
    (4, GRAY),
    (8, GRAY),
    (16, GRAY),
    (8, RGB),
    (16, RGB),
    (1, PALETTE),
    (4, PALETTE),
    (8, PALETTE),
    (8, GRAY_ALPHA),
    (16, GRAY_ALPHA),
    (8, RGBA),
    (16, RGBA),
]
#: Declared sizes (width, height) of the "huge header" variant: each would need from hundreds of MB to many GB.
HUGE_SIZES = [
    (65535, 65535),
    (20000, 20000),
    (100_000, 2000),
    (2000, 100_000_000),
    (2**31 - 1, 2**31 - 1),
    (0, 5),
    (5, 0),
]


def sizes():
    return st.tuples(st.integers(1, 9), st.integers(1, 9))


@st.composite
def png_file(draw, values: st.SearchStrategy, fmt=None) -> tuple[bytes, np.ndarray, tuple[int, int]]:
    """``(bytes, samples [H, W, C], (bit depth, colour type))`` of a PNG of any legal format (or ``fmt``)."""
    bit_depth, colour = fmt or draw(st.sampled_from(PNG_FORMATS))
    h, w = draw(sizes())
    c = CHANNELS[colour]
    top = (1 << bit_depth) - 1
    a = np.array(draw(st.lists(values, min_size=h * w * c, max_size=h * w * c)), dtype=np.int64).reshape(h, w, c)
    a = np.clip(a, 0, top)
    palette = bytes(draw(st.binary(min_size=3 * (top + 1), max_size=3 * (top + 1)))) if colour == PALETTE else None
    return png_bytes(a, bit_depth, colour, palette), a, (bit_depth, colour)


@st.composite
def damaged(draw, data: bytes, is_png: bool) -> bytes:
    """``data`` unchanged, byte-mutated, or with a huge declared size."""
    kind = draw(st.sampled_from(("same", "mutate", "mutate", "huge")))
    if kind == "same":
        return data
    if kind == "mutate":
        return draw(mutate_bytes(data))
    w, h = draw(st.sampled_from(HUGE_SIZES))
    return png_with_size(data, w, h) if is_png else jpeg_with_size(data, min(w, 65535), min(h, 65535))


def jpeg_bytes(a: np.ndarray, subsampling: int) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="JPEG", quality=95, subsampling=subsampling)
    return buf.getvalue()


@fuzz_settings(max_examples=80)
@given(data=st.data(), jpeg=st.booleans())
def test_fuzz_rgb(tmp_path_factory, data, jpeg):
    """Colour images (Mid-Air/TopAir/Aeroscapes/flight frames): JPEG, or PNG of any format."""
    folder = tmp_path_factory.getbasetemp() / "fuzz_rgb"
    if jpeg:
        h, w = data.draw(sizes())
        base = np.linspace(0, 255, h * w * 3).reshape(h, w, 3).astype(np.uint8)
        good, truth = jpeg_bytes(base, data.draw(st.sampled_from((0, 2)))), base
        path = folder / "000004.JPEG"
    else:
        good, samples, (bit_depth, colour) = data.draw(png_file(st.integers(0, 65535)))
        # what a valid file must give: its samples as written (16-bit ones with every bit, gray replicated)
        truth = {
            (8, RGB): samples.astype(np.uint8),
            (16, RGB): samples.astype(np.uint16),
            (16, RGBA): samples[..., :3].astype(np.uint16),
            (16, GRAY): np.repeat(samples, 3, axis=2).astype(np.uint16),
        }.get((bit_depth, colour))
        path = folder / "000004.png"
    raw = data.draw(damaged(good, not jpeg))
    write(path, raw)

    def check(rgb) -> None:
        assert isinstance(rgb, np.ndarray) and rgb.ndim == 3 and rgb.shape[2] == 3
        assert rgb.dtype in (np.uint8, np.uint16)
        if raw == good:
            assert rgb.dtype == (np.uint16 if not jpeg and bit_depth == 16 else np.uint8)
        assert rgb.shape[0] >= 1 and rgb.shape[1] >= 1
        if raw == good and truth is not None:
            if jpeg:  # lossy: close to what was written, same size
                assert rgb.shape == truth.shape
                assert np.abs(rgb.astype(int) - truth).mean() < 12
            else:
                np.testing.assert_array_equal(rgb, truth)

    outcome(lambda: read_rgb(path), [path], check)
    outcome(lambda: image_size(path), [path], lambda hw: None if raw != good else None)


@fuzz_settings(max_examples=80)
@given(data=st.data())
def test_fuzz_midair_disparity(tmp_path_factory, data):
    """Mid-Air disparity PNGs: any 16-bit pattern (NaN, inf, negative, subnormal, zero), any PNG format."""
    right = data.draw(st.booleans())
    # valid disparities (positive finite float16 patterns, zero and subnormals included) or any 16-bit pattern
    values = data.draw(st.sampled_from((st.integers(0, 0x7BFF), st.integers(0, 65535))))
    good, samples, fmt = data.draw(png_file(values, fmt=(16, GRAY) if right else None))
    raw = data.draw(damaged(good, True))
    path = write(tmp_path_factory.getbasetemp() / "fuzz_disp" / "000004.PNG", raw)

    def check(depth) -> None:
        assert depth.dtype == np.float32 and depth.ndim == 2
        assert np.isfinite(depth).all() and (depth > 0).all()
        if raw == good:
            event("valid disparity map read")
            assert fmt == (16, GRAY), f"a {fmt} PNG was read as a disparity map"
            disp = samples[..., 0].astype(np.uint16).view(np.float16).astype(np.float32)
            assert np.isfinite(disp).all() and (disp >= 0).all(), "an invalid disparity was read"
            # depth is inversely proportional to the stored disparity (zero read as the smallest float16)
            k = depth * np.maximum(disp, np.float32(np.finfo(np.float16).smallest_subnormal))
            np.testing.assert_allclose(k, k.flat[0], rtol=1e-6)

    outcome(lambda: read_depth(path), [path], check)


@fuzz_settings(max_examples=80)
@given(data=st.data(), which=st.sampled_from(("midair", "topair_labels", "topair_depth")))
def test_fuzz_label_and_8bit_maps(tmp_path_factory, data, which):
    """Segmentation PNGs (Mid-Air 14 IDs, TopAir 9 classes) and TopAir 8-bit depth, any PNG format."""
    values = data.draw(st.sampled_from((st.integers(0, 8), st.integers(0, 20), st.integers(0, 65535))))
    good, samples, fmt = data.draw(png_file(values))
    raw = data.draw(damaged(good, True))
    path = write(tmp_path_factory.getbasetemp() / "fuzz_labels" / "000004.PNG", raw)
    h, w = samples.shape[:2]
    values = samples[..., 0]
    if fmt[1] == GRAY and fmt[0] in (2, 4):
        # 2- and 4-bit gray samples are read at 8 bits, scaled to the full range as the PNG standard (and the
        # original's TF decoder) does: 1 in a 4-bit file reads 17. 1-bit gray reads 0/1.
        values = values * (255 // ((1 << fmt[0]) - 1))

    if which == "topair_depth":

        def check(depth) -> None:
            assert depth.dtype == np.float32 and depth.ndim == 2
            assert np.isfinite(depth).all() and (depth >= 0).all() and (depth <= 100).all()
            if raw == good and fmt[1] != PALETTE:
                np.testing.assert_allclose(depth, values * np.float32(100 / 255), rtol=1e-6)

        outcome(lambda: read_depth8(path), [path], check)
        return
    num = 14 if which == "midair" else 9

    def check_labels(ids) -> None:
        assert ids.ndim == 2 and ids.dtype.kind in "ui"
        assert ids.min() >= 0 and ids.max() < num
        if raw == good:
            assert ids.shape == (h, w)
            np.testing.assert_array_equal(ids, values)

    if which == "midair":
        outcome(lambda: read_labels(path, "raw"), [path], check_labels)
    else:
        from cosemdepth.data.decode import read_label_ids

        outcome(lambda: read_label_ids(path, num), [path], check_labels)


@fuzz_settings(max_examples=40)
@given(data=st.data(), dataset=st.sampled_from(("midair", "topair", "aeroscapes")))
def test_fuzz_frame_loaders(tmp_path_factory, data, dataset):
    """A whole frame (colour + depth + labels, each possibly damaged) through each dataset's frame loader, resized
    to another size: finite tensors of the right shapes and ranges, or an error naming the damaged file."""
    from cosemdepth.data.midair.dataset import MidAirFrameLoader
    from cosemdepth.data.topair import TopAirFrameLoader

    folder = tmp_path_factory.getbasetemp() / "fuzz_frames"
    h, w = data.draw(sizes())
    colour = jpeg_bytes(np.full((h, w, 3), 90, np.uint8), 0)
    rgb = write(folder / "rgb.jpg", data.draw(damaged(colour, False)))
    depth = None
    if dataset == "midair":
        disp = np.full((h, w), 2.0, np.float16).view(np.uint16)
        depth = write(folder / "disp.png", data.draw(damaged(png_bytes(disp, 16, GRAY), True)))
        loader, classes = MidAirFrameLoader((5, 7), "midair"), 7
    elif dataset == "topair":
        depth = write(folder / "depth.png", data.draw(damaged(png_bytes(np.full((h, w), 128), 8, GRAY), True)))
        loader, classes = TopAirFrameLoader((5, 7)), 9
    else:
        loader, classes = AeroscapesFrameLoader((5, 7)), 12
    good, samples, fmt = data.draw(png_file(st.integers(0, 8), fmt=(8, GRAY)))
    sem = write(folder / "sem.png", data.draw(damaged(good, True)))

    def check(item) -> None:
        assert item["rgb"].shape == (3, 5, 7) and item["semantic"].shape == (5, 7)
        assert bool(item["rgb"].isfinite().all()) and float(item["rgb"].min()) >= 0 and float(item["rgb"].max()) <= 1
        assert int(item["semantic"].min()) >= 0 and int(item["semantic"].max()) < classes
        if depth is not None:
            d = item["depth"]
            assert d.shape == (1, 5, 7) and bool(d.isfinite().all()) and float(d.min()) >= 0

    paths = [rgb, sem] + ([depth] if depth is not None else [])
    outcome(lambda: loader(FrameRecord(rgb=rgb, depth=depth, semantic=sem)), paths, check)


def _npy_bytes(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a, allow_pickle=False)
    return buf.getvalue()


@st.composite
def depth_arrays(draw):
    h, w = draw(sizes())
    kind = draw(
        st.sampled_from(
            ("float32", "float64", "float16", "uint16", "int32", "bool", "complex64", "U3", "3d", "1d", "0d", "special")
        )
    )
    if kind == "special":
        a = np.array(
            draw(
                st.lists(
                    st.sampled_from([np.nan, np.inf, -np.inf, -1.0, 0.0, 1e30, 5.0]), min_size=h * w, max_size=h * w
                )
            ),
            dtype=np.float32,
        ).reshape(h, w)
    elif kind == "3d":
        a = np.ones((h, w, 2), np.float32)
    elif kind == "1d":
        a = np.ones(h * w, np.float32)
    elif kind == "0d":
        a = np.array(3.0, np.float32)
    elif kind == "U3":
        a = np.full((h, w), "abc")
    else:
        a = (np.arange(h * w).reshape(h, w) % 7 + 1).astype(kind)
    return a


@fuzz_settings(max_examples=50)
@given(data=st.data(), npy=st.booleans())
def test_fuzz_flight_depth(tmp_path_factory, data, npy):
    """A flight's ground-truth depth: ``.npy`` of any dtype/shape/values, or a PNG of any format."""
    folder = tmp_path_factory.getbasetemp() / "fuzz_flight_depth"
    img = folder / "img.png"
    if not img.exists():
        write(img, png_bytes(np.zeros((4, 6, 3), np.uint8), 8, RGB))
    if npy:
        a = data.draw(depth_arrays())
        good = _npy_bytes(a)
        raw = data.draw(st.sampled_from(["same", "mutate"]))
        raw = good if raw == "same" else data.draw(mutate_bytes(good))
        path = write(folder / "depth" / "img.npy", raw)
    else:
        a = None
        good, samples, fmt = data.draw(png_file(st.integers(0, 65535)))
        raw = data.draw(damaged(good, True))
        path = write(folder / "depth" / "img.png", raw)

    def check(item) -> None:
        d = item["depth"]
        assert d.shape == (1, 4, 6) and bool(d.isfinite().all()) and float(d.min()) >= 0

    loader = FlightFrameLoader((4, 6), (4, 6), 0.001, 7)
    outcome(lambda: loader(FrameRecord(rgb=img, depth=path)), [path], check)


@pytest.mark.parametrize("width, height", HUGE_SIZES)
@pytest.mark.parametrize("fmt", ["png16", "png8", "rgbpng", "jpeg"])
def test_huge_declared_size_is_refused(tmp_path, width, height, fmt):
    """Found by the fuzzer: a JPEG/PNG header declaring a huge size made Pillow raise DecompressionBombError (not
    a project error) or allocate the declared size before failing on the missing data. Refused up front now."""
    if fmt == "jpeg":
        raw = jpeg_with_size(jpeg_bytes(np.zeros((8, 8, 3), np.uint8), 0), min(width, 65535), min(height, 65535))
    else:
        bit_depth, colour = {"png16": (16, GRAY), "png8": (8, GRAY), "rgbpng": (8, RGB)}[fmt]
        raw = png_with_size(png_bytes(np.zeros((8, 8, CHANNELS[colour]), np.uint8), bit_depth, colour), width, height)
    path = write(tmp_path / "000004.PNG", raw)
    for read in (read_rgb, read_depth, lambda p: read_labels(p, "raw"), read_depth8, image_size):
        with pytest.raises(DatasetError) as e:
            read(path)
        assert str(path) in str(e.value)


def _huge_shape_npy() -> bytes:
    header = b"{'descr': '<f4', 'fortran_order': False, 'shape': (100000, 100000), }"
    header = header.ljust(118) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + b"\x00" * 64


@pytest.mark.parametrize(
    "raw, message",
    [
        (_npy_bytes(np.full((4, 6), np.nan, np.float32)), "NaN"),  # was read, giving NaN ground truth
        (_npy_bytes(np.full((4, 6), 1e300)), "infinite in float32"),  # finite float64, inf in float32
        (_npy_bytes(np.full((4, 6), -2.0, np.float32)), "negative"),
        (_npy_bytes(np.full((4, 6), "abc")), "real numbers"),  # was ValueError from astype
        (_npy_bytes(np.ones((4, 6), np.complex64)), "real numbers"),  # was silently dropping the imaginary part
        (_huge_shape_npy(), "header declares"),  # 10^10 values declared: was an allocation attempt
        (_npy_bytes(np.ones((4, 6), np.float32))[:60], "cannot read depth array"),  # was SyntaxError/EOFError
        (_npy_bytes(np.ones((4, 6), np.float32))[:-5], "truncated"),
    ],
)
def test_flight_depth_npy_regressions(tmp_path, raw, message):
    img = write(tmp_path / "img.png", png_bytes(np.zeros((4, 6, 3), np.uint8), 8, RGB))
    path = write(tmp_path / "img.npy", raw)
    with pytest.raises(DatasetError, match=message) as e:
        FlightFrameLoader((4, 6), (4, 6), 0.001, 7)(FrameRecord(rgb=img, depth=path))
    assert str(path) in str(e.value)
