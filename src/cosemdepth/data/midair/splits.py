"""Mid-Air split CSVs: the generator from ``sensor_records.hdf5`` (design 10.3, 10.4) and CSV read/write.

A CSV row ``k`` refers to camera frame ``K (k + 1)`` and holds the relative motion from frame ``K k`` to frame
``K k + K`` in camera axes, such that ``X_prev = R(q) X_curr + t`` (design 2.2); ``K`` is the frame step, Mid-Air's
4 (25 Hz camera, rows at 6.25 Hz) unless a generator asks for another one.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import h5py
import numpy as np

from ...errors import DatasetError
from ...output_safety.atomic import atomic_write_text
from ...output_safety.staging import StagedDir
from ..files import dataset_root, read_text
from ..quaternion import qconj, qmul, qrotate
from . import format as fmt

#: Ground-truth samples per camera frame (100 Hz / 25 Hz).
GT_PER_FRAME = fmt.GROUNDTRUTH_RATE // fmt.CAMERA_RATE
#: Ground-truth samples per CSV row: 4 camera frames x 4 ground-truth samples per frame.
GT_PER_ROW = fmt.FRAME_SKIP * GT_PER_FRAME

#: Co-SemDepth's validation trajectories (taken out of the M4Depth test split), by (environment, number).
MIDAIR_VALIDATION = {
    ("Kite_training", 6),
    ("Kite_training", 1009),
    ("Kite_training", 2000),
    ("Kite_training", 3012),
    ("PLE_training", 4006),
    ("PLE_training", 4015),
    ("PLE_training", 5018),
    ("PLE_training", 6021),
}

SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class Trajectory:
    env: str
    climate: str
    number: int  # as in the folder name trajectory_XXXX
    index: int  # position in the sorted listing of the climate (the CSV's traj_XXXX number)

    @property
    def name(self) -> str:
        return fmt.trajectory_dir(self.number)


def relative_motions(
    attitude: np.ndarray, position: np.ndarray, stride: int = GT_PER_ROW
) -> tuple[np.ndarray, np.ndarray]:
    """Per-row relative motion in camera axes from 100 Hz ground truth (body NED, quaternion w-first).

    Args:
        attitude: ``[N, 4]`` unit quaternions (w, x, y, z), body -> world.
        position: ``[N, 3]`` positions in metres (NED world frame).
        stride: ground-truth samples between two rows (``4 K`` for a frame step of ``K`` camera frames).
    Returns:
        ``(q [R, 4], t [R, 3])`` with ``R = (N - stride) // stride`` rows, camera axes (x right, y down, z forward):
        row ``k`` is the motion from sample ``stride k`` to sample ``stride (k + 1)``.
    """
    attitude = np.asarray(attitude, dtype=np.float64)
    position = np.asarray(position, dtype=np.float64)
    n_rows = max((len(attitude) - stride) // stride, 0)
    a = np.arange(n_rows) * stride
    b = a + stride
    inv_a = qconj(attitude[a])
    q_body = qmul(inv_a, attitude[b])
    # an unchanged attitude is exactly no rotation (the product's rounding depends on the CPU's vector width)
    q_body[(attitude[a] == attitude[b]).all(axis=1)] = (1.0, 0.0, 0.0, 0.0)
    t_body = qrotate(inv_a, position[b] - position[a])
    q_cam = q_body[:, [0, 2, 3, 1]]
    t_cam = t_body[:, [1, 2, 0]]
    return q_cam, t_cam


def midair_split_rule(traj: Trajectory) -> str:
    """The paper's rule: index % 3 == 0 is test, except the 8 fixed validation trajectories; the rest train."""
    if (traj.env, traj.number) in MIDAIR_VALIDATION:
        return "val"
    return "test" if traj.index % 3 == 0 else "train"


def generic_split_rule(trajectories: Sequence[Trajectory]) -> Callable[[Trajectory], str]:
    """Rule for datasets other than Mid-Air (e.g. SynthAir): index % 3 == 0 is test, the rest train; in each
    climate that has at least two test trajectories, the last one goes to validation instead."""
    val = set()
    by_climate: dict[tuple[str, str], list[Trajectory]] = {}
    for t in trajectories:
        if t.index % 3 == 0:
            by_climate.setdefault((t.env, t.climate), []).append(t)
    for tests in by_climate.values():
        if len(tests) >= 2:
            val.add(max(tests, key=lambda t: t.index))

    def rule(traj: Trajectory) -> str:
        if traj in val:
            return "val"
        return "test" if traj.index % 3 == 0 else "train"

    return rule


def find_climates(root: Path) -> list[tuple[str, str]]:
    """``(env, climate)`` folders under ``root`` that hold a ``sensor_records.hdf5``, sorted."""
    root = dataset_root(root)
    found = sorted({(p.parent.parent.name, p.parent.name) for p in root.glob(f"*/*/{fmt.SENSOR_RECORDS}")})
    if not found:
        raise DatasetError(f"{root}: no <env>/<climate>/{fmt.SENSOR_RECORDS} found; is this a Mid-Air-format root?")
    return found


def list_trajectories(root: Path, env: str, climate: str) -> list[Trajectory]:
    """Trajectories of one climate, from the ``color_left`` listing, numbered in sorted order."""
    color = root / env / climate / fmt.COLOR_DIR
    if not color.is_dir():
        raise DatasetError(f"{color}: missing colour image folder")
    names = sorted(p.name for p in color.iterdir() if p.is_dir() and p.name.startswith("trajectory_"))
    out = []
    for i, name in enumerate(names):
        try:
            number = int(name.split("_", 1)[1])
        except ValueError:
            raise DatasetError(f"{color / name}: trajectory folder name must be trajectory_<number>") from None
        out.append(Trajectory(env, climate, number, i))
    return out


def trajectory_rows(
    traj: Trajectory, attitude: np.ndarray, position: np.ndarray, frame_step: int = fmt.FRAME_SKIP
) -> list[dict]:
    """The CSV rows of one trajectory (paths relative to the dataset root), one every ``frame_step`` camera
    frames: row ``k`` is frame ``frame_step (k + 1)`` with the motion from frame ``frame_step k``."""
    q, t = relative_motions(attitude, position, stride=frame_step * GT_PER_FRAME)
    base = f"{traj.env}/{traj.climate}"
    rows = []
    for k in range(len(q)):
        frame = frame_step * (k + 1)
        rows.append(
            {
                "id": k,
                "camera_l": f"{base}/{fmt.COLOR_DIR}/{traj.name}/{fmt.frame_name(frame, fmt.COLOR_EXT)}",
                "disp": f"{base}/{fmt.DISPARITY_DIR}/{traj.name}/{fmt.frame_name(frame, fmt.DISPARITY_EXT)}",
                "semantic": f"{base}/{fmt.SEGMENTATION_DIR}/{traj.name}/{fmt.frame_name(frame, fmt.SEGMENTATION_EXT)}",
                "qw": q[k, 0],
                "qx": q[k, 1],
                "qy": q[k, 2],
                "qz": q[k, 3],
                "tx": t[k, 0],
                "ty": t[k, 1],
                "tz": t[k, 2],
            }
        )
    return rows


def format_csv(rows: Iterable[Mapping], columns: Sequence[str] = fmt.CSV_COLUMNS) -> str:
    """Rows -> the authors' tab-separated text (header, floats with 6 decimals)."""
    buf = io.StringIO()
    buf.write("\t".join(columns) + "\n")
    for r in rows:
        fields = []
        for c in columns:
            v = r[c]
            fields.append(f"{v:.6f}" if isinstance(v, (float, np.floating)) else str(v))
        buf.write("\t".join(fields) + "\n")
    return buf.getvalue()


def write_csv(path: Path, rows: Iterable[Mapping], columns: Sequence[str] = fmt.CSV_COLUMNS) -> None:
    """Write a split CSV atomically (``columns``: Mid-Air's by default; TopAir has ``depth`` for ``disp``)."""
    atomic_write_text(path, format_csv(rows, columns))


#: Largest accepted deviation of a CSV quaternion's norm from 1 (the authors print 6 decimals).
QUATERNION_TOLERANCE = 1e-3

_MOTION_COLUMNS = ("qw", "qx", "qy", "qz", "tx", "ty", "tz")
_REQUIRED_COLUMNS = ("id", "camera_l") + _MOTION_COLUMNS


def read_csv(path: Path) -> list[dict]:
    """Read and validate a split CSV (tab separated, header line, design 10.3).

    ``id`` is converted to int and the motion columns to float; other columns (``camera_l``, ``disp``,
    ``semantic``, TopAir's ``depth``...) stay strings. Raises a :class:`DatasetError` naming the file and line for a
    missing/unreadable file, a missing column, a row with the wrong number of fields (truncated file), a malformed,
    NaN or infinite number, a quaternion whose norm is not 1 (within :data:`QUATERNION_TOLERANCE`), an empty path
    field, or a file without data rows.
    """
    path = Path(path)
    text = read_text(path, "split CSV")
    try:
        return _read_rows(path, csv.DictReader(io.StringIO(text), delimiter="\t"))
    except csv.Error as e:  # e.g. a field over the csv module's size limit
        raise DatasetError(f"{path}: malformed split CSV ({e})") from None


#: Range of the values a split CSV may hold: ids are int64, motions float32 in the datasets built from them.
_ID_RANGE = (-(2**63), 2**63 - 1)
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def _read_rows(path: Path, reader: csv.DictReader) -> list[dict]:
    if not reader.fieldnames:
        raise DatasetError(f"{path}: empty split CSV (no header)")
    missing = [c for c in _REQUIRED_COLUMNS if c not in reader.fieldnames]
    if missing:
        raise DatasetError(f"{path}: split CSV header lacks column(s) {missing}; found {reader.fieldnames}")
    path_columns = [c for c in reader.fieldnames if c not in _REQUIRED_COLUMNS or c == "camera_l"]
    rows = []
    for r in reader:
        line_no = reader.line_num
        if None in r or any(v is None for v in r.values()):
            raise DatasetError(f"{path}:{line_no}: row has the wrong number of fields (truncated CSV?)")
        try:
            r["id"] = int(r["id"])
        except ValueError:
            raise DatasetError(f"{path}:{line_no}: malformed id {r['id']!r}") from None
        if not _ID_RANGE[0] <= r["id"] <= _ID_RANGE[1]:
            raise DatasetError(f"{path}:{line_no}: id {r['id']} out of the int64 range")
        for c in _MOTION_COLUMNS:
            try:
                r[c] = float(r[c])
            except ValueError:
                raise DatasetError(f"{path}:{line_no}: malformed number {r[c]!r} in column {c}") from None
            if not abs(r[c]) <= _FLOAT32_MAX:
                raise DatasetError(f"{path}:{line_no}: column {c} is {r[c]} (NaN/inf, or beyond float32's range)")
        norm = math.sqrt(sum(r[c] ** 2 for c in ("qw", "qx", "qy", "qz")))
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise DatasetError(f"{path}:{line_no}: quaternion (qw, qx, qy, qz) is not unit (norm {norm:.6f})")
        for c in path_columns:
            if not r[c].strip():
                raise DatasetError(f"{path}:{line_no}: empty {c} field")
        rows.append(r)
    if not rows:
        raise DatasetError(f"{path}: split CSV has a header but no data rows (empty or truncated)")
    return rows


def generate_splits(
    root: str | Path,
    out_dir: str | Path,
    rule: Callable[[Trajectory], str] | str = "auto",
    frame_step: int = fmt.FRAME_SKIP,
) -> dict[str, list[Path]]:
    """Write ``out_dir/{train,val,test}_data/<env>/<climate>/traj_XXXX.csv`` for a Mid-Air-format root.

    Args:
        root: dataset root holding ``<env>/<climate>/sensor_records.hdf5`` and the image folders.
        out_dir: where the split folders go (nothing is written into ``root``).
        rule: ``"midair"`` (the paper's), ``"generic"`` (see :func:`generic_split_rule`), ``"auto"`` (midair when
            the root has Mid-Air's environment names), a split name (``"train"``, ``"val"``, ``"test"``: every
            trajectory goes to that split, e.g. for a world used only for training or only for testing) or a
            callable ``Trajectory -> split name``.
        frame_step: camera frames between two rows (Mid-Air's 4: rows at 25 / 4 = 6.25 Hz; 2 doubles the rate).
    Returns:
        split name -> written CSV paths. A trajectory too short for one row (fewer than ``8 frame_step``
        ground-truth samples, 32 at the default step) gets no CSV; the others keep their index in the sorted
        listing.
    """
    if not isinstance(frame_step, int) or frame_step < 1:
        raise ValueError(f"frame_step must be a positive integer, got {frame_step!r}")
    root, out_dir = Path(root), Path(out_dir)
    climates = find_climates(root)
    trajs = [t for env, cl in climates for t in list_trajectories(root, env, cl)]
    if rule == "auto":
        rule = "midair" if all(env in fmt.ENVIRONMENTS for env, _ in climates) else "generic"
    if rule == "midair":
        rule_fn = midair_split_rule
    elif rule == "generic":
        rule_fn = generic_split_rule(trajs)
    elif rule in SPLITS:

        def rule_fn(traj: Trajectory, _split: str = rule) -> str:
            return _split
    elif callable(rule):
        rule_fn = rule
    else:
        raise ValueError(f"unknown split rule {rule!r}")

    written: dict[str, list[Path]] = {s: [] for s in SPLITS}
    planned: list[tuple[str, Path, list]] = []
    for env, climate in climates:
        h5_path = root / env / climate / fmt.SENSOR_RECORDS
        try:
            h5 = h5py.File(h5_path, "r")
        except OSError as e:
            raise DatasetError(f"{h5_path}: cannot open HDF5 file ({e})") from None
        with h5:
            for traj in (t for t in trajs if (t.env, t.climate) == (env, climate)):
                att, pos = _read_groundtruth(h5, h5_path, traj.name)
                _check_groundtruth(h5_path, traj.name, att, pos)
                with np.errstate(over="ignore", invalid="ignore"):
                    rows = trajectory_rows(traj, att, pos, frame_step)
                if not rows:  # fewer than two rows' worth of ground-truth samples: nothing to write
                    continue
                _check_motions(h5_path, traj.name, rows)
                split = rule_fn(traj)
                if split not in written:
                    raise ValueError(f"split rule returned {split!r}; expected one of {SPLITS}")
                planned.append((split, Path(f"{split}_data") / env / climate / f"traj_{traj.index:04d}.csv", rows))
    return write_split_files(out_dir, planned, written)


def write_split_files(
    out_dir: Path, planned: list, written: dict[str, list[Path]], columns: tuple[str, ...] | None = None
) -> dict[str, list[Path]]:
    """Make the planned ``(split, relative path, rows)`` CSVs the contents of ``out_dir``, under the output policy
    (:mod:`cosemdepth.output_safety.outdir`): a previous ``splits`` output there is replaced as a whole (no CSV of another
    rule is left over), a folder holding anything else (a CSV nobody wrote or one edited since) is refused. Returns
    ``written`` with the paths appended."""
    if not planned:
        return written
    with StagedDir(out_dir, "splits", overwrite=None, what="split folder") as tmp:
        for _, rel, rows in planned:
            write_csv(tmp / rel, rows, *([columns] if columns else []))
    for split, rel, _ in planned:
        written[split].append(Path(out_dir) / rel)
    return written


#: Most ground-truth samples accepted per trajectory (about 28 hours at 100 Hz): a larger declared size is a
#: corrupt or foreign file, and reading it would take gigabytes.
MAX_GROUNDTRUTH_SAMPLES = 10_000_000


def _read_groundtruth(h5, h5_path: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(attitude [N, 4], position [N, 3])`` of trajectory ``name``, float64, after checking that both are numeric
    datasets of that shape and a plausible size (nothing is read before)."""
    where = f"{h5_path}: {name}/groundtruth"
    try:
        traj = h5.get(name)
        gt = traj.get("groundtruth") if isinstance(traj, h5py.Group) else None
        if not isinstance(gt, h5py.Group):
            raise DatasetError(f"{h5_path}: trajectory {name} lacks groundtruth data (no {name}/groundtruth group)")
        out = []
        for key, width in (("attitude", 4), ("position", 3)):
            ds = gt.get(key)
            if not isinstance(ds, h5py.Dataset):
                raise DatasetError(f"{where}/{key} is missing or not a dataset")
            if ds.dtype.kind not in "iuf":
                raise DatasetError(f"{where}/{key} must hold real numbers, got dtype {ds.dtype}")
            if len(ds.shape) != 2 or ds.shape[1] != width:
                raise DatasetError(f"{where}/{key} must have shape [N, {width}], got {list(ds.shape)}")
            if ds.shape[0] > MAX_GROUNDTRUTH_SAMPLES:
                raise DatasetError(
                    f"{where}/{key} declares {ds.shape[0]} samples, more than {MAX_GROUNDTRUTH_SAMPLES} (corrupt?)"
                )
            out.append(np.asarray(ds[()], dtype=np.float64))
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as e:  # h5py's errors on a damaged file
        raise DatasetError(f"{where}: cannot read ({e})") from None
    return out[0], out[1]


def _check_motions(h5_path: Path, name: str, rows: list[dict]) -> None:
    """The CSV motions must be finite in float32 (the readers' precision), e.g. not from positions near 1e308."""
    big = float(np.finfo(np.float32).max)
    for k, r in enumerate(rows):
        if not all(abs(r[c]) <= big for c in _MOTION_COLUMNS):
            raise DatasetError(
                f"{h5_path}: {name}/groundtruth gives a motion beyond float32's range at row {k} "
                "(positions too large or too far apart)"
            )


def _check_groundtruth(h5_path: Path, name: str, att: np.ndarray, pos: np.ndarray) -> None:
    where = f"{h5_path}: {name}/groundtruth"
    if att.ndim != 2 or att.shape[1] != 4:
        raise DatasetError(f"{where}/attitude must have shape [N, 4], got {list(att.shape)}")
    if pos.ndim != 2 or pos.shape[1] != 3 or len(pos) != len(att):
        raise DatasetError(f"{where}/position must have shape [{len(att)}, 3], got {list(pos.shape)}")
    if not (np.isfinite(att).all() and np.isfinite(pos).all()):
        raise DatasetError(f"{where}: attitude or position holds NaN/inf")
    with np.errstate(over="ignore"):  # an overflowing norm is reported as not unit below
        norms = np.linalg.norm(att, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1) > 1e-3)
    if bad.size:
        raise DatasetError(f"{where}/attitude[{bad[0]}] is not a unit quaternion (norm {norms[bad[0]]:.6f})")
