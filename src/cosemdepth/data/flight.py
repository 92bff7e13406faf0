"""Your own flight: a folder of images + a file of absolute camera poses + intrinsics -> model-ready sequences.

Inputs:

* ``root``: a folder of images (``.jpg``, ``.jpeg``, ``.png``, any case; or a sub-folder ``images/`` of it), all of
  the same size;
* ``poses``: a pose file (default: the first of ``poses.txt``, ``poses.tum``, ``poses.csv``, ``groundtruth.txt``
  in ``root``) in TUM or CSV format, with the world/camera convention of :mod:`cosemdepth.data.poses`;
* ``intrinsics=(fx, fy, cx, cy)`` in pixels of the original images, or ``fov`` = horizontal field of view in
  degrees (square pixels, centred principal point). The principal point is in the convention of design 2.1 (pixel
  ``(i, j)`` covers ``[j, j+1] x [i, i+1]``; a centred camera has ``cx = W/2``). Calibration tools in the OpenCV
  convention (pixel centres at integer coordinates, centred ``cx = (W-1)/2``) need ``+0.5``:
  pass ``intrinsics_convention="opencv"`` to have it added.

Matching images to poses (``match``: ``"auto"``, ``"stamp"``, ``"order"``, ``"index"``; ``stamp_unit``;
``max_gap``; ``skip_unposed``): see :mod:`cosemdepth.data.pose_matching`. What was matched, and why, is kept as
``dataset.pose_matching`` (:meth:`~cosemdepth.data.pose_matching.PoseMatch.summary`, plus ``"describe"``: one line).

``frame_skip = k`` keeps images 0, k, 2k, ... (after matching). The first kept frame is a reset with the identity
motion; every other frame carries the motion from the previous kept frame, ``X_prev = R X_curr + t`` in camera axes
(x right, y down, z forward). Intrinsics are rescaled to the output size (``fx, cx`` by ``W_out/W``, ``fy, cy`` by
``H_out/H``).

A calibrated lens (``calibration``: a calibration file, :func:`cosemdepth.camera.load_calibration`, or a
:class:`~cosemdepth.camera.Calibration`) replaces ``intrinsics`` / ``fov``: the images are undistorted to a centred
pinhole at the output size (:class:`~cosemdepth.camera.Undistorter`), the dataset's intrinsics are that pinhole's,
items carry ``source_valid`` (the pixels with a source) and the ground truth is remapped with the images (depth
nearest, 0 where no source; labels nearest). A calibration for another image size of the same aspect ratio is
scaled (said in ``dataset.calibration["calibration"]["note"]``). ``dataset.calibration`` is
:meth:`Undistorter.info <cosemdepth.camera.Undistorter.info>` (None without a calibration).

Optional ground truth: ``depth_dir`` with one file per image of the same stem, ``.npy`` (float metres, finite and
>= 0, 0 where unknown; see :func:`read_depth_npy`) or a 16-bit
``.png`` times ``depth_scale`` metres (default 0.001); ``semantic_dir`` with class-ID PNGs (checked against
``num_classes``). Depth is BL2-resized, labels NN2-resized.
"""

from __future__ import annotations

import math
import re
import tokenize
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ..camera import Calibration, UndistortedFrames
from ..errors import ConfigError, DatasetError
from ..models.config import ModelConfig
from .augment import resolve_augment
from .decode import (
    DEFAULT_JPEG_IDCT,
    check_image_size,
    check_jpeg_idct,
    check_nonnegative,
    image_size,
    read_label_ids,
    read_rgb,
    read_uint16_png,
)
from .frames import Size, depth_to_tensor, labels_to_tensor, resolve_size, rgb_to_tensor
from .pose_matching import DEFAULT_MAX_GAP, match_images
from .poses import read_poses, relative_camera_motions
from .sequence import FrameRecord, SequenceDataset, Trajectory
from .undistorted import undistorter_for

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png")
DEFAULT_POSE_FILES = ("poses.txt", "poses.tum", "poses.csv", "groundtruth.txt")
#: Axes of a flight's posed frame when none is given (:data:`cosemdepth.data.poses.CONVENTIONS`).
DEFAULT_CONVENTION = "opencv"


def natural_key(name: str) -> list:
    """Sort key putting ``img2`` before ``img10``."""
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", name)]


def list_images(folder: Path) -> list[Path]:
    """Image files of ``folder`` (non-recursive), naturally sorted."""
    if not folder.is_dir():
        raise DatasetError(f"{folder}: image folder not found (or not a folder)")
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS]
    if not files and (folder / "images").is_dir():
        return list_images(folder / "images")
    if not files:
        raise DatasetError(f"{folder}: no images ({', '.join(IMAGE_EXTENSIONS)}) found")
    return sorted(files, key=lambda p: natural_key(p.name))


def parse_intrinsics(intrinsics, fov: float | None, native: Size, convention: str = "model") -> np.ndarray:
    """``(fx, fy, cx, cy)`` in pixels of the native image from ``intrinsics`` (4 numbers, or a string
    ``"fx,fy,cx,cy"``) or a horizontal ``fov`` in degrees."""
    h, w = native
    if (intrinsics is None) == (fov is None):
        raise ConfigError("a flight needs exactly one of intrinsics=(fx, fy, cx, cy) or fov=<horizontal degrees>")
    if fov is not None:
        if not 0 < float(fov) < 180:
            raise ConfigError(f"fov must be a horizontal field of view in degrees in (0, 180), got {fov!r}")
        f = (w / 2) / math.tan(math.radians(float(fov)) / 2)
        return np.array([f, f, w / 2, h / 2])
    if isinstance(intrinsics, str):
        intrinsics = [s for s in re.split(r"[,\s]+", intrinsics.strip()) if s]
    try:
        k = np.array([float(v) for v in intrinsics], dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"intrinsics must be 4 numbers (fx, fy, cx, cy), got {intrinsics!r}") from None
    if k.shape != (4,) or not np.isfinite(k).all() or k[0] <= 0 or k[1] <= 0:
        raise ConfigError(f"intrinsics must be 4 finite numbers (fx, fy, cx, cy) with fx, fy > 0, got {intrinsics!r}")
    if convention == "opencv":
        k[2:] += 0.5
    elif convention != "model":
        raise ConfigError(f"intrinsics_convention must be 'model' or 'opencv', got {convention!r}")
    return k


def scale_intrinsics(k: np.ndarray, native: Size, out: Size) -> torch.Tensor:
    """Rescale ``(fx, fy, cx, cy)`` from ``native = (H, W)`` to ``out = (H', W')``."""
    sy, sx = out[0] / native[0], out[1] / native[1]
    return torch.tensor([k[0] * sx, k[1] * sy, k[2] * sx, k[3] * sy], dtype=torch.float32)


class FlightFrameLoader:
    """Loads one flight image (and optional depth/labels) at the output size. Picklable."""

    def __init__(
        self, size: Size, native: Size, depth_scale: float, num_classes: int, jpeg_idct: str = DEFAULT_JPEG_IDCT
    ) -> None:
        self.size = size
        self.native = native
        self.depth_scale = depth_scale
        self.num_classes = num_classes
        self.jpeg_idct = check_jpeg_idct(jpeg_idct)

    def __call__(self, rec: FrameRecord) -> dict[str, torch.Tensor]:
        rgb = read_rgb(rec.rgb, self.jpeg_idct)
        if rgb.shape[:2] != tuple(self.native):
            raise DatasetError(
                f"{rec.rgb}: image is {rgb.shape[0]}x{rgb.shape[1]} but the flight's first image is "
                f"{self.native[0]}x{self.native[1]}; all images of a flight must have one size"
            )
        out = {"rgb": rgb_to_tensor(rgb, self.size)}
        if rec.depth is not None:
            out["depth"] = depth_to_tensor(self._depth(rec.depth), self.size)
        if rec.semantic is not None:
            out["semantic"] = labels_to_tensor(read_label_ids(rec.semantic, self.num_classes), self.size, "nn2")
        return out

    def _depth(self, path: Path) -> np.ndarray:
        if path.suffix.lower() == ".npy":
            return read_depth_npy(path)
        return read_uint16_png(path).astype(np.float32) * np.float32(self.depth_scale)


def read_depth_npy(path: str | Path) -> np.ndarray:
    """A ``.npy`` depth map -> ``[H, W]`` float32 metres.

    The header is checked before any data is read: a real numeric dtype (bool, int, float), 2-D once unit axes
    are dropped, at most :data:`~cosemdepth.data.decode.MAX_PIXELS` values, and as many bytes as it declares.
    The values must be finite and non-negative in float32 (write 0 where the depth is unknown).
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
            elif version == (2, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
            else:
                raise DatasetError(f"{path}: unsupported .npy format version {version[0]}.{version[1]}")
            if dtype.kind not in "biuf":
                raise DatasetError(f"{path}: depth array must hold real numbers, got dtype {dtype}")
            squeezed = [d for d in shape if d != 1]
            if len(squeezed) != 2:
                raise DatasetError(f"{path}: depth array must be 2-D, got shape {list(shape)}")
            check_image_size(path, squeezed[1], squeezed[0])
            count = squeezed[0] * squeezed[1]
            data = f.read(count * dtype.itemsize)
    except FileNotFoundError:
        raise DatasetError(f"{path}: file not found") from None
    except (OSError, ValueError, SyntaxError, EOFError, tokenize.TokenError) as e:
        raise DatasetError(f"{path}: cannot read depth array ({e})") from None
    if len(data) != count * dtype.itemsize:
        raise DatasetError(f"{path}: depth array is truncated ({len(data)} of {count * dtype.itemsize} bytes)")
    d = np.frombuffer(data, dtype=dtype).reshape(squeezed, order="F" if fortran else "C")
    with np.errstate(over="ignore"):
        d = d.astype(np.float32)
    check_nonnegative(path, d, "depth", note=" in float32", hint="; write 0 where the depth is unknown")
    return d


def _companion(folder: Path, stem: str, exts: Sequence[str], what: str) -> Path:
    for ext in exts:
        p = folder / f"{stem}{ext}"
        if p.is_file():
            return p
    raise DatasetError(f"{folder}: no {what} file for image {stem!r} (looked for {', '.join(stem + e for e in exts)})")


def open_flight(
    root: str | Path,
    split_dir=None,
    split=None,
    seq_len: int = 1,
    size: int | tuple[int, int] | None = None,
    augment=False,
    *,
    poses: str | Path | None = None,
    pose_format: str = "auto",
    convention=DEFAULT_CONVENTION,
    intrinsics=None,
    fov: float | None = None,
    intrinsics_convention: str = "model",
    match: str = "auto",
    stamp_unit="auto",
    frame_skip: int = 1,
    max_gap: float = DEFAULT_MAX_GAP,
    skip_unposed: bool = False,
    depth_dir: str | Path | None = None,
    depth_scale: float = 0.001,
    semantic_dir: str | Path | None = None,
    num_classes: int = ModelConfig.num_classes,
    mode: str = "stream",
    db_seq_len: int | None = None,
    seed: int = 0,
    name: str = "flight",
    jpeg_idct: str = DEFAULT_JPEG_IDCT,
    calibration: str | Path | Calibration | None = None,
) -> SequenceDataset:
    """Open your own flight (see the module docstring). ``split_dir`` and ``split`` are ignored (one flight is
    one trajectory); ``size`` defaults to the native image size (a
    :class:`~cosemdepth.data.frames.FocalSize` is applied to the native size and ``fx`` of the intrinsics). ``jpeg_idct``: JPEG decoding, ``"fast"`` (default,
    as the models were trained: the original's ``tf.io.decode_jpeg``) or ``"accurate"``. ``calibration``: a lens
    to undistort (module docstring), instead of ``intrinsics`` / ``fov``."""
    check_jpeg_idct(jpeg_idct)
    if calibration is not None:
        if intrinsics is not None or fov is not None:
            raise ConfigError("give a flight's calibration or its intrinsics / fov, not both")
        if augment:
            raise ConfigError("a calibrated (undistorted) flight cannot be augmented")
    root = Path(root)
    images = list_images(root)
    if poses is None:
        found = [root / n for n in DEFAULT_POSE_FILES if (root / n).is_file()]
        if not found:
            raise DatasetError(f"{root}: no pose file given and none of {DEFAULT_POSE_FILES} found there")
        poses = found[0]
    track = read_poses(poses, pose_format)
    if not isinstance(frame_skip, int) or frame_skip < 1:
        raise ConfigError(f"frame_skip must be a positive integer, got {frame_skip!r}")

    matched = match_images(
        images, track, match=match, stamp_unit=stamp_unit, max_gap=max_gap, skip_unposed=skip_unposed
    )
    images, pos, quat, times = matched.images, matched.positions, matched.quaternions, matched.times

    keep = np.arange(0, len(images), frame_skip)
    images = [images[i] for i in keep]
    with np.errstate(over="ignore", invalid="ignore"):
        q_rel, t_rel = relative_camera_motions(quat[keep], pos[keep], convention)
    # The dataset hands motions to the model as float32: each must be finite there.
    big = np.finfo(np.float32).max
    ok = (np.abs(q_rel) <= big).all(axis=1) & (np.abs(t_rel) <= big).all(axis=1)
    if not ok.all():
        i = int(np.flatnonzero(~ok)[0])
        raise DatasetError(
            f"{track.path}: the camera motion to image {images[i].name} is not finite in float32 "
            "(positions too large or too far apart)"
        )
    times = times[keep] if times is not None else None

    depth_dir = Path(depth_dir) if depth_dir is not None else None
    semantic_dir = Path(semantic_dir) if semantic_dir is not None else None
    frames = []
    for i, img in enumerate(images):
        frames.append(
            FrameRecord(
                rgb=img,
                depth=_companion(depth_dir, img.stem, (".npy", ".png"), "depth") if depth_dir else None,
                semantic=_companion(semantic_dir, img.stem, (".png",), "label") if semantic_dir else None,
                rot=tuple(float(v) for v in q_rel[i]),
                trans=tuple(float(v) for v in t_rel[i]),
                id=int(matched.indices[keep[i]]),
                timestamp=float(times[i]) if times is not None else None,
            )
        )
    native = image_size(images[0])
    undistorter = None
    if calibration is not None:
        undistorter = undistorter_for(calibration, native, size, "the flight's images")
        loader = UndistortedFrames(FlightFrameLoader(None, native, depth_scale, num_classes, jpeg_idct), undistorter)
        intr = undistorter.intrinsics
    else:
        k_native = parse_intrinsics(intrinsics, fov, native, intrinsics_convention)
        out_size = resolve_size(size, lambda: (native, float(k_native[0]))) or native
        loader = FlightFrameLoader(out_size, native, depth_scale, num_classes, jpeg_idct)
        intr = scale_intrinsics(k_native, native, out_size)
    dataset = SequenceDataset(
        [Trajectory.from_records(root.name, frames)],
        loader,
        intr,
        seq_len=seq_len,
        mode=mode,
        db_seq_len=db_seq_len,
        augment=resolve_augment(augment),
        seed=seed,
        name=name,
        size_at=lambda rule: (
            undistorter_for(calibration, native, rule, "the flight's images").size
            if calibration is not None
            else resolve_size(rule, lambda: (native, float(k_native[0]))) or native
        ),
    )
    dataset.pose_matching = {**matched.summary(), "describe": matched.describe()}
    dataset.calibration = None if undistorter is None else undistorter.info()
    return dataset
