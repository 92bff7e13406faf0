"""Reading image files (JPEG/PNG) into numpy arrays, with errors that name the file and the problem.

Every reader here only opens files for reading. Decoding uses Pillow (libjpeg / libpng defaults), so a JPEG decodes
to the same uint8 values as TensorFlow's ``decode_jpeg`` up to the +-1 LSB differences of IDCT implementations.

PNG flavours accepted for single-channel maps (labels, 8-bit depth): 8-bit gray (``L``), 16-bit gray (``I;16``),
palette (``P``: the palette *indices* are the values), gray+alpha (``LA``) and 8-bit RGB/RGBA (channel 0 is kept).
16-bit colour PNGs are rejected: Pillow would silently keep only their high bytes.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from ..errors import DatasetError

#: PNG IHDR colour types.
_PNG_GRAY, _PNG_RGB, _PNG_PALETTE, _PNG_GRAY_ALPHA, _PNG_RGBA = 0, 2, 3, 4, 6
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


#: Largest image the readers decode, in pixels (8192 x 8192). A header declaring more is refused before anything
#: is allocated: it is corrupt, or an image far larger than any aerial dataset's (decoding it would take GBs).
MAX_PIXELS = 1 << 26


def check_image_size(path: str | os.PathLike, width: int, height: int) -> None:
    """Raise a DatasetError naming ``path`` unless ``width x height`` (from a header) is a decodable image size."""
    if width < 1 or height < 1 or width * height > MAX_PIXELS:
        raise DatasetError(
            f"{path}: header declares a {width}x{height} image; readable sizes are 1 to {MAX_PIXELS} pixels "
            "(corrupt header?)"
        )


def _open_header(path: Path):
    """Open an image with Pillow (header only), checking its declared size; failures are DatasetErrors."""
    import warnings

    from PIL import Image

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # MAX_PIXELS is checked below
        img = Image.open(path)
    check_image_size(path, *img.size)
    return img


def _open(path: Path):
    """Open and fully decode an image with Pillow; any failure becomes a DatasetError naming ``path``."""
    from PIL import Image, UnidentifiedImageError

    try:
        img = _open_header(path)
        img.load()
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise DatasetError(f"{path}: is a folder, expected an image file") from None
    except UnidentifiedImageError:
        raise DatasetError(f"{path}: not a readable image (corrupt or unknown format)") from None
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        raise DatasetError(f"{path}: corrupt image ({e})") from None
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


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """Colour image (JPEG or PNG) -> ``[H, W, 3]`` uint8. Gray images are replicated, alpha is dropped."""
    path = Path(path)
    img = _open(path)
    if img.mode == "RGB":
        arr = np.array(img)
    elif img.mode in ("L", "P", "RGBA", "LA", "CMYK", "YCbCr"):
        arr = np.array(img.convert("RGB"))
    else:
        raise DatasetError(f"{path}: unsupported colour image mode {img.mode!r} (expected 8-bit RGB or gray)")
    return np.ascontiguousarray(arr)


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
    return np.ascontiguousarray(arr)


def check_labels(labels: np.ndarray, num_ids: int, path: str | os.PathLike) -> None:
    """Raise a DatasetError naming ``path`` if a label lies outside ``0..num_ids-1``."""
    if labels.size == 0:
        raise DatasetError(f"{path}: empty label map")
    lo, hi = int(labels.min()), int(labels.max())
    if lo < 0 or hi >= num_ids:
        bad = hi if hi >= num_ids else lo
        count = int(np.count_nonzero((labels < 0) | (labels >= num_ids)))
        raise DatasetError(
            f"{path}: label ID {bad} out of range 0..{num_ids - 1} ({count} pixel(s) out of range)"
        )


def read_label_ids(path: str | os.PathLike, num_ids: int) -> np.ndarray:
    """Label PNG -> ``[H, W]`` class IDs (channel 0, see :func:`read_channel0`) at the native size, checked to lie
    in ``0..num_ids-1`` (:func:`check_labels`)."""
    ids = read_channel0(path)
    check_labels(ids, num_ids, path)
    return ids


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """``(H, W)`` of an image file, from its header (no full decoding)."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    try:
        with _open_header(path) as img:
            w, h = img.size
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        raise DatasetError(f"{path}: not a readable image ({e})") from None
    return h, w
