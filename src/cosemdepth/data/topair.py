"""TopAir (design 10.8): an AirSim aerial dataset with 8-bit depth and 9 classes, read through split CSVs.

On disk: ``<root>/<env>/images/NNNNNN.png`` (RGB), ``<root>/<env>/depth/NNNNNN.png`` (8-bit,
``depth = value * 100 / 255`` m), ``<root>/<env>/seg_id/NNNNNN.png`` (channel 0 = class ID 0..8).
Split CSVs as Mid-Air's (tab separated, ``id camera_l depth semantic qw qx qy qz tx ty tz``), under
``<split_dir>/<split>_data/`` (train: 13 environments, test: OakForest_3 and RuralAust3_1).

Decoding: colour ``/255`` then BL2; depth and labels with TF2 nearest (NN2, the original loader's
``tf.image.resize(..., "nearest")``); intrinsics ``f = W/2, H/2``, ``c = W/2, H/2`` as for Mid-Air.

The authors' CSVs start with a row of ``id = -1`` (the true first frame, with a dummy motion) and their loader
resets on ``id == 0``, i.e. on the *second* frame (design 10.8). Here the first row of each CSV is the reset and
``id == 0`` is not.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import numpy as np
import torch

from ..errors import DatasetError
from ..models.config import MIDAIR_IMAGE_SIZE
from .csvsplits import open_csv_split
from .decode import DEFAULT_JPEG_IDCT, check_jpeg_idct, read_channel0, read_label_ids, read_rgb
from .frames import Size, depth_to_tensor, labels_to_tensor, rgb_to_tensor
from .sequence import FrameRecord, SequenceDataset

CLASSES = ("sky", "water", "trees", "land", "vehicle", "boulders", "road", "man_made_construction", "others")

#: RGB visualisation palette of the 9 classes (the authors' TopAir loader).
PALETTE = np.array(
    [
        (127, 175, 230),
        (75, 163, 185),
        (50, 128, 0),
        (53, 94, 59),
        (237, 125, 49),
        (70, 70, 70),
        (128, 64, 128),
        (64, 64, 128),
        (128, 64, 64),
    ],
    dtype=np.uint8,
)

#: Metres per unit of the 8-bit depth PNGs.
DEPTH_SCALE = 100.0 / 255.0

#: Environments in the order of the authors' split generator, their frame skips, and the test environments.
ENVIRONMENTS = (
    "Africa_1",
    "Africa_2",
    "Africa_3",
    "CityPark_1",
    "CityPark_2",
    "CityPark_3",
    "CityPark_4",
    "CityPark_6",
    "CityPark_8",
    "OakForest_1",
    "OakForest_2",
    "OakForest_3",
    "RuralAust1_2",
    "RuralAust3_1",
    "RuralAust3_2",
)
FRAME_SKIPS = (1, 2, 3, 1, 2, 3, 1, 3, 2, 1, 2, 3, 3, 2, 1)
TEST_ENVIRONMENTS = ("OakForest_3", "RuralAust3_1")


def read_depth8(path: str | Path) -> np.ndarray:
    """TopAir 8-bit depth PNG -> ``[H, W]`` float32 metres (``value * 100 / 255``)."""
    raw = read_channel0(path)
    if raw.dtype != np.uint8:
        raise DatasetError(f"{path}: TopAir depth must be an 8-bit PNG, got {raw.dtype}")
    return raw.astype(np.float32) * np.float32(DEPTH_SCALE)


class TopAirFrameLoader:
    """Loads one TopAir row at the output size. Picklable."""

    def __init__(self, size: Size | None, jpeg_idct: str = DEFAULT_JPEG_IDCT) -> None:
        self.size = size
        self.jpeg_idct = check_jpeg_idct(jpeg_idct)

    def __call__(self, rec: FrameRecord) -> dict[str, torch.Tensor]:
        out = {"rgb": rgb_to_tensor(read_rgb(rec.rgb, self.jpeg_idct), self.size)}
        if rec.depth is not None:
            out["depth"] = depth_to_tensor(read_depth8(rec.depth), self.size, rule="nn2")
        if rec.semantic is not None:
            out["semantic"] = labels_to_tensor(read_label_ids(rec.semantic, len(CLASSES)), self.size, "nn2")
        return out


def open_topair(
    root: str | Path,
    split_dir: str | Path | None = None,
    split: str = "test",
    seq_len: int = 1,
    size: int | tuple[int, int] | None = MIDAIR_IMAGE_SIZE,
    augment=False,
    *,
    mode: str | None = None,
    db_seq_len: int | None = None,
    modalities: Iterable[str] | None = None,
    seed: int = 0,
    name: str = "topair",
    jpeg_idct: str = DEFAULT_JPEG_IDCT,
) -> SequenceDataset:
    """Open a TopAir split. ``split_dir`` defaults to ``<root>/splits``; other arguments as
    :func:`cosemdepth.data.midair.dataset.open_midair` (no ``labels``: TopAir has its own 9 classes)."""
    check_jpeg_idct(jpeg_idct)
    return open_csv_split(
        root,
        split_dir if split_dir is not None else Path(root) / "splits",
        split,
        seq_len,
        size,
        augment,
        columns={"rgb": "camera_l", "depth": "depth", "semantic": "semantic"},
        reset_rule=lambda ids: np.zeros(len(ids), dtype=bool),  # only the first row (id -1 in the authors' CSVs)
        make_loader=lambda out_size: TopAirFrameLoader(out_size, jpeg_idct),
        mode=mode,
        db_seq_len=db_seq_len,
        modalities=modalities,
        seed=seed,
        name=name,
    )
