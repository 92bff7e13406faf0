"""The decoder registry: its tables find the built-in decoders whichever module a process imports first (the models
never import a decoder folder; the first read of a table registers them), and its architecture rules."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cosemdepth.errors import ConfigError
from cosemdepth.models import registry
from cosemdepth.models.config import ModelConfig
from cosemdepth.models.registry import ARCHITECTURE_FIELDS, ARCHITECTURES, DECODERS, architecture_of

SRC = Path(__file__).resolve().parents[2] / "src"


def _fresh(code: str) -> str:
    """Run ``code`` in a fresh interpreter with this checkout's package; its stdout."""
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        env={**os.environ, "PYTHONPATH": str(SRC), "OMP_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_a_model_config_finds_the_built_in_decoders_without_importing_them():
    out = _fresh(
        """
        import sys
        from cosemdepth.models import build_model
        from cosemdepth.models.config import ModelConfig
        assert "cosemdepth.decoders" not in sys.modules  # the models import no decoder folder
        cfg = ModelConfig(arch="cosemdepth-t", levels=2)  # the first read of a table registers them
        assert "cosemdepth.decoders" in sys.modules and cfg.semantic_time == "own"
        print(sorted({k.split(".")[0] for k in build_model(cfg).state_dict()}))
        """
    )
    assert out == "['depth_decoder', 'encoder', 'semantic_decoder']"


def test_the_conversion_s_table_alone_finds_them():
    out = _fresh(
        """
        from cosemdepth.checkpoints.tf_decoders import TF_DECODERS
        print([(n, t.refiner) for n, t in TF_DECODERS.items()])
        """
    )
    assert out == "[('depth', 'disp_refiner'), ('semantic', 'semantic_refiner')]"


@pytest.fixture
def scratch(monkeypatch):
    """The registry's store (the built-in decoders in it), restored after the test."""
    registry.load_builtin()
    for table in ("_entries", "_architectures", "_architecture_fields"):
        monkeypatch.setattr(registry, table, dict(getattr(registry, table)))


def test_an_architecture_names_registered_decoders_with_distinct_heads_and_states(scratch):
    with pytest.raises(ConfigError, match=r"unknown decoder\(s\) \['nope'\]"):
        registry.register_architecture("bad", ("depth", "nope"))
    with pytest.raises(ConfigError, match="share a head or state name"):
        registry.register_architecture("twice", ("depth", "depth"))
    with pytest.raises(TypeError, match="decoder class with a head"):
        registry.register("thing", object)
    with pytest.raises(ConfigError, match="identifier"):
        registry.register("not a name", DECODERS["depth"])
    assert "bad" not in ARCHITECTURES and "twice" not in ARCHITECTURES


def test_fixed_fields_and_the_plain_architecture_of_a_decoder_set(scratch):
    # cosemdepth-t fixes semantic_time; the plain architecture of the same decoders is cosemdepth, whatever the order
    registry.register_architecture("semdepth-t", ("semantic", "depth"), {"semantic_time": "gt"})
    assert architecture_of(["semantic", "depth"]) == "cosemdepth" and architecture_of(["edge"]) is None
    assert ModelConfig(arch="semdepth-t").semantic_time == "gt"
    with pytest.raises(ConfigError, match="has semantic_time 'gt', got 'own'; use arch 'cosemdepth'"):
        ModelConfig(arch="semdepth-t", semantic_time="own")
    registry.unregister_architecture("semdepth-t")
    assert "semdepth-t" not in ARCHITECTURES and "semdepth-t" not in ARCHITECTURE_FIELDS
    # an architecture that fixes fields is still found when it is the only one of its decoders
    registry.register_architecture("solo-t", ("semantic",), {"semantic_time": "gt"})
    registry.unregister_architecture("m4semantic")
    assert architecture_of(["semantic"]) == "solo-t"
