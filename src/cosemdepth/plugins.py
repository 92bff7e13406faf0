"""Plugins: modules (a decoder's folder, as a package) that register further decoders with their tasks
(:func:`~cosemdepth.tasks.register_decoder`) so that the command line trains, evaluates, predicts and exports them
like the built-in ones.

A plugin is imported by :func:`load_plugins` (the CLI calls it before reading its arguments) when it is named in the
``COSEMDEPTH_PLUGINS`` environment variable (module names separated by commas) or when an installed distribution
declares it in the ``cosemdepth.decoders`` entry-point group.
"""

from __future__ import annotations

import importlib
import os
from importlib.metadata import entry_points
from typing import Mapping

from .errors import ConfigError

#: The environment variable naming plugin modules (comma-separated).
PLUGINS_ENV = "COSEMDEPTH_PLUGINS"
#: The entry-point group of installed plugins (each entry point names a module, or an object in it, to import).
ENTRY_POINT_GROUP = "cosemdepth.decoders"

_loaded: set[str] = set()


def plugin_modules(environ: Mapping[str, str] | None = None) -> list[str]:
    """The modules named in :data:`PLUGINS_ENV`, in order, without empty entries."""
    value = (os.environ if environ is None else environ).get(PLUGINS_ENV, "")
    return [m.strip() for m in value.split(",") if m.strip()]


def load_plugins(environ: Mapping[str, str] | None = None) -> list[str]:
    """Import the plugin modules of :data:`PLUGINS_ENV` and of the :data:`ENTRY_POINT_GROUP` entry points (each
    once per process); return the names imported by this call. A module that cannot be imported is a
    :class:`ConfigError` naming it and where it was named."""
    done = []
    for name in plugin_modules(environ):
        if name in _loaded:
            continue
        try:
            importlib.import_module(name)
        except ImportError as e:
            raise ConfigError(f"{PLUGINS_ENV}: cannot import plugin module {name!r}: {e}") from None
        _loaded.add(name)
        done.append(name)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        key = f"entry point {ep.name} = {ep.value}"
        if key in _loaded:
            continue
        try:
            ep.load()
        except ImportError as e:
            raise ConfigError(f"{ENTRY_POINT_GROUP} {key}: cannot import it: {e}") from None
        _loaded.add(key)
        done.append(ep.value)
    return done


__all__ = ["ENTRY_POINT_GROUP", "PLUGINS_ENV", "load_plugins", "plugin_modules"]
