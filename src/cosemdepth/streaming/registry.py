"""The tables of sources and sinks: a source or a sink is one module and one entry here.

``SOURCES[name]`` is a source class with ``from_options(options, size)`` (its options value and the input size the
command asks for, see :func:`cosemdepth.data.frames.resolve_size`); ``SINKS[name]`` a sink class. Modules of this
package register the built-in ones when :mod:`cosemdepth.streaming` is imported; a plugin registers its own the same
way.
"""

from __future__ import annotations

from ..errors import ConfigError

#: Source name -> source class (``name``, ``describe``, ``frame_size``, ``batches``, ``close``, ``from_options``).
SOURCES: dict[str, type] = {}
#: Sink name -> sink class (``open``, ``__call__``, ``close``, ``abort``).
SINKS: dict[str, type] = {}


def _register(table: dict[str, type], what: str, name: str, cls: type, methods: tuple[str, ...]) -> type:
    if not isinstance(name, str) or not name:
        raise ConfigError(f"a {what} needs a non-empty name, got {name!r}")
    missing = [m for m in methods if not callable(getattr(cls, m, None))]
    if missing:
        raise TypeError(f"{what} {name!r}: {cls!r} lacks {', '.join(missing)}")
    table[name] = cls
    return cls


def register_source(name: str, cls: type) -> type:
    """Make ``cls`` the source ``name`` (replacing any of that name); returns ``cls``."""
    return _register(SOURCES, "source", name, cls, ("describe", "frame_size", "batches", "close"))


def register_sink(name: str, cls: type) -> type:
    """Make ``cls`` the sink ``name`` (replacing any of that name); returns ``cls``."""
    return _register(SINKS, "sink", name, cls, ("open", "__call__", "close", "abort"))


__all__ = ["SINKS", "SOURCES", "register_sink", "register_source"]
