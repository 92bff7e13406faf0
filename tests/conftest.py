"""Shared test fixtures.

The TensorFlow reference fixtures: ``tests/fixtures/tfref-64x96`` (in the repository, in its compact form: the
checkpoint's seeded weights are rebuilt once per session and checked against TensorFlow's SHA-256) always, and the
larger ``tfref-s128`` of ``../shared/fixtures`` beside the repository (or wherever ``COSEMDEPTH_FIXTURES`` points) as
an extra check of every test that reads one. Outside CI a missing shared fixture leaves that extra check out: its
tests are not collected (pytest's header says so, a line ``-q`` hides); in CI (``CI=true``) it is a failure.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

REPO_ROOT = Path(__file__).resolve().parents[1]


def fixtures_dir() -> Path:
    env = os.environ.get("COSEMDEPTH_FIXTURES")
    return Path(env) if env else REPO_ROOT.parent / "shared" / "fixtures"


#: The fixture in the repository (5 levels, 7 classes, 4 frames of 64x96, batch 2; its README says how it was made).
IN_REPO_TFREF = REPO_ROOT / "tests" / "fixtures" / "tfref-64x96"
SHARED_TFREF = "tfref-s128"


def _shared_tfref_found() -> bool:
    return (fixtures_dir() / SHARED_TFREF / "reference.npz").is_file()


def tfref_params() -> list[str]:
    """The fixtures ``tfref_dir`` runs on: the repository's, and the shared one when it is beside the repository;
    CI always takes the shared one (absent there, its tests fail)."""
    run_shared = _shared_tfref_found() or os.environ.get("CI") == "true"
    return [IN_REPO_TFREF.name, *([SHARED_TFREF] if run_shared else [])]


def pytest_report_header(config) -> str | None:
    if SHARED_TFREF in tfref_params():
        return None
    return (
        f"the extra check on the shared TensorFlow fixture is not run: {fixtures_dir() / SHARED_TFREF} not found "
        f"(put the project's shared/ folder beside the repository or set COSEMDEPTH_FIXTURES)"
    )


@pytest.fixture(scope="session", params=tfref_params())
def tfref_dir(request, tmp_path_factory) -> Path:
    """A folder with a TensorFlow reference fixture: ``ckpt/`` (the checkpoint the authors' code wrote),
    ``reference.npz``, ``weights.json``, ``meta.json``. Every test that takes it runs on each fixture of
    :func:`tfref_params`."""
    from tfref_fixture import open_fixture

    if request.param == IN_REPO_TFREF.name:
        return open_fixture(IN_REPO_TFREF, tmp_path_factory.mktemp("tfref"))
    d = fixtures_dir() / SHARED_TFREF
    if not _shared_tfref_found():
        pytest.fail(
            f"the extra check on the shared TensorFlow fixture: {d} not found. Put the project's shared/ folder "
            f"beside the repository or set COSEMDEPTH_FIXTURES to the folder that holds {SHARED_TFREF}/."
        )
    return d


@pytest.fixture(autouse=True)
def _deterministic():
    """Every test starts from seed 0 and leaves torch's thread count as it found it (an in-process trainer or CLI
    call sets it; the float32 rounding of a convolution, and so of the tests that follow, depends on it)."""
    torch.manual_seed(0)
    threads = torch.get_num_threads()
    yield
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)


@pytest.fixture
def bf16_cpu():
    """bfloat16 convolutions on the CPU for one test: oneDNN's where it has them (AVX-512 and up); on a CPU where it
    has none (AVX2 only), the test runs with oneDNN switched off, so that PyTorch's own (slow) kernels compute the
    same bf16 program and its numerics are still checked. Yields whether oneDNN's kernels are used. (The product
    itself refuses bf16 on such a CPU with one line: tests/test_devices.py.)"""
    from cosemdepth.devices import bf16_convolutions

    if bf16_convolutions("cpu"):
        yield True
    else:
        with torch.backends.mkldnn.flags(enabled=False):
            yield False


class _FullDiskFile:
    """A file opened for writing on a simulated full disk: ``write`` raises ENOSPC once ``room`` bytes are used (a
    partial write first, as a real full disk does)."""

    def __init__(self, f, disk):
        self._f, self._disk = f, disk

    def write(self, data):
        import errno

        n = len(data)
        if self._disk.room < n:
            self._f.write(data[: max(self._disk.room, 0)])
            self._disk.room = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._disk.room -= n
        return self._f.write(data)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()
        return False

    def __iter__(self):
        return iter(self._f)

    def __getattr__(self, name):
        return getattr(self._f, name)


class FullDisk:
    """``builtins.open`` patched so that the files opened for writing under ``folder`` share ``room`` bytes, after
    which every write raises ``OSError(ENOSPC)`` (what every Python-level writer of the package goes through)."""

    def __init__(self, monkeypatch, folder: Path, room: int = 0):
        import builtins

        self.folder, self.room = Path(folder).resolve(), room
        real_open = builtins.open

        def patched(file, mode="r", *args, **kwargs):
            f = real_open(file, mode, *args, **kwargs)
            writing = any(c in mode for c in "wax+")
            if writing and isinstance(file, (str, os.PathLike)):
                path = Path(os.fsdecode(file)).resolve()
                if path == self.folder or self.folder in path.parents:
                    return _FullDiskFile(f, self)
            return f

        monkeypatch.setattr(builtins, "open", patched)


@pytest.fixture
def full_disk(monkeypatch):
    """``full_disk(folder, room=0)``: simulate a disk with ``room`` bytes left for the writes under ``folder``."""
    return lambda folder, room=0: FullDisk(monkeypatch, folder, room)
