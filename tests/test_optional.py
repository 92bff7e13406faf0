"""The optional dependencies (cosemdepth.optional): the table agrees with pyproject.toml's extras, and a missing
package is one line naming what needs it and how to install it."""

import re
from pathlib import Path

import pytest
import tomllib

from cosemdepth.errors import ConfigError
from cosemdepth.optional import OPTIONAL_PACKAGES, install_hint, missing_package, require

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


def test_every_optional_package_is_in_the_extra_it_names():
    extras = tomllib.loads(PYPROJECT.read_text())["project"]["optional-dependencies"]
    for module, (package, extra) in OPTIONAL_PACKAGES.items():
        names = [re.split(r"[<>=!~ \[]", req, maxsplit=1)[0] for req in extras[extra]]
        assert package in names, f"{module}: {package} is not in the [{extra}] extra {extras[extra]}"


def test_require_imports_or_says_what_to_install(monkeypatch):
    import json

    assert require("json", "x") is json
    monkeypatch.setitem(__import__("sys").modules, "onnx", None)  # as if onnx were not installed
    with pytest.raises(ConfigError) as e:
        require("onnx", "export")
    assert str(e.value) == (
        "export needs the Python package onnx, which is not installed; "
        "pip install 'cosemdepth[export]' (or pip install onnx)"
    )
    assert install_hint("yaml") == "pip install yaml"


def test_missing_package_finds_the_import_error_behind_another_and_leaves_our_own_bugs_alone():
    try:
        try:
            import rerun_not_installed_here  # noqa: F401
        except ImportError as inner:
            raise RuntimeError("while opening the recording") from inner
    except RuntimeError as outer:
        assert missing_package(outer) == (
            "this command needs the Python package rerun_not_installed_here, which is "
            "not installed; pip install rerun_not_installed_here"
        )
    err = ModuleNotFoundError("No module named 'cosemdepth.nope'", name="cosemdepth.nope")
    assert missing_package(err) is None  # a module of this package failing to import is a bug: traceback kept
    assert missing_package(ValueError("x")) is None
