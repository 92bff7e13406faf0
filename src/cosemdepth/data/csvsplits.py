"""Finding split CSVs, turning their rows into trajectories and opening a split as a dataset (Mid-Air, SynthAir and
TopAir share this).

Layout: ``<split_dir>/<split>_data/**/*.csv`` (the authors' ``data/midair/{train,val,test}_data/...``); a plain
``<split_dir>/<split>/`` folder is accepted too. One CSV is one trajectory; CSVs are taken in sorted order of their
path relative to the split folder, rows in file order. Paths inside the CSVs are relative to the dataset root.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from ..camera import UndistortedFrames
from ..errors import ConfigError, DatasetError
from .augment import resolve_augment
from .decode import image_size
from .files import dataset_root, is_dir
from .frames import FocalSize, Size, as_size, midair_intrinsics, resolve_size
from .midair.splits import read_csv
from .sequence import FrameLoader, SequenceDataset, Trajectory, default_mode
from .undistorted import undistorter_for


def find_split_csvs(split_dir: str | Path, split: str) -> tuple[Path, list[Path]]:
    """``(split folder, sorted CSV paths)`` of ``split`` under ``split_dir``."""
    split_dir = Path(split_dir)
    if not split_dir.is_dir():
        raise DatasetError(f"{split_dir}: split folder not found (or not a folder)")
    candidates = [split_dir / f"{split}_data", split_dir / split]
    folder = next((c for c in candidates if c.is_dir()), None)
    if folder is None:
        raise DatasetError(
            f"{split_dir}: no {split!r} split here (looked for {candidates[0].name}/ and {candidates[1].name}/); "
            "write the split CSVs with `cosemdepth splits`"
        )
    csvs = sorted((p for p in folder.rglob("*.csv") if p.is_file()), key=lambda p: p.relative_to(folder).as_posix())
    if not csvs:
        raise DatasetError(f"{folder}: no split CSV files (*.csv) found")
    return folder, csvs


def trajectories_from_csvs(
    root: Path,
    folder: Path,
    csvs: Sequence[Path],
    columns: dict[str, str | None],
    reset_rule: Callable[[np.ndarray], np.ndarray],
    derive: dict[str, Callable[[str], str]] | None = None,
) -> list[Trajectory]:
    """Read the CSVs into :class:`Trajectory` objects.

    Args:
        root: dataset root (CSV paths are relative to it).
        folder: split folder (trajectory names are CSV paths relative to it, without ``.csv``).
        csvs: CSV files, in order.
        columns: modality -> CSV column, for ``"rgb"``, ``"depth"``, ``"semantic"``; ``None`` skips a modality.
            A column missing from a CSV means the modality is absent, unless ``derive`` has a rule for it.
        reset_rule: ``ids [n] -> reset flags [n]`` for stream mode (the first row is always a reset too).
        derive: modality -> ``rgb relative path -> that modality's relative path``, used when its column is missing
            (e.g. Mid-Air CSVs written by the original generator, which have no ``semantic`` column).
    """
    derive = derive or {}
    trajectories = []
    for csv_path in csvs:
        rows = read_csv(csv_path)
        header = rows[0].keys()
        sources: dict[str, Callable[[dict], str] | None] = {}
        for modality in ("depth", "semantic"):
            col = columns.get(modality)
            if col is None:
                sources[modality] = None
            elif col in header:
                sources[modality] = lambda r, c=col: r[c]
            elif modality in derive:
                rule = derive[modality]
                first = root / rule(rows[0][columns["rgb"]])
                sources[modality] = (lambda r, f=rule: f(r[columns["rgb"]])) if is_dir(first.parent) else None
            else:
                sources[modality] = None
        rgb_col = columns["rgb"]
        ids = np.array([r["id"] for r in rows], dtype=np.int64)
        reset = np.asarray(reset_rule(ids), dtype=bool).copy()
        reset[0] = True
        trajectories.append(
            Trajectory(
                csv_path.relative_to(folder).with_suffix("").as_posix(),
                [r[rgb_col] for r in rows],
                [(r["qw"], r["qx"], r["qy"], r["qz"]) for r in rows],
                [(r["tx"], r["ty"], r["tz"]) for r in rows],
                ids,
                root=root,
                depth=[sources["depth"](r) for r in rows] if sources["depth"] else None,
                semantic=[sources["semantic"](r) for r in rows] if sources["semantic"] else None,
                reset=reset,
            )
        )
    return trajectories


def check_modalities_consistent(trajectories: Sequence[Trajectory], where: Path) -> None:
    """All trajectories of a dataset must agree on which modalities they have (items are batched together)."""
    kinds = {(t.depth is not None, t.semantic is not None) for t in trajectories}
    if len(kinds) > 1:
        raise DatasetError(
            f"{where}: the split CSVs disagree on the modalities they provide (some have depth/semantic columns, "
            "some do not); use one format for the whole split"
        )


def open_csv_split(
    root: str | Path,
    split_dir: str | Path,
    split: str,
    seq_len: int,
    size: int | tuple[int, int] | None,
    augment,
    *,
    columns: Mapping[str, str],
    reset_rule: Callable[[np.ndarray], np.ndarray],
    make_loader: Callable[[Size | None], FrameLoader],
    derive: dict[str, Callable[[str], str]] | None = None,
    mode: str | None = None,
    db_seq_len: int | None = None,
    modalities: Iterable[str] | None = None,
    seed: int = 0,
    name: str = "",
    calibration=None,
) -> SequenceDataset:
    """Open a split of a dataset described by split CSVs (the common part of the Mid-Air/SynthAir and TopAir readers).

    Checks ``root`` and ``modalities`` (a subset of ``("depth", "semantic")``, default both), reads the CSVs of
    ``split`` under ``split_dir`` (:func:`find_split_csvs`, :func:`trajectories_from_csvs` with ``columns`` restricted
    to the wanted modalities, ``reset_rule`` and ``derive``), checks that they agree on their modalities, and returns
    a :class:`SequenceDataset` whose frames are read by ``make_loader(output size)`` (``None``: native size) and
    whose intrinsics are the 90-degree convention at the output size (the first image's size if ``size`` is None).
    ``size`` may be a :class:`~cosemdepth.data.frames.FocalSize`: applied to the first image's size and the
    90-degree camera there.

    Args:
        columns: modality -> CSV column, for ``"rgb"``, ``"depth"`` and ``"semantic"``.
        mode: window mode; default :func:`cosemdepth.data.sequence.default_mode` of ``split`` and ``seq_len``.
        calibration: the lens the images were taken through (a calibration file or a
            :class:`~cosemdepth.camera.Calibration`): frames are undistorted (:mod:`cosemdepth.data.undistorted`),
            the intrinsics are the undistorted camera's, items carry ``source_valid``; None: the 90-degree pinhole.
        Other arguments as :func:`cosemdepth.data.midair.dataset.open_midair`.
    """
    root = dataset_root(root)
    if not isinstance(size, FocalSize):
        as_size(size)  # (checked before the CSVs are read)
    wanted = set(("depth", "semantic") if modalities is None else modalities)
    unknown = wanted - {"depth", "semantic"}
    if unknown:
        raise ConfigError(f"modalities may only name 'depth' and 'semantic', got {sorted(unknown)}")
    folder, csvs = find_split_csvs(split_dir, split)
    trajectories = trajectories_from_csvs(
        root,
        folder,
        csvs,
        columns={
            "rgb": columns["rgb"],
            "depth": columns["depth"] if "depth" in wanted else None,
            "semantic": columns["semantic"] if "semantic" in wanted else None,
        },
        reset_rule=reset_rule,
        derive=derive,
    )
    check_modalities_consistent(trajectories, folder)

    def native() -> tuple[Size, float]:  # the first image's size, and the 90-degree camera's focal length there
        shape = image_size(trajectories[0].frame(0).rgb)
        return shape, float(midair_intrinsics(shape)[0])

    undistorter = None
    if calibration is not None:
        if augment:
            raise ConfigError("a calibrated (undistorted) dataset cannot be augmented")
        undistorter = undistorter_for(calibration, image_size(trajectories[0].frame(0).rgb), size)
        loader, intrinsics = UndistortedFrames(make_loader(None), undistorter), undistorter.intrinsics
    else:
        out_size = resolve_size(size, native)
        intrinsics_size = out_size if out_size is not None else image_size(trajectories[0].frame(0).rgb)
        loader, intrinsics = make_loader(out_size), midair_intrinsics(intrinsics_size)
    dataset = SequenceDataset(
        trajectories,
        loader,
        intrinsics,
        seq_len=seq_len,
        mode=mode or default_mode(split, seq_len),
        db_seq_len=db_seq_len,
        augment=resolve_augment(augment),
        seed=seed,
        name=name,
        size_at=lambda rule: resolve_size(rule, native) or native()[0],
    )
    dataset.calibration = None if undistorter is None else undistorter.info()
    return dataset
