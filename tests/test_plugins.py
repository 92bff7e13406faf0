"""Plugins: the modules named in COSEMDEPTH_PLUGINS and the cosemdepth.decoders entry points are imported once;
one that cannot be imported is a ConfigError naming it."""

from __future__ import annotations

import sys
from types import SimpleNamespace

import pytest

from cosemdepth import plugins
from cosemdepth.errors import ConfigError


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    monkeypatch.setattr(plugins, "_loaded", set())
    monkeypatch.setattr(plugins, "entry_points", lambda group: [])
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("plug_a", "plug_b"):
        (tmp_path / f"{name}.py").write_text(f"NAME = {name!r}\n")
        sys.modules.pop(name, None)
    yield
    for name in ("plug_a", "plug_b"):
        sys.modules.pop(name, None)


def test_the_environment_names_modules_imported_once_in_order(fresh):
    env = {plugins.PLUGINS_ENV: " plug_a, ,plug_b "}
    assert plugins.plugin_modules(env) == ["plug_a", "plug_b"]
    assert plugins.load_plugins(env) == ["plug_a", "plug_b"]
    assert "plug_a" in sys.modules and "plug_b" in sys.modules
    assert plugins.load_plugins(env) == []  # a second call imports nothing again


def test_entry_points_are_loaded(fresh, monkeypatch):
    loaded = []
    point = SimpleNamespace(name="edge", value="plug_a", load=lambda: loaded.append("plug_a"))
    monkeypatch.setattr(plugins, "entry_points", lambda group: [point] if group == plugins.ENTRY_POINT_GROUP else [])
    assert plugins.load_plugins({}) == ["plug_a"]
    assert plugins.load_plugins({}) == [] and loaded == ["plug_a"]


def test_a_missing_module_is_a_config_error_naming_it(fresh):
    with pytest.raises(ConfigError, match=rf"{plugins.PLUGINS_ENV}.*'no_such_plugin_here'"):
        plugins.load_plugins({plugins.PLUGINS_ENV: "no_such_plugin_here"})
