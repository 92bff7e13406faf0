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
    torch.manual_seed(0)
    yield
