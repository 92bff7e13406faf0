"""The run folder: checks before anything is written, its creation, the saved config, and the best model.

Layout of ``RUN_DIR``::

    config.yaml          the resolved config of the run (written first; its presence marks a run folder)
    events.jsonl         the event log (cosemdepth.training.events)
    checkpoints/         ckpt-<step>/ folders (cosemdepth.training.checkpoint)
    best/                the best model so far: model.safetensors + config.json (loads with load_model) + metrics.json
    tensorboard/         TensorBoard event files
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any, Mapping

import torch
import yaml

from ..errors import ConfigError
from ..models.config import ModelConfig
from ..operating_point import OperatingPoint
from ..output_safety.atomic import _fsync_dir, atomic_write_text
from ..output_safety.outdir import Input, check_not_input, check_not_other_input, probe_writable
from .checkpoint import _jsonable, save_model_files
from .config import RunConfig, dump_config

CONFIG_NAME = "config.yaml"
EVENTS_NAME = "events.jsonl"
CHECKPOINTS_NAME = "checkpoints"
BEST_NAME = "best"
TENSORBOARD_NAME = "tensorboard"
BEST_METRICS_NAME = "metrics.json"


def run_inputs(config: RunConfig | None) -> list[Input]:
    """The input paths of a run (dataset roots and split folders), which the run folder must stay clear of."""
    if config is None:
        return []
    sources = [*config.data.train, *([config.data.val] if config.data.val is not None else [])]
    out = []
    for i, src in enumerate(sources):
        key = f"data.train.{i}" if i < len(config.data.train) else "data.val"
        out += [Input(f"{key}.{k}", v) for k, v in (("root", src.root), ("split_dir", src.split_dir)) if v]
    return out


def check_output_dir(run_dir: str | os.PathLike, config: RunConfig | None = None) -> bool:
    """Check that ``run_dir`` can hold a run, without writing anything. Returns True if it is an existing run
    (to be resumed). The output policy of :mod:`cosemdepth.output_safety.outdir`: the run folder is new, empty or a run (its
    ``config.yaml``), and never one of the run's inputs (``config``'s dataset roots and split folders), a folder
    holding one or a folder inside one.

    Raises:
        ConfigError: it is a file, a non-empty folder that is not a run, under a file, overlaps an input, or is not
            writable.
    """
    p = Path(run_dir)
    check_not_input(p, run_inputs(config), "--out run folder")
    check_not_other_input(p, command="train", what="--out run folder")  # no dataset, model... of another command
    if p.exists() or p.is_symlink():
        if not p.is_dir():
            raise ConfigError(
                f"--out {p}: exists and is not a folder (the run folder must be a new or empty "
                "folder, or a previous run to resume)"
            )
        if (p / CONFIG_NAME).is_file():
            _check_writable(p)
            return True
        if any(p.iterdir()):
            raise ConfigError(
                f"--out {p}: the folder is not empty and is not a cosemdepth run (no {CONFIG_NAME}); "
                "choose a new or empty folder"
            )
        _check_writable(p)
        return False
    parent = p.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"--out {p}: {parent} is a file, so the run folder cannot be created under it")
    _check_writable(parent, f"--out {p}: cannot create the run folder in {parent}")
    return False


def _check_writable(folder: Path, what: str | None = None) -> None:
    probe_writable(folder, f"{what or f'--out {folder}'}: the folder is not writable")


def create_run_dir(run_dir: str | os.PathLike, config: RunConfig) -> list[Path]:
    """Create ``run_dir`` (and missing parents) and write its ``config.yaml``. Returns the folders it created
    (deepest first), so that a failure right after can remove them.

    Raises:
        ConfigError: the folder cannot be created or written (nothing is left behind).
    """
    p = Path(run_dir)
    created = []
    q = p.absolute()
    while not q.exists():
        created.append(q)
        q = q.parent
    try:
        p.mkdir(parents=True, exist_ok=True)
        atomic_write_text(p / CONFIG_NAME, dump_config(config))
    except OSError as e:
        remove_created(created)
        raise ConfigError(f"--out {p}: cannot create the run folder ({e.strerror or e})") from None
    return created


def remove_created(created: list[Path]) -> None:
    """Remove folders made by :func:`create_run_dir` (deepest first) if they hold nothing but our config."""
    for d in created:
        try:
            cfg = d / CONFIG_NAME
            if cfg.exists() and not [x for x in d.iterdir() if x.name != CONFIG_NAME]:
                cfg.unlink()
            d.rmdir()
        except OSError:
            break


def read_run_config(run_dir: str | os.PathLike) -> dict[str, Any]:
    path = Path(run_dir) / CONFIG_NAME
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as e:
        raise ConfigError(f"{path}: cannot read the config of the run to resume ({e})") from e
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: not a run config")
    return data


def compare_configs(saved: Mapping[str, Any], new: RunConfig, run_dir: Path) -> list[str]:
    """Differences between the saved config of a run and the config it is resumed with, as ``key: old -> new``.

    Raises:
        ConfigError: the model differs (the checkpoints would not fit).
    """
    old = RunConfig.from_dict(saved).to_dict()
    cur = new.to_dict()
    if old["model"] != cur["model"]:
        raise ConfigError(
            f"--out {run_dir}: this run trains the model {old['model']}, but the config asks for "
            f"{cur['model']}; use a new --out folder for another model"
        )
    return [f"{k}: {o!r} -> {n!r}" for k, o, n in _diff(old, cur, "")]


def _diff(a: Any, b: Any, prefix: str):
    if isinstance(a, dict) and isinstance(b, dict):
        for k in a.keys() | b.keys():
            yield from _diff(a.get(k), b.get(k), f"{prefix}.{k}" if prefix else k)
    elif a != b:
        yield prefix, a, b


def save_best(
    run_dir: str | os.PathLike,
    model_state: Mapping[str, torch.Tensor],
    model_config: ModelConfig,
    metrics: Mapping[str, Any],
    source: Mapping[str, Any],
    operating_point: OperatingPoint | None = None,
) -> Path:
    """Replace ``RUN_DIR/best`` by a new model folder (with ``metrics.json``, and the run's ``operating_point`` in
    its ``config.json``), atomically: the new folder is fully written under a temporary name, then swapped in.
    :func:`recover_best` repairs an interrupted swap."""
    run_dir = Path(run_dir)
    best = run_dir / BEST_NAME
    tmp = run_dir / f".tmp-best-{os.getpid()}"
    old = run_dir / f".old-best-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        save_model_files(model_state, model_config, tmp, source, operating_point)
        atomic_write_text(tmp / BEST_METRICS_NAME, json.dumps(_jsonable(dict(metrics, **source)), indent=2) + "\n")
        if best.exists():
            os.replace(best, old)
        os.replace(tmp, best)
        _fsync_dir(run_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    shutil.rmtree(old, ignore_errors=True)
    return best


def recover_best(run_dir: str | os.PathLike) -> None:
    """After a crash: put back ``best`` from ``.old-best-*`` if the swap was interrupted, remove temporary folders."""
    run_dir = Path(run_dir)
    best = run_dir / BEST_NAME
    olds = sorted(run_dir.glob(".old-best-*"))
    if not best.exists() and olds:
        os.replace(olds[-1], best)
    for p in list(run_dir.glob(".old-best-*")) + list(run_dir.glob(".tmp-best-*")):
        shutil.rmtree(p, ignore_errors=True)


__all__ = [
    "BEST_NAME",
    "CHECKPOINTS_NAME",
    "CONFIG_NAME",
    "EVENTS_NAME",
    "TENSORBOARD_NAME",
    "check_output_dir",
    "compare_configs",
    "create_run_dir",
    "read_run_config",
    "recover_best",
    "remove_created",
    "save_best",
]
