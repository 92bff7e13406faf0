"""Mid-Air on-disk encodings (design sections 10.1-10.5), shared by the reader and by the SynthAir writer.

Depth is stored as stereo disparity in a 16-bit PNG whose uint16 values are the *bit patterns* of float16
disparities, ``z_depth = 512 / disparity`` (Mid-Air's native focal of 512 px, 1 m baseline) **whatever the PNG's
size**: like every Mid-Air tool (the authors' loader included, design 10.2) we never rescale the stored values when an
image is resized, so a PNG downsized by a user keeps its meaning, and SynthAir writes ``512 / z_depth`` at every size.
"""

from __future__ import annotations

import numpy as np

#: Mid-Air's native image size and focal length (pixels), 90 degree horizontal FOV.
NATIVE_SIZE = 1024
NATIVE_FOCAL = 512.0

ENVIRONMENTS = {
    "Kite_training": ("sunny", "sunset", "foggy", "cloudy"),
    "PLE_training": ("fall", "spring", "winter"),
}

#: The 14 Mid-Air label IDs, in ID order.
MIDAIR_CLASSES = (
    "sky",
    "animals",
    "trees",
    "dirt_ground",
    "ground_vegetation",
    "rocky_ground",
    "boulders",
    "empty",
    "water",
    "man_made_construction",
    "road",
    "train_track",
    "road_sign",
    "others",
)

#: Mid-Air ID -> Co-SemDepth class (design 10.5).
MIDAIR_TO_7 = np.array([0, 6, 2, 3, 3, 3, 4, 6, 1, 6, 5, 6, 6, 6], dtype=np.uint8)

CLASSES_7 = ("sky", "water", "trees", "land", "boulders", "road", "others")

#: RGB visualisation palette of the 7 classes (design 10.5).
PALETTE_7 = np.array(
    [
        (127, 175, 230),
        (75, 163, 185),
        (50, 128, 0),
        (53, 94, 59),
        (70, 70, 70),
        (128, 64, 128),
        (128, 64, 64),
    ],
    dtype=np.uint8,
)

#: Split CSV columns, tab separated, floats printed with 6 decimals (design 10.3).
CSV_COLUMNS = ("id", "camera_l", "disp", "semantic", "qw", "qx", "qy", "qz", "tx", "ty", "tz")

#: Folders of one climate, and file extensions.
COLOR_DIR, DISPARITY_DIR, SEGMENTATION_DIR = "color_left", "stereo_disparity", "segmentation"
COLOR_EXT, DISPARITY_EXT, SEGMENTATION_EXT = ".JPEG", ".PNG", ".PNG"
SENSOR_RECORDS = "sensor_records.hdf5"

#: Sampling rates (Hz): camera 25, ground truth 100; the split CSVs keep every 4th frame.
CAMERA_RATE, GROUNDTRUTH_RATE, FRAME_SKIP = 25, 100, 4


def frame_name(index: int, ext: str) -> str:
    return f"{index:06d}{ext}"


def trajectory_dir(number: int) -> str:
    return f"trajectory_{number:04d}"


def encode_disparity(disparity: np.ndarray) -> np.ndarray:
    """float disparity -> uint16 array holding its float16 bit patterns (what the 16-bit PNG stores)."""
    return np.ascontiguousarray(np.asarray(disparity, dtype=np.float16)).view(np.uint16)


def decode_disparity(raw: np.ndarray) -> np.ndarray:
    """uint16 PNG values -> float32 disparity (bit-cast to float16)."""
    raw = np.asarray(raw)
    if raw.dtype != np.uint16:
        raise ValueError(f"a Mid-Air disparity map must be uint16, got {raw.dtype}")
    return np.ascontiguousarray(raw).view(np.float16).astype(np.float32)


def focal_at_width(width: int) -> float:
    """Focal length in pixels of the Mid-Air camera at image width ``width`` (512 at 1024)."""
    return NATIVE_FOCAL * width / NATIVE_SIZE


#: ``z_depth = DISPARITY_SCALE / disparity`` for a stored disparity value at any PNG size (Mid-Air's convention).
DISPARITY_SCALE = NATIVE_FOCAL


def disparity_to_depth(disparity: np.ndarray) -> np.ndarray:
    """Stored disparity value -> z-depth in metres: ``512 / disparity``, whatever the image size."""
    return np.float32(DISPARITY_SCALE) / np.asarray(disparity, dtype=np.float32)


def depth_to_disparity(depth: np.ndarray) -> np.ndarray:
    """z-depth in metres -> the disparity value to store: ``512 / z_depth``, whatever the image size."""
    return np.float32(DISPARITY_SCALE) / np.asarray(depth, dtype=np.float32)


def map_labels(midair_ids: np.ndarray) -> np.ndarray:
    """Map Mid-Air IDs (0..13) to the 7 Co-SemDepth classes. Raises ValueError on an out-of-range ID."""
    ids = np.asarray(midair_ids)
    if ids.size and (ids.min() < 0 or ids.max() >= len(MIDAIR_TO_7)):
        raise ValueError(f"label IDs must lie in 0..{len(MIDAIR_TO_7) - 1}, found {int(ids.min())}..{int(ids.max())}")
    return MIDAIR_TO_7[ids]


def colorize(labels: np.ndarray, palette: np.ndarray = PALETTE_7) -> np.ndarray:
    """[H,W] class indices -> [H,W,3] uint8 RGB with ``palette``."""
    return palette[np.asarray(labels)]
