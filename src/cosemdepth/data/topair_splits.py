"""TopAir split CSVs from the AirSim recordings (design 10.8), in the authors' format.

Input: ``<root>/<env>/airsim_rec.txt`` (AirSim's tab-separated recording with a header; the columns used are
``POS_X POS_Y POS_Z`` (NED world, metres) and ``Q_W Q_X Q_Y Q_Z`` (body-to-world, body x forward, y right,
z down)); row ``i`` goes with ``images/NNNNNN.png`` number ``i``.

Output: ``<out_dir>/{train,test}_data/traj_XXXX.csv`` with XXXX the environment's position in
:data:`cosemdepth.data.topair.ENVIRONMENTS` (test = OakForest_3 and RuralAust3_1). As the authors' files: a first
row ``id = -1`` for image 0 with the identity rotation and translation (1e-4, 1e-4, 1e-4); then row ``id = k``
for image ``(k+1) s`` (``s`` the environment's frame skip) with the motion from image ``k s``; a zero translation
is replaced by (1e-4, 1e-4, 1e-4). Unlike the authors (who rotate by Euler angles 1.57 rad), the body-to-camera
rotation is the exact axis permutation (x right = body y, y down = body z, z forward = body x).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from .files import dataset_root, read_text
from .midair.splits import write_split_files
from .poses import QUATERNION_TOLERANCE, relative_camera_motions
from .topair import ENVIRONMENTS, FRAME_SKIPS, TEST_ENVIRONMENTS

REC_FILE = "airsim_rec.txt"
_COLUMNS = ("POS_X", "POS_Y", "POS_Z", "Q_W", "Q_X", "Q_Y", "Q_Z")
ZERO_TRANSLATION = 1e-4


def read_airsim_rec(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(positions [N, 3], quaternions [N, 4] w-first)`` of an AirSim recording file."""
    text = read_text(path, "AirSim recording")
    reader = csv.DictReader(io.StringIO(text), delimiter="\t")
    values = []
    try:
        if reader.fieldnames is None or any(c not in reader.fieldnames for c in _COLUMNS):
            raise DatasetError(
                f"{path}: AirSim recording header must contain {list(_COLUMNS)}, got {reader.fieldnames}"
            )
        for row in reader:
            try:
                values.append([float(row[c]) for c in _COLUMNS])
            except (TypeError, ValueError):
                raise DatasetError(f"{path}:{reader.line_num}: malformed or missing pose values") from None
    except csv.Error as e:  # e.g. a field over the csv module's size limit
        raise DatasetError(f"{path}: malformed AirSim recording ({e})") from None
    if not values:
        raise DatasetError(f"{path}: AirSim recording holds no rows")
    v = np.array(values, dtype=np.float64)
    if not np.isfinite(v).all():
        line = int(np.flatnonzero(~np.isfinite(v).all(axis=1))[0]) + 2
        raise DatasetError(f"{path}:{line}: pose holds NaN/inf")
    with np.errstate(over="ignore"):  # an overflowing norm is reported as not unit below
        norms = np.linalg.norm(v[:, 3:], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1) > QUATERNION_TOLERANCE)
    if bad.size:
        raise DatasetError(f"{path}:{bad[0] + 2}: quaternion is not unit (norm {norms[bad[0]]:.6f})")
    return v[:, :3], v[:, 3:] / norms[:, None]


def topair_rows(env: str, positions: np.ndarray, quaternions: np.ndarray, skip: int) -> list[dict]:
    """The CSV rows of one environment (paths relative to the TopAir root)."""
    n = len(positions) // skip
    idx = np.arange(n) * skip
    q, t = relative_camera_motions(quaternions[idx], positions[idx], "ned")
    rows = []
    for m in range(n):
        tm = t[m] if m > 0 else np.zeros(3)
        if not tm.any():
            tm = np.full(3, ZERO_TRANSLATION)
        name = f"{m * skip:06d}.png"
        rows.append(
            {
                "id": m - 1,
                "camera_l": f"{env}/images/{name}",
                "depth": f"{env}/depth/{name}",
                "semantic": f"{env}/seg_id/{name}",
                "qw": float(q[m, 0]),
                "qx": float(q[m, 1]),
                "qy": float(q[m, 2]),
                "qz": float(q[m, 3]),
                "tx": float(tm[0]),
                "ty": float(tm[1]),
                "tz": float(tm[2]),
            }
        )
    return rows


TOPAIR_CSV_COLUMNS = ("id", "camera_l", "depth", "semantic", "qw", "qx", "qy", "qz", "tx", "ty", "tz")


def generate_topair_splits(root: str | Path, out_dir: str | Path) -> dict[str, list[Path]]:
    """Write the TopAir split CSVs of every known environment found under ``root``; returns split -> paths."""
    root, out_dir = dataset_root(root), Path(out_dir)
    envs = sorted(p.parent.name for p in root.glob(f"*/{REC_FILE}"))
    if not envs:
        raise DatasetError(f"{root}: no <env>/{REC_FILE} found; is this a TopAir root?")
    unknown = [e for e in envs if e not in ENVIRONMENTS]
    if unknown:
        raise DatasetError(f"{root}: unknown TopAir environment(s) {unknown}; known: {list(ENVIRONMENTS)}")
    written: dict[str, list[Path]] = {"train": [], "test": []}
    planned: list = []
    for env in envs:
        k = ENVIRONMENTS.index(env)
        pos, quat = read_airsim_rec(root / env / REC_FILE)
        with np.errstate(over="ignore", invalid="ignore"):
            rows = topair_rows(env, pos, quat, FRAME_SKIPS[k])
        big = float(np.finfo(np.float32).max)
        for m, r in enumerate(rows):
            if not all(abs(r[c]) <= big for c in ("qw", "qx", "qy", "qz", "tx", "ty", "tz")):
                raise DatasetError(
                    f"{root / env / REC_FILE}: the motion of row {m} is beyond float32's range "
                    "(positions too large or too far apart)"
                )
        split = "test" if env in TEST_ENVIRONMENTS else "train"
        planned.append((split, Path(f"{split}_data") / f"traj_{k:04d}.csv", rows))
    return write_split_files(out_dir, planned, written, columns=TOPAIR_CSV_COLUMNS)
