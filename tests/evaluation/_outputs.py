"""Helpers for the tests of commands that write outputs: tiny models and datasets, an unwritable folder, leftovers.

Also module-scoped pytest fixtures for those tests; a test module uses them by importing them
(``from _outputs import _one_thread, data, model_dir``): ``_one_thread`` (autouse: the module runs with one torch
thread), ``model_dir`` (a tiny random model folder) and ``data`` (a tiny Mid-Air-format dataset).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "data"))
from _writers import write_midair  # noqa: E402

SIZE = 32


def tiny_model(path: Path, arch: str = "cosemdepth", levels: int = 2, seed: int = 0) -> Path:
    """A small randomly initialised model saved in our format."""
    import torch

    from cosemdepth import build_model, save_model

    torch.manual_seed(seed)
    save_model(build_model(arch=arch, levels=levels), path)
    return path


def tiny_midair(root: Path, trajectories=(0, 1), frames: int = 16, size: int = SIZE) -> Path:
    """A Mid-Air-format dataset whose trajectories are all in the test split (``root/splits``)."""
    from cosemdepth.data.midair.splits import generate_splits

    write_midair(root, {("Kite_training", "sunny"): list(trajectories)}, frames=frames, size=size)
    generate_splits(root, root / "splits", rule=lambda t: "test")
    return root


def leftovers(folder: Path) -> list[str]:
    """Hidden temporary files/folders our atomic writers leave behind if something goes wrong."""
    return sorted(
        p.name
        for p in folder.iterdir()
        if p.name.startswith(".") and (p.name.endswith((".partial", ".old", ".tmp")) or ".tmp" in p.name)
    )


def _writable(folder: Path) -> bool:
    try:
        (folder / ".probe").mkdir()
    except OSError:
        return False
    (folder / ".probe").rmdir()
    return True


@contextlib.contextmanager
def unwritable_folder(folder: Path):
    """``folder`` made unwritable: mode 0555, plus the immutable attribute when running as root (which ignores
    modes). Fails (does not skip) if neither works here."""
    folder.mkdir(parents=True, exist_ok=True)
    os.chmod(folder, 0o555)
    immutable = False
    if _writable(folder) and shutil.which("chattr"):
        immutable = subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode == 0
    try:
        assert not _writable(folder), f"cannot make {folder} unwritable on this machine (mode 0555, chattr +i)"
        yield folder
    finally:
        if immutable:
            subprocess.run(["chattr", "-i", str(folder)], check=True)
        os.chmod(folder, 0o755)


@contextlib.contextmanager
def torch_threads(n: int):
    """Run with ``n`` torch threads (tiny test tensors gain nothing from more, and a busy machine loses a lot)."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    with torch_threads(1):
        yield


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    return tiny_model(tmp_path_factory.mktemp("m") / "tiny")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return tiny_midair(tmp_path_factory.mktemp("d") / "midair")
