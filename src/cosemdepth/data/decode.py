"""Reading image files (JPEG/PNG) into numpy arrays, with errors that name the file and the problem.

Every reader here only opens files for reading.

JPEG (any file whose content starts with the JPEG SOI marker, whatever its name) is decoded by libjpeg-turbo through
``simplejpeg``, in one function, :func:`decode_jpeg`, with the IDCT chosen by ``jpeg_idct``:

* ``"fast"`` (default): libjpeg-turbo's fast integer IDCT (IFAST) with fancy (smooth) chroma upsampling. This is what
  ``tf.io.decode_jpeg`` does with its defaults, hence what the original Co-SemDepth loader feeds its networks:
  ``simplejpeg.decode_jpeg(data, colorspace="RGB", fastdct=True, fastupsample=False)`` reproduces it bit for bit
  (4:4:4, 4:2:0 and gray; also ``djpeg -dct fast``, the fixture of ``tests/data/test_decode.py``). On SynthAir frames
  it differs from the accurate IDCT on about 60 % of the values, by up to 12 levels.
* ``"accurate"``: the accurate integer IDCT (ISLOW; ``djpeg -dct int``), what Pillow and most image tools give.

Reduced-size decoding (``min_size``, training's ``data.train_decode: reduced`` only): libjpeg-turbo can decode a JPEG
at a scale ``M/8`` of its size (``M = 1..8``) by running a smaller IDCT on each block's low frequencies, for a
fraction of the IDCT, upsampling and colour-conversion work. :func:`decode_jpeg` with ``min_size = (h, w)`` picks the
smallest such scale whose picture is at least ``h x w`` (full size when none is smaller), e.g. a 1024 px frame for a
384 px input at 3/8, exactly 384 px. The pixels are a low-pass picture of that size, not the full-size decode: the
original's pipeline (and every evaluation here) decodes at full size and resizes with BL2 afterwards, so the exact
path is the default everywhere, and :func:`cosemdepth.data.frames.rgb_to_tensor` resizes what remains to the output
size either way.

PNG (and other formats) decode with Pillow (libpng). PNG flavours accepted for single-channel maps (labels, 8-bit
depth): 8-bit gray (``L``), 16-bit gray (``I;16``), palette (``P``: the palette *indices* are the values), gray+alpha
(``LA``) and 8-bit RGB/RGBA (channel 0 is kept). 16-bit colour PNGs are rejected for maps: a class ID or depth in
channel 0 of a 16-bit colour PNG is not a layout any dataset uses.

Colour images keep their precision: :func:`read_rgb` and :func:`decode_rgb` return uint8 for 8-bit images and uint16
for 16-bit ones (16-bit gray, RGB or RGBA PNGs), and :func:`cosemdepth.data.frames.rgb_to_tensor` scales either to
the model's 0..1 input (``/255`` or ``/65535``). Pillow holds 16-bit colour only as 8 bits, so a 16-bit RGB(A) PNG
is decoded twice by libpng through Pillow, once unpacking the high byte of each sample and once the low byte
(:func:`_decode_png16_colour`). 16-bit gray+alpha PNGs (which Pillow cannot unpack that way) are refused with an
error naming the file.

Orientation: an EXIF orientation tag (JPEG APP1, PNG eXIf) is applied to every image and map read here (as
``PIL.ImageOps.exif_transpose`` does), so arrays, :func:`image_size` and the intrinsics derived from it describe the
picture as it is meant to be seen.
"""

from __future__ import annotations

import io
import os
import struct
import warnings
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from ..errors import ConfigError, DatasetError

#: PNG IHDR colour types.
_PNG_GRAY, _PNG_RGB, _PNG_PALETTE, _PNG_GRAY_ALPHA, _PNG_RGBA = 0, 2, 3, 4, 6
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_SOI = b"\xff\xd8"
_JPEG_SUFFIXES = (".jpg", ".jpeg", ".jpe", ".jfif")

#: The JPEG IDCT choices (``jpeg_idct`` option, ``--jpeg-idct`` flag); the first is the default (the original's).
JPEG_IDCTS = ("fast", "accurate")
DEFAULT_JPEG_IDCT = "fast"
#: EXIF tag 0x0112 (Orientation).
_EXIF_ORIENTATION = 0x0112
#: JPEG APP1 payload start of an EXIF segment.
_EXIF_HEADER = b"Exif\0\0"
#: Largest image the readers decode, in pixels (8192 x 8192). A header declaring more is refused before anything
#: is allocated: it is corrupt, or an image far larger than any aerial dataset's (decoding it would take GBs).
MAX_PIXELS = 1 << 26


def check_jpeg_idct(jpeg_idct: str) -> str:
    """Return ``jpeg_idct`` if it is one of :data:`JPEG_IDCTS`, else raise a ConfigError."""
    if jpeg_idct not in JPEG_IDCTS:
        raise ConfigError(f"jpeg_idct must be one of {', '.join(map(repr, JPEG_IDCTS))}, got {jpeg_idct!r}")
    return jpeg_idct


def check_nonnegative(path: str | os.PathLike, values: np.ndarray, what: str, note: str = "", hint: str = "") -> None:
    """Raise a DatasetError naming ``path`` and the first bad pixel if any of the ``[H, W]`` ``values`` (``what``:
    "depth", "disparity") is negative, NaN or infinite; ``note`` follows the problem, ``hint`` ends the message."""
    bad = ~np.isfinite(values) | (values < 0)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise DatasetError(
            f"{path}: {int(bad.sum())} {what} value(s) are negative, NaN or infinite{note} (first at "
            f"row {i}, column {j}: {values[i, j]}){hint}"
        )


def check_image_size(path: str | os.PathLike, width: int, height: int) -> None:
    """Raise a DatasetError naming ``path`` unless ``width x height`` (from a header) is a decodable image size."""
    if width < 1 or height < 1 or width * height > MAX_PIXELS:
        raise DatasetError(
            f"{path}: header declares a {width}x{height} image; readable sizes are 1 to {MAX_PIXELS} pixels "
            "(corrupt header?)"
        )


def orient(arr: np.ndarray, orientation: int) -> np.ndarray:
    """``[H, W, ...]`` as stored -> as displayed for the EXIF ``orientation`` 1..8 (``[W, H, ...]`` for 5..8): the
    transposition of ``PIL.ImageOps.exif_transpose`` (1 or an unknown value: unchanged)."""
    if orientation == 2:
        arr = arr[:, ::-1]
    elif orientation == 3:
        arr = arr[::-1, ::-1]
    elif orientation == 4:
        arr = arr[::-1]
    elif orientation == 5:
        arr = arr.swapaxes(0, 1)
    elif orientation == 6:
        arr = np.rot90(arr, -1)
    elif orientation == 7:
        arr = arr[::-1, ::-1].swapaxes(0, 1)
    elif orientation == 8:
        arr = np.rot90(arr, 1)
    return np.ascontiguousarray(arr)


def _orientation(img: Image.Image) -> int:
    """The EXIF orientation of an opened Pillow image (1 when it has none or it cannot be read)."""
    try:
        value = img.getexif().get(_EXIF_ORIENTATION, 1)
    except Exception:  # a damaged EXIF block does not make the pixels unreadable: they are used as stored
        return 1
    return int(value) if isinstance(value, int) else 1


def _jpeg_orientation(data: bytes) -> int:
    """The EXIF orientation of JPEG bytes (1 when none): read by Pillow from the header, only when an EXIF
    segment is present."""
    if _EXIF_HEADER not in data[: 1 << 17]:  # APP segments precede the image data; 128 KiB covers any EXIF block
        return 1
    try:
        with Image.open(io.BytesIO(data)) as img:
            return _orientation(img)
    except Exception:  # the decoder reports a damaged file; the tag is optional
        return 1


def _swapped(orientation: int, width: int, height: int) -> tuple[int, int]:
    """``(width, height)`` as displayed for the EXIF ``orientation``."""
    return (height, width) if orientation in (5, 6, 7, 8) else (width, height)


def decode_jpeg(
    data: bytes, path: str | os.PathLike, jpeg_idct: str = DEFAULT_JPEG_IDCT, min_size: tuple[int, int] | None = None
) -> np.ndarray:
    """JPEG bytes -> ``[H, W, 3]`` uint8 RGB (gray replicated), decoded by libjpeg-turbo with the IDCT ``jpeg_idct``
    (see the module docstring). ``min_size = (h, w)`` (as displayed): decode at the smallest DCT scale ``M/8`` whose
    picture is at least that size (reduced-size decoding, see the module docstring; ``None``: full size). Any
    decoding problem is a DatasetError naming ``path``."""
    import simplejpeg  # deferred: a compiled extension only the JPEG readers need

    check_jpeg_idct(jpeg_idct)
    if not data.startswith(_JPEG_SOI):
        raise DatasetError(f"{path}: not a JPEG file (no JPEG start-of-image marker; corrupt or another format?)")
    try:
        h, w, colorspace, _ = simplejpeg.decode_jpeg_header(data)
    except Exception as e:  # the C library's errors (ValueError mostly): the file cannot be decoded
        raise DatasetError(f"{path}: corrupt JPEG ({_jpeg_message(e)})") from None
    check_image_size(path, w, h)
    if colorspace not in ("Gray", "YCbCr", "RGB"):
        raise DatasetError(f"{path}: unsupported JPEG colour space {colorspace} (expected RGB/YCbCr or gray)")
    orientation = _jpeg_orientation(data)
    scale = {}
    if min_size is not None:  # (the scale is chosen on the stored picture: the displayed one may be transposed)
        mw, mh = _swapped(orientation, int(min_size[1]), int(min_size[0]))
        scale = {"min_height": max(mh, 1), "min_width": max(mw, 1)}
    try:
        arr = simplejpeg.decode_jpeg(
            data, colorspace="RGB", fastdct=jpeg_idct == "fast", fastupsample=False, strict=True, **scale
        )
    except MemoryError:
        raise DatasetError(f"{path}: JPEG too large to decode in memory") from None
    except Exception as e:
        raise DatasetError(f"{path}: corrupt JPEG ({_jpeg_message(e)})") from None
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        raise DatasetError(f"{path}: JPEG decoded to an unexpected array {arr.dtype} {list(arr.shape)}")
    return orient(arr, orientation)


def _jpeg_message(e: Exception) -> str:
    msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return msg[:200]


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise DatasetError(f"{path}: is a folder, expected an image file") from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot read ({e.strerror or e})") from None


def _open_header(path, where=None):
    """Open an image with Pillow (header only; ``path``: a file or a binary stream whose errors name ``where``),
    checking its declared size before anything is decoded."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # MAX_PIXELS is checked below
        img = Image.open(path)
    check_image_size(path if where is None else where, *img.size)
    return img


def _open(path, where=None):
    """Open and fully decode an image with Pillow (``path``: a file, or a binary stream whose errors name
    ``where``); any failure becomes a DatasetError naming it."""
    where = path if where is None else where
    try:
        img = _open_header(path, where)
        img.load()
    except FileNotFoundError:
        raise DatasetError(f"{where}: file not found") from None
    except IsADirectoryError:
        raise DatasetError(f"{where}: is a folder, expected an image file") from None
    except UnidentifiedImageError:
        raise DatasetError(f"{where}: not a readable image (corrupt or unknown format)") from None
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        raise DatasetError(f"{where}: corrupt image ({e})") from None
    return img


def png_header(path: str | os.PathLike) -> tuple[int, int, int, int]:
    """``(width, height, bit_depth, colour_type)`` from a PNG's IHDR chunk (no decoding)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(33)
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot read ({e.strerror})") from None
    if len(head) < 33 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise DatasetError(f"{path}: not a PNG file (bad signature or header; corrupt or truncated?)")
    width, height, bit_depth, colour_type = struct.unpack(">IIBB", head[16:26])
    return width, height, bit_depth, colour_type


def read_rgb(
    path: str | os.PathLike, jpeg_idct: str = DEFAULT_JPEG_IDCT, min_size: tuple[int, int] | None = None
) -> np.ndarray:
    """Colour image -> ``[H, W, 3]`` uint8, or uint16 for a 16-bit PNG (full precision), as displayed (EXIF
    orientation applied). JPEG content goes through :func:`decode_jpeg` with ``jpeg_idct`` (``"fast"``, the
    original's, by default; ``"accurate"``) and ``min_size`` (reduced-size decoding; other formats ignore it);
    other formats (PNG...) through Pillow. A file named ``.jpg``/``.jpeg`` must hold a JPEG. Gray images are
    replicated, alpha is dropped."""
    path = Path(path)
    check_jpeg_idct(jpeg_idct)
    data = _read_bytes(path)
    if path.suffix.lower() in _JPEG_SUFFIXES or data.startswith(_JPEG_SOI):
        return decode_jpeg(data, path, jpeg_idct, min_size)
    return decode_rgb(data, path, jpeg_idct)


def decode_rgb(data: bytes, where: str | os.PathLike, jpeg_idct: str = DEFAULT_JPEG_IDCT) -> np.ndarray:
    """Encoded colour image bytes (JPEG through :func:`decode_jpeg`, PNG and other formats through Pillow) ->
    ``[H, W, 3]`` uint8 or uint16 (16-bit PNGs), as :func:`read_rgb` (which reads files; this also serves images
    inside other containers, e.g. a ROS ``CompressedImage``). Errors are DatasetErrors prefixed with ``where``."""
    check_jpeg_idct(jpeg_idct)
    if data.startswith(_JPEG_SOI):
        return decode_jpeg(data, where, jpeg_idct)
    bit_depth, colour_type = _png_format(data)
    if bit_depth == 16 and colour_type in (_PNG_RGB, _PNG_RGBA):
        return _decode_png16_colour(data, where)
    if bit_depth == 16 and colour_type == _PNG_GRAY_ALPHA:
        raise DatasetError(
            f"{where}: 16-bit gray+alpha PNGs are not supported; write 16-bit gray, RGB or RGBA (or 8-bit)"
        )
    img = _open(io.BytesIO(data), where)
    if img.mode == "RGB":
        arr = np.array(img)
    elif img.mode in ("L", "P", "RGBA", "LA", "CMYK", "YCbCr"):
        arr = np.array(img.convert("RGB"))
    elif img.mode in ("I;16", "I;16B", "I;16L"):  # 16-bit gray: every bit kept
        arr = np.repeat(np.asarray(img, dtype=np.uint16)[..., None], 3, axis=2)
    else:
        raise DatasetError(f"{where}: unsupported colour image mode {img.mode!r} (expected 8- or 16-bit RGB or gray)")
    return orient(arr, _orientation(img))


def _png_format(data: bytes) -> tuple[int, int]:
    """``(bit_depth, colour_type)`` of PNG bytes, ``(0, -1)`` for anything else."""
    if len(data) < 26 or not data.startswith(_PNG_SIGNATURE) or data[12:16] != b"IHDR":
        return 0, -1
    return data[24], data[25]


def _decode_png16_colour(data: bytes, where) -> np.ndarray:
    """16-bit RGB or RGBA PNG bytes -> ``[H, W, 3]`` uint16, every bit kept (alpha dropped, orientation applied).

    Pillow unpacks 16-bit colour PNGs to 8 bits (the high byte of each sample). Its unpackers for little-endian
    16-bit samples (``RGB;16L``), applied to the PNG's big-endian samples, give the low bytes instead: the image is
    decoded once with each and the bytes are joined. The unfiltering, de-interlacing and CRC checks stay libpng's
    (through Pillow's ``zip`` decoder)."""
    halves = []
    for rawmode in ("16B", "16L"):
        try:
            img = _open_header(io.BytesIO(data), where)
            tile = img.tile
            if len(tile) != 1 or tile[0][0] != "zip" or img.mode not in ("RGB", "RGBA"):
                raise DatasetError(f"{where}: unexpected 16-bit colour PNG layout {img.mode} {tile!r}")
            name, extents, offset, args = tile[0]
            mode = img.mode
            args = (f"{mode};{rawmode}", *args[1:]) if isinstance(args, tuple) else f"{mode};{rawmode}"
            # Pillow >= 11 holds tiles as named tuples, older versions as plain ones
            img.tile = [tile[0]._replace(args=args) if hasattr(tile[0], "_replace") else (name, extents, offset, args)]
            img.load()
        except DatasetError:
            raise
        except UnidentifiedImageError:
            raise DatasetError(f"{where}: not a readable image (corrupt or unknown format)") from None
        except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
            raise DatasetError(f"{where}: corrupt image ({e})") from None
        halves.append(np.asarray(img)[..., :3])
        orientation = _orientation(img)
    hi, lo = halves
    return orient((hi.astype(np.uint16) << 8) | lo, orientation)


def read_channel0(path: str | os.PathLike) -> np.ndarray:
    """Single-channel map (class IDs, 8-bit depth) -> ``[H, W]`` integer array (uint8, uint16 or int32).

    Keeps channel 0 of colour PNGs and the raw indices of palette PNGs (see the module docstring).
    """
    path = Path(path)
    if path.suffix.lower() == ".png":
        _, _, bit_depth, colour_type = png_header(path)
        if bit_depth == 16 and colour_type in (_PNG_RGB, _PNG_RGBA, _PNG_GRAY_ALPHA):
            raise DatasetError(
                f"{path}: 16-bit colour PNGs are not supported for label/depth maps; write 8- or 16-bit gray "
                "(or 8-bit RGB with the value in channel 0)"
            )
    img = _open(path)
    arr = np.array(img)
    if arr.ndim == 3:
        arr = arr[..., 0]
    arr = orient(arr, _orientation(img))
    if arr.ndim != 2:
        raise DatasetError(f"{path}: expected a 2-D map, got an array of shape {list(arr.shape)}")
    if arr.dtype == np.bool_:
        arr = arr.astype(np.uint8)
    if arr.dtype.kind not in "ui":
        raise DatasetError(f"{path}: expected integer pixel values, got {arr.dtype}")
    return np.ascontiguousarray(arr)


def read_uint16_png(path: str | os.PathLike) -> np.ndarray:
    """16-bit single-channel PNG -> ``[H, W]`` uint16 (the stored values, bit-exact)."""
    path = Path(path)
    _, _, bit_depth, colour_type = png_header(path)
    if bit_depth != 16 or colour_type != _PNG_GRAY:
        raise DatasetError(
            f"{path}: expected a 16-bit single-channel PNG, got bit depth {bit_depth}, colour type {colour_type}"
        )
    img = _open(path)
    arr = np.array(img)
    if arr.dtype != np.uint16:
        if arr.dtype.kind not in "ui" or arr.min(initial=0) < 0 or arr.max(initial=0) > 0xFFFF:
            raise DatasetError(f"{path}: unexpected decoded values ({arr.dtype}) for a 16-bit PNG")
        arr = arr.astype(np.uint16)
    return orient(arr, _orientation(img))


def check_labels(labels: np.ndarray, num_ids: int, path: str | os.PathLike) -> None:
    """Raise a DatasetError naming ``path`` if a label lies outside ``0..num_ids-1``."""
    if labels.size == 0:
        raise DatasetError(f"{path}: empty label map")
    lo, hi = int(labels.min()), int(labels.max())
    if lo < 0 or hi >= num_ids:
        bad = hi if hi >= num_ids else lo
        count = int(np.count_nonzero((labels < 0) | (labels >= num_ids)))
        raise DatasetError(f"{path}: label ID {bad} out of range 0..{num_ids - 1} ({count} pixel(s) out of range)")


def read_label_ids(path: str | os.PathLike, num_ids: int) -> np.ndarray:
    """Label PNG -> ``[H, W]`` class IDs (channel 0, see :func:`read_channel0`) at the native size, checked to lie
    in ``0..num_ids-1`` (:func:`check_labels`)."""
    ids = read_channel0(path)
    check_labels(ids, num_ids, path)
    return ids


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """``(H, W)`` of an image file as displayed (EXIF orientation applied: what :func:`read_rgb` returns), from its
    header (no full decoding)."""
    path = Path(path)
    try:
        with _open_header(path) as img:
            w, h = _swapped(_orientation(img), *img.size)
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        raise DatasetError(f"{path}: not a readable image ({e})") from None
    return h, w
