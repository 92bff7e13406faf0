"""Shared test fixtures.

The TensorFlow reference fixture lives in ``../shared/fixtures`` beside the repository (or wherever
``COSEMDEPTH_FIXTURES`` points). Outside CI a missing fixture skips the tests that need it, with a message; in CI
(``CI=true``) it is a failure.
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


@pytest.fixture(scope="session")
def tfref_dir() -> Path:
    d = fixtures_dir() / "tfref-s128"
    if not (d / "reference.npz").is_file():
        msg = (
            f"TensorFlow reference fixture not found at {d}. Put the project's shared/ folder beside the "
            "repository or set COSEMDEPTH_FIXTURES to the folder that holds tfref-s128/."
        )
        pytest.fail(msg)  # the fidelity oracle is part of the project: never silently skipped
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
