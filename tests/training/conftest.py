"""Fixtures of the training tests: a tiny, fast run configuration on the in-memory toy dataset."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import pytest

from cosemdepth.training.config import RunConfig, set_key

SRC = Path(__file__).resolve().parents[2] / "src"

#: A run of a few seconds: 3 levels, 16x16 frames, 8 toy sequences, batch 2 (4 steps per epoch), one CPU thread.
TINY = {
    "model.levels": 3,
    "data.train.0.name": "toy",
    "data.train.0.options": {"length": 8},
    "data.size": 16,
    "data.num_workers": 0,
    "train.batch_size": 2,
    "train.epochs": 2,
    "train.num_threads": 1,
    "train.log_every": 1,
    "train.image_every": 0,
    "train.progress": False,
    "train.checkpoint_every": 2,
    "train.validate_every_epochs": 0,
}


def tiny_dict(**overrides: Any) -> dict:
    """The nested config dict of :data:`TINY` with ``key__sub=value`` overrides (``train__lr=3e-4``)."""
    d: dict = {}
    for k, v in TINY.items():
        set_key(d, k, v)
    for k, v in overrides.items():
        set_key(d, k.replace("__", "."), v)
    return d


@pytest.fixture
def tiny_config():
    """``tiny_config(train__max_steps=6, ...) -> RunConfig``."""

    def make(**overrides: Any) -> RunConfig:
        return RunConfig.from_dict(tiny_dict(**overrides))

    return make


def cli_args(**overrides: Any) -> list[str]:
    """``--set`` arguments reproducing :data:`TINY` plus overrides, for the command line."""
    import json

    out = []
    merged = dict(TINY)
    merged.update({k.replace("__", "."): v for k, v in overrides.items()})
    for k, v in merged.items():
        out += ["--set", f"{k}={json.dumps(v) if isinstance(v, (dict, list, bool)) else v}"]
    return out


@pytest.fixture
def cli_env() -> dict:
    """Environment for running ``python -m cosemdepth`` from the source tree in a subprocess, single-threaded."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(SRC) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["OMP_NUM_THREADS"] = "1"
    env["MKL_NUM_THREADS"] = "1"
    env.pop("COSEMDEPTH_DEBUG_CHECKPOINT_DELAY", None)
    return env


@pytest.fixture
def python() -> str:
    return sys.executable


@pytest.fixture
def tiny_cli():
    """``tiny_cli(train__max_steps=6) -> ["--set", "model.levels=3", ...]``."""
    return cli_args


@pytest.fixture(autouse=True)
def _one_thread():
    """One CPU thread: on a small shared machine torch's thread pool is many times slower than a single thread."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
