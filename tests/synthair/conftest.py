"""Shared SynthAir fixtures: the world of seed 0 (built once per session) and small generated datasets."""

from __future__ import annotations

import pytest
import torch

SEED = 0


@pytest.fixture(scope="session")
def world():
    from cosemdepth.synthair.world import get_world

    torch.set_num_threads(1)
    return get_world(SEED)
