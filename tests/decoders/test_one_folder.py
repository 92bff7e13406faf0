"""A decoder is one folder and one registration: its module, its task and its TF checkpoint names are defined in its
folder (``cosemdepth/decoders/<name>/``, or a plugin's folder), nothing of it is declared anywhere else in the
package, and the one ``register_decoder`` call in its ``__init__`` fills every table the package reads (the
decoders, the tasks, the architectures, the TF names)."""

from __future__ import annotations

import ast
import importlib
import sys
from pathlib import Path

import pytest

import cosemdepth
from cosemdepth.models import build_model, registry
from cosemdepth.models.registry import ARCHITECTURE_FIELDS, ARCHITECTURES, DECODERS, TASKS, TF_DECODERS
from cosemdepth.tasks import tasks_for

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import edge_decoder  # noqa: E402  (the plugin folder beside this file)

SRC = Path(cosemdepth.__file__).resolve().parent
#: decoder -> the package of its folder
FOLDERS = {"depth": "cosemdepth.decoders.depth", "semantic": "cosemdepth.decoders.semantic", "edge": "edge_decoder"}
#: the classes a decoder subclasses (its module, its levels, its task)
DECODER_BASES = {"PyramidDecoder", "PyramidLevel", "DecoderTask"}
#: the registration functions (the one a folder calls, and the store's own)
REGISTRATIONS = {"register_decoder", "register", "register_architecture", "register_task", "register_tf_decoder"}


def _inside(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


@pytest.mark.parametrize("name", FOLDERS)
def test_the_module_task_and_tf_names_of_a_decoder_are_defined_in_its_folder(name):
    task, module = TASKS[name], DECODERS[name]
    parts = [module, module.level_class, type(task)]
    if name in TF_DECODERS:
        parts.append(TF_DECODERS[name].config)
    assert [p.__module__ for p in parts if not _inside(p.__module__, FOLDERS[name])] == []
    assert task.name == name and task.decoder is module
    # its folder's package holds the registered objects under the names it exports
    folder = importlib.import_module(FOLDERS[name])
    assert module in vars(folder).values() and task in vars(folder).values()


def test_the_built_in_folders_and_their_architectures():
    assert list(DECODERS)[:2] == ["depth", "semantic"]  # the order of a model's <name>_decoder submodules
    assert set(TF_DECODERS) == {"depth", "semantic"}  # the edge decoder has no TF weights
    assert {a: ARCHITECTURES[a] for a in ("cosemdepth", "m4depth", "m4semantic", "cosemdepth-t")} == {
        "cosemdepth": ("depth", "semantic"),
        "m4depth": ("depth",),
        "m4semantic": ("semantic",),
        "cosemdepth-t": ("depth", "semantic"),
    }
    assert dict(ARCHITECTURE_FIELDS["cosemdepth-t"]) == {"semantic_time": "own"} and "cosemdepth" not in (
        ARCHITECTURE_FIELDS
    )
    assert ARCHITECTURES[edge_decoder.ARCH] == ("depth", "edge")


def _calls_and_classes(path: Path) -> tuple[list[str], list[str]]:
    """The registration calls of a source file and the classes it defines on a decoder base class."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    calls, classes = [], []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            called = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
            # ``x.register(...)`` on another library's object (rosbags' typestore) is not ours: the store's plain
            # ``register`` counts called by name or on the registry module
            foreign = called == "register" and isinstance(f, ast.Attribute)
            foreign = foreign and not (isinstance(f.value, ast.Name) and f.value.id == "registry")
            if called in REGISTRATIONS and not foreign:
                calls.append(called)
        elif isinstance(node, ast.ClassDef):
            bases = {b.id if isinstance(b, ast.Name) else getattr(b, "attr", "") for b in node.bases}
            if bases & DECODER_BASES:
                classes.append(node.name)
    return calls, classes


def test_nothing_of_a_decoder_is_declared_outside_its_folder():
    """Across the package: each built-in folder's ``__init__`` makes one registration call, no other module makes
    one (besides the registration functions themselves), and the classes of decoders and tasks are defined in the
    decoder folders only."""
    calls, classes = {}, {}
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        c, k = _calls_and_classes(path)
        if c:
            calls[rel] = c
        if k:
            classes[rel] = k
    # the registration functions: register -> register_architecture, register_decoder -> register
    machinery = ("models/registry.py", "tasks/base.py")
    assert {f: c for f, c in calls.items() if f not in machinery} == {
        "decoders/depth/__init__.py": ["register_decoder"],
        "decoders/semantic/__init__.py": ["register_decoder"],
    }
    assert classes == {
        "decoders/depth/decoder.py": ["DepthLevel", "DepthDecoder"],
        "decoders/depth/task.py": ["DepthTask"],
        "decoders/semantic/decoder.py": ["SemanticLevel", "SemanticDecoder"],
        "decoders/semantic/task.py": ["SemanticTask"],
    }
    assert sorted(p.name for p in (SRC / "decoders" / "depth").glob("*.py")) == sorted(
        p.name for p in (SRC / "decoders" / "semantic").glob("*.py")
    )  # the same shape: __init__, decoder, task, tf_names
    plugin_calls = {
        p.name: _calls_and_classes(p)[0]
        for p in sorted((HERE / "edge_decoder").glob("*.py"))
        if _calls_and_classes(p)[0]
    }
    assert plugin_calls == {"__init__.py": ["register_decoder"]}


def test_the_one_registration_fills_every_table(monkeypatch):
    """The edge plugin's folder unregistered, then its ``__init__`` run again: its one call makes the decoder, its
    task and its architecture known, and a model of that architecture is built with the decoder's weights."""
    registry.load_builtin()
    for table in ("_entries", "_architectures", "_architecture_fields"):  # restored after the test
        monkeypatch.setattr(registry, table, dict(getattr(registry, table)))
    registry.unregister("edge")
    assert "edge" not in DECODERS and "edge" not in TASKS and edge_decoder.ARCH not in ARCHITECTURES
    importlib.reload(edge_decoder)
    assert DECODERS["edge"] is edge_decoder.EdgeDecoder and TASKS["edge"] is edge_decoder.EDGE
    assert ARCHITECTURES[edge_decoder.ARCH] == ("depth", "edge") and "edge" not in TF_DECODERS
    model = build_model(arch=edge_decoder.ARCH, levels=2)
    assert [t.name for t in tasks_for(model.config)] == ["depth", "edge"]
    assert any(k.startswith("edge_decoder.levels.1.refiner.") for k in model.state_dict())
