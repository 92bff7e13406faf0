"""The Mid-Air sequence dataset (design 10), also used for SynthAir (same on-disk format, any env/climate names).

Decoding of one row (design 10.2, 10.6):

* colour: ``camera_l`` JPEG -> uint8 (libjpeg-turbo, fast integer IDCT like the original by default; ``jpeg_idct``)
  -> ``/255`` -> BL2 resize to the output size. With ``reduced_decode`` (training only, ``data.train_decode:
  reduced``) the JPEG is decoded at the smallest DCT scale ``M/8`` at least the output size
  (:mod:`cosemdepth.data.decode`) and BL2 resizes the rest;
* depth: ``disp`` 16-bit PNG whose values are float16 bit patterns -> disparity -> z-depth ``512 / disparity``
  whatever the PNG's size (Mid-Air's convention, design 10.2: resizing a PNG never rescales its values) at the native
  size -> BL2 resize (in the depth domain). A zero disparity (infinitely far) is read as the smallest positive float16
  disparity (2^-24), i.e. a depth of ``512 * 2^24`` m, so that the bilinear resize stays finite (design 10.2); a negative, NaN or infinite
  disparity is a :class:`DatasetError`;
* labels: ``semantic`` PNG, channel 0 (8-bit gray, 16-bit gray, palette indices or RGB) -> OpenCV nearest (NN1)
  to the output size -> the 14 Mid-Air IDs mapped to the 7 classes on the fly (``labels="midair"``; the dataset is
  never rewritten), or already-mapped 7-class files (``labels="mapped"``), or the raw 14 IDs (``labels="raw"``).
  An ID out of range is a :class:`DatasetError` naming the file;
* motion: ``(qw, qx, qy, qz)``, ``(tx, ty, tz)`` from the CSV; intrinsics ``fx = W/2, fy = H/2, cx = W/2,
  cy = H/2`` at the output size (design 2.1).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

import numpy as np
import torch

from ...errors import ConfigError, DatasetError
from ...models.config import MIDAIR_IMAGE_SIZE
from ..csvsplits import open_csv_split
from ..decode import DEFAULT_JPEG_IDCT, check_jpeg_idct, check_nonnegative, read_label_ids, read_rgb, read_uint16_png
from ..frames import Size, depth_to_tensor, labels_to_tensor, rgb_to_tensor
from ..sequence import FrameRecord, SequenceDataset
from . import format as fmt

#: Smallest positive float16 (subnormal): zero disparities are read as this value.
MIN_DISPARITY = float(np.finfo(np.float16).smallest_subnormal)

LABEL_MODES = {"midair": len(fmt.MIDAIR_CLASSES), "raw": len(fmt.MIDAIR_CLASSES), "mapped": len(fmt.CLASSES_7)}


def read_disparity(path: str | Path) -> np.ndarray:
    """Mid-Air disparity PNG -> ``[H, W]`` float32 disparity, bit-exact (uint16 values bit-cast to float16)."""
    return fmt.decode_disparity(read_uint16_png(path))


def read_depth(path: str | Path) -> np.ndarray:
    """Mid-Air disparity PNG -> ``[H, W]`` float32 z-depth in metres at the file's native size."""
    return _depth_tensor(path).numpy()


def _depth_tensor(path: str | Path) -> torch.Tensor:
    """:func:`read_depth` as a tensor. The float16 -> float32 conversion, the clamp and the division run as torch
    ops (vectorised; numpy converts float16 element by element): exact conversions and IEEE divisions, the same
    values as ``512 / max(disparity, MIN_DISPARITY)`` in numpy."""
    path = Path(path)
    raw = np.ascontiguousarray(read_uint16_png(path))
    disp = torch.from_numpy(raw.view(np.int16)).view(torch.float16).float()
    check_nonnegative(path, disp.numpy(), "disparity")
    # a true division (a Python number over a tensor would be a reciprocal and a product)
    return torch.div(torch.tensor(fmt.DISPARITY_SCALE, dtype=torch.float32), disp.clamp_min_(MIN_DISPARITY))


def read_labels(path: str | Path, labels: str = "midair") -> np.ndarray:
    """Segmentation PNG -> ``[H, W]`` class IDs at native size, validated for ``labels`` (not yet mapped)."""
    return read_label_ids(path, LABEL_MODES[labels])


_MAP_14_TO_7 = torch.from_numpy(fmt.MIDAIR_TO_7.astype(np.int64))


class MidAirFrameLoader:
    """Loads one row at the output size (see the module docstring). Picklable, for DataLoader workers."""

    def __init__(
        self, size: Size, labels: str = "midair", jpeg_idct: str = DEFAULT_JPEG_IDCT, reduced_decode: bool = False
    ) -> None:
        if labels not in LABEL_MODES:
            raise ConfigError(f"labels must be one of {sorted(LABEL_MODES)}, got {labels!r}")
        if not isinstance(reduced_decode, bool):
            raise ConfigError(f"reduced_decode must be true or false, got {reduced_decode!r}")
        self.size = size
        self.labels = labels
        self.jpeg_idct = check_jpeg_idct(jpeg_idct)
        self.reduced_decode = reduced_decode

    def __call__(self, rec: FrameRecord) -> dict[str, torch.Tensor]:
        min_size = self.size if self.reduced_decode else None
        out = {"rgb": rgb_to_tensor(read_rgb(rec.rgb, self.jpeg_idct, min_size), self.size)}
        if rec.depth is not None:
            out["depth"] = depth_to_tensor(_depth_tensor(rec.depth), self.size)
        if rec.semantic is not None:
            sem = labels_to_tensor(read_labels(rec.semantic, self.labels), self.size, "nn1")
            if self.labels == "midair":
                sem = _MAP_14_TO_7[sem]
            out["semantic"] = sem
        return out


def _derive_semantic(rgb_rel: str) -> str:
    """``.../color_left/trajectory_XXXX/NNNNNN.JPEG`` -> ``.../segmentation/trajectory_XXXX/NNNNNN.PNG``."""
    parts = rgb_rel.split("/")
    if fmt.COLOR_DIR in parts:
        parts[len(parts) - 1 - parts[::-1].index(fmt.COLOR_DIR)] = fmt.SEGMENTATION_DIR
    stem = parts[-1].rsplit(".", 1)[0]
    parts[-1] = stem + fmt.SEGMENTATION_EXT
    return "/".join(parts)


def open_midair(
    root: str | Path,
    split_dir: str | Path,
    split: str = "test",
    seq_len: int = 1,
    size: int | tuple[int, int] | None = MIDAIR_IMAGE_SIZE,
    augment=False,
    *,
    mode: str | None = None,
    db_seq_len: int | None = None,
    labels: str = "midair",
    modalities: Iterable[str] | None = None,
    seed: int = 0,
    name: str = "midair",
    jpeg_idct: str = DEFAULT_JPEG_IDCT,
    reduced_decode: bool = False,
    calibration=None,
) -> SequenceDataset:
    """Open a split of a Mid-Air-format dataset (Mid-Air itself or SynthAir).

    Args:
        root: dataset root; the CSV paths are relative to it.
        split_dir: folder holding ``<split>_data/**/*.csv`` (see :mod:`cosemdepth.data.csvsplits`).
        split: ``"train"``, ``"val"``, ``"test"`` (or any folder name present).
        seq_len: frames per item.
        size: output size, int or ``(H, W)``; ``None`` keeps the native size of each file.
        augment: ``False``, ``True`` (paper settings), a preset name or an :class:`AugmentConfig`.
        mode: window mode (``"train"``, ``"windowed"``, ``"stream"``); default ``"train"`` for the train split,
            ``"windowed"`` for val with ``seq_len > 1`` (design 7.3) and ``"stream"`` otherwise
            (:func:`cosemdepth.data.sequence.default_mode`).
        db_seq_len: chunk length in train mode (default ``seq_len``; the paper uses 4 / 4).
        labels: ``"midair"`` (14 IDs mapped to 7 classes), ``"mapped"`` (files already hold the 7 classes) or
            ``"raw"`` (the 14 IDs, unmapped).
        modalities: subset of ``("depth", "semantic")`` to load (default: all the CSVs provide).
        seed: base seed of the random window offsets and augmentations.
        name: stored as ``dataset.name``.
        jpeg_idct: JPEG decoding, ``"fast"`` (default: libjpeg-turbo's fast integer IDCT, bit-exact with the
            original's ``tf.io.decode_jpeg``) or ``"accurate"`` (see :mod:`cosemdepth.data.decode`).
        reduced_decode: decode each JPEG at the smallest DCT scale ``M/8`` at least the output size, then BL2 the
            rest (faster, a low-pass picture; not the original's pixels). Off by default (the exact path); training
            turns it on for its training datasets with ``data.train_decode: reduced``.
        calibration: the lens of the images (a calibration file or a :class:`~cosemdepth.camera.Calibration`):
            frames are undistorted to a centred pinhole (:func:`cosemdepth.data.csvsplits.open_csv_split`). A
            SynthAir set rendered through a lens (``cosemdepth synth --distortion``) needs one (its own files are in
            ``ROOT/calibration/``), or ``calibration=False`` to read its images as if they were a pinhole's.
    """
    check_jpeg_idct(jpeg_idct)
    if calibration is None:
        lens = rendered_lens(root)
        if lens is not None:
            raise DatasetError(
                f"{root}: this SynthAir set was rendered through a {lens} lens; pass its calibration "
                f"(--calibration {Path(root) / 'calibration' / 'camera_info.yaml'}) to undistort it"
            )
    elif calibration is False:
        calibration = None
    return open_csv_split(
        root,
        split_dir,
        split,
        seq_len,
        size,
        augment,
        columns={"rgb": "camera_l", "depth": "disp", "semantic": "semantic"},
        reset_rule=lambda ids: ids == 0,
        derive={"semantic": _derive_semantic},
        make_loader=lambda out_size: MidAirFrameLoader(out_size, labels, jpeg_idct, reduced_decode),
        mode=mode,
        db_seq_len=db_seq_len,
        modalities=modalities,
        seed=seed,
        name=name,
        calibration=calibration,
    )


def rendered_lens(root: str | Path) -> str | None:
    """The lens model a SynthAir set at ``root`` was rendered through (its ``synthair.json``), None for a pinhole
    set or anything else."""
    meta = Path(root) / "synthair.json"
    try:
        lens = json.loads(meta.read_text()).get("camera", {}).get("distortion")
    except (OSError, ValueError, AttributeError):
        return None
    return str(lens.get("model")) if isinstance(lens, dict) else None
