"""Aeroscapes (design 10.9): 3,269 aerial images at 720x1280 with 12 classes; semantic segmentation only.

On disk: ``<root>/JPEGImages/<name>.jpg``, ``<root>/SegmentationClass/<name>.png`` (channel 0 = class ID 0..11)
and ``<root>/ImageSets/trn.txt`` / ``val.txt`` (one image name per line). Split names: ``"train"`` (or ``"trn"``)
reads ``trn.txt``; ``"val"`` reads ``val.txt``; ``"test"`` also reads ``val.txt`` (Aeroscapes has no test split;
published numbers are on ``val``).

Items have no ``depth``; the motion is the identity (``rot = (1, 0, 0, 0)``, ``trans = 0``) and every image is its
own reset (``reset`` all True). ``size`` is free (default: native 720x1280, as the original); colour is BL2-resized
and labels TF2-nearest (NN2). Intrinsics follow the 90-degree convention ``f = W/2, H/2``, ``c = W/2, H/2``
(Aeroscapes has no calibration; the semantic decoder does not use the camera).
With ``seq_len > 1`` an item groups consecutive names of the split file (remainder dropped).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..errors import DatasetError
from .augment import resolve_augment
from .decode import DEFAULT_JPEG_IDCT, check_jpeg_idct, image_size, read_label_ids, read_rgb
from .files import dataset_root, read_text
from .frames import Size, labels_to_tensor, midair_intrinsics, resolve_size, rgb_to_tensor
from .sequence import FrameRecord, SequenceDataset, Trajectory

CLASSES = (
    "background",
    "person",
    "bike",
    "car",
    "drone",
    "boat",
    "animal",
    "obstacle",
    "construction",
    "vegetation",
    "road",
    "sky",
)
PALETTE = np.array(
    [
        (0, 0, 0),
        (192, 128, 128),
        (0, 128, 0),
        (128, 128, 128),
        (128, 0, 0),
        (0, 0, 128),
        (192, 0, 128),
        (192, 0, 0),
        (192, 128, 0),
        (0, 64, 0),
        (128, 128, 0),
        (0, 128, 128),
    ],
    dtype=np.uint8,
)
NATIVE_SIZE = (720, 1280)
SPLIT_FILES = {"train": "trn.txt", "trn": "trn.txt", "val": "val.txt", "test": "val.txt"}


def read_split_file(path: Path) -> list[str]:
    """Image names of an ``ImageSets`` file (blank lines ignored; a trailing ``.jpg`` is tolerated)."""
    text = read_text(path, "Aeroscapes split file")
    names = []
    for line in text.splitlines():
        name = line.strip()
        if name:
            names.append(name[:-4] if name.lower().endswith(".jpg") else name)
    if not names:
        raise DatasetError(f"{path}: split file lists no images")
    return names


class AeroscapesFrameLoader:
    """Loads one Aeroscapes image and its labels at the output size. Picklable."""

    def __init__(self, size: Size | None, jpeg_idct: str = DEFAULT_JPEG_IDCT) -> None:
        self.size = size
        self.jpeg_idct = check_jpeg_idct(jpeg_idct)

    def __call__(self, rec: FrameRecord) -> dict[str, torch.Tensor]:
        out = {"rgb": rgb_to_tensor(read_rgb(rec.rgb, self.jpeg_idct), self.size)}
        if rec.semantic is not None:
            out["semantic"] = labels_to_tensor(read_label_ids(rec.semantic, len(CLASSES)), self.size, "nn2")
        return out


def open_aeroscapes(
    root: str | Path,
    split_dir: str | Path | None = None,
    split: str = "val",
    seq_len: int = 1,
    size: int | tuple[int, int] | None = None,
    augment=False,
    *,
    seed: int = 0,
    name: str = "aeroscapes",
    jpeg_idct: str = DEFAULT_JPEG_IDCT,
) -> SequenceDataset:
    """Open an Aeroscapes split. ``split_dir`` defaults to ``<root>/ImageSets``; ``jpeg_idct`` as
    :func:`cosemdepth.data.midair.dataset.open_midair`."""
    check_jpeg_idct(jpeg_idct)
    root = dataset_root(root)
    if split not in SPLIT_FILES:
        raise DatasetError(f"Aeroscapes has splits {sorted(SPLIT_FILES)}, got {split!r}")
    split_dir = Path(split_dir) if split_dir is not None else root / "ImageSets"
    names = read_split_file(split_dir / SPLIT_FILES[split])
    frames = [
        FrameRecord(
            rgb=root / "JPEGImages" / f"{n}.jpg",
            semantic=root / "SegmentationClass" / f"{n}.png",
            id=i,
        )
        for i, n in enumerate(names)
    ]
    trajectory = Trajectory.from_records(split, frames, reset=np.ones(len(frames), dtype=bool))

    def native():  # the first image's size and the focal length of the intrinsics convention there
        shape = image_size(frames[0].rgb)
        return shape, float(midair_intrinsics(shape)[0])

    out_size = resolve_size(size, native)
    return SequenceDataset(
        [trajectory],
        AeroscapesFrameLoader(out_size, jpeg_idct),
        midair_intrinsics(out_size or image_size(frames[0].rgb)),
        seq_len=seq_len,
        mode="stream",
        augment=resolve_augment(augment),
        seed=seed,
        name=name,
        size_at=lambda rule: resolve_size(rule, native) or native()[0],
    )
