"""The decoder registry: each decoder once, by name, with everything the package needs to know of it, and the
architectures (the shared encoder plus registered decoders, in order).

A decoder's entry (:class:`DecoderEntry`) holds its module class (a
:class:`~cosemdepth.models.pyramid.PyramidDecoder` subclass, built as the submodule ``<name>_decoder``, so its
weights are ``<name>_decoder.*`` in the state dict), its task (a :class:`~cosemdepth.tasks.DecoderTask`: loss,
metrics, ground truth, files, pictures) and its names in the official TF checkpoints (a
:class:`~cosemdepth.checkpoints.tf_decoders.TfDecoder`, or None). The tables the rest of the package reads are views
of these entries: :data:`DECODERS` (name -> module class), :data:`TASKS` (name -> task), :data:`TF_DECODERS`
(name -> TF names), :data:`ARCHITECTURES` (architecture -> decoder names) and :data:`ARCHITECTURE_FIELDS`
(architecture -> the model-config fields it fixes). One call of :func:`cosemdepth.tasks.register_decoder`, in the
decoder's folder, fills all of them.

This module is in the lowest layer (it imports only :mod:`cosemdepth.errors`), so the model config, the models, the
conversion and the tasks all read the same tables, and none of them imports a decoder. The built-in decoders are
the folders of the ``cosemdepth.decoders`` package (:data:`BUILTIN_DECODERS`), a layer above the tasks: the first
read of any table imports that package by name (as :mod:`cosemdepth.plugins` imports the plugins), which registers
them; further decoders register the same way from plugins.
"""

from __future__ import annotations

import importlib
import threading
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Mapping, Optional

from ..errors import ConfigError

#: The package whose import registers the built-in decoders (one folder each, see docs/architecture.md).
BUILTIN_DECODERS = "cosemdepth.decoders"


@dataclass(frozen=True)
class DecoderEntry:
    """One registered decoder.

    Attributes:
        name: its registered name (the submodule ``<name>_decoder`` of a model).
        module: its :class:`~cosemdepth.models.pyramid.PyramidDecoder` subclass (built from a ``ModelConfig``).
        task: its :class:`~cosemdepth.tasks.DecoderTask`, or None for a decoder registered for the model alone.
        tf: its names in the official TF checkpoints (:class:`~cosemdepth.checkpoints.tf_decoders.TfDecoder`), or
            None: the TF checkpoints do not hold it.
    """

    name: str
    module: type
    task: Any = None
    tf: Any = None


_entries: dict[str, DecoderEntry] = {}
_architectures: dict[str, tuple[str, ...]] = {}
_architecture_fields: dict[str, dict[str, Any]] = {}
_lock = threading.RLock()
_builtin = "no"  # "no", "loading", "yes"


def load_builtin() -> None:
    """Import :data:`BUILTIN_DECODERS` once (each of its folders registers its decoder). A read of a table while
    that import runs (the registrations themselves) sees the entries made so far."""
    global _builtin
    if _builtin == "yes":
        return
    with _lock:  # re-entrant: the loading thread's own reads pass, other threads wait for the whole import
        if _builtin != "no":
            return
        _builtin = "loading"
        try:
            importlib.import_module(BUILTIN_DECODERS)
        except BaseException:
            _builtin = "no"
            raise
        _builtin = "yes"


class Table(Mapping):
    """A read-only view of the registry (a table of the module docstring); reading it loads the built-in decoders
    first (:func:`load_builtin`). Entries are added by the registration functions only."""

    def __init__(self, read: Callable[[], Mapping[str, Any]], what: str) -> None:
        self._read = read
        self._what = what

    def _data(self) -> Mapping[str, Any]:
        load_builtin()
        return self._read()

    def __getitem__(self, key: str) -> Any:
        return self._data()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(list(self._data()))

    def __len__(self) -> int:
        return len(self._data())

    def __contains__(self, key: object) -> bool:
        return key in self._data()

    def __repr__(self) -> str:
        return f"<{self._what}: {dict(self._data())!r}>"


#: Decoder name -> its module class (:class:`~cosemdepth.models.pyramid.PyramidDecoder` subclass), in registration
#: order (the order of the ``<name>_decoder`` submodules of a model).
DECODERS: Mapping[str, type] = Table(lambda: {n: e.module for n, e in _entries.items()}, "decoders")
#: Decoder name -> its task (:class:`~cosemdepth.tasks.DecoderTask`), for the decoders registered with one.
TASKS: Mapping[str, Any] = Table(
    lambda: {n: e.task for n, e in _entries.items() if e.task is not None}, "decoder tasks"
)
#: Decoder name -> its names in the official TF checkpoints, for the decoders those checkpoints hold, in
#: registration order (the order the conversion reads their config fields).
TF_DECODERS: Mapping[str, Any] = Table(
    lambda: {n: e.tf for n, e in _entries.items() if e.tf is not None}, "TF checkpoint decoders"
)
#: Architecture -> the decoders it puts on the shared encoder (registered names, in order).
ARCHITECTURES: Mapping[str, tuple[str, ...]] = Table(lambda: _architectures, "architectures")
#: Architecture -> the ``ModelConfig`` fields it fixes (e.g. ``cosemdepth-t``: ``semantic_time="own"``); a field
#: left None in a config takes the value, another value is refused.
ARCHITECTURE_FIELDS: Mapping[str, Mapping[str, Any]] = Table(lambda: _architecture_fields, "architecture fields")


def register(
    name: str,
    module: type,
    *,
    task: Any = None,
    tf: Any = None,
    architectures: Optional[Mapping[str, Any]] = None,
) -> DecoderEntry:
    """Register decoder ``name`` (its module class, task and TF names), then each of ``architectures``:
    architecture -> decoder names, or ``(decoder names, fixed config fields)`` (see :func:`register_architecture`).

    The typed front is :func:`cosemdepth.tasks.register_decoder` (it checks the classes); this is the store."""
    if not name or not isinstance(name, str) or not name.isidentifier():
        raise ConfigError(f"a decoder name must be an identifier (its weights are <name>_decoder.*), got {name!r}")
    if not isinstance(module, type) or not getattr(module, "head", ""):
        raise TypeError(f"decoder {name!r} must be a decoder class with a head, got {module!r}")
    load_builtin()  # the built-in decoders first, whoever registers first
    with _lock:
        entry = _entries[name] = DecoderEntry(name, module, task, tf)
        for arch, spec in (architectures or {}).items():
            decoders, fields = (spec, None) if _is_names(spec) else spec
            register_architecture(arch, tuple(decoders), fields)
    return entry


def _is_names(spec: Any) -> bool:
    return all(isinstance(s, str) for s in spec)


def register_architecture(name: str, decoders: tuple[str, ...], fields: Optional[Mapping[str, Any]] = None) -> None:
    """Make ``ModelConfig(arch=name)`` the shared encoder plus ``decoders`` (registered names, in order), with the
    config ``fields`` it fixes (None: none)."""
    load_builtin()
    with _lock:
        unknown = [d for d in decoders if d not in _entries]
        if unknown or not decoders:
            raise ConfigError(f"architecture {name!r}: unknown decoder(s) {unknown}; registered: {sorted(_entries)}")
        heads = [_entries[d].module.head for d in decoders]
        states = [s for d in decoders for s in _entries[d].module.state_names]
        if len(set(heads)) != len(heads) or len(set(states)) != len(states):
            raise ConfigError(f"architecture {name!r}: decoders {decoders} share a head or state name")
        _architectures[name] = tuple(decoders)
        if fields:
            _architecture_fields[name] = dict(fields)
        else:
            _architecture_fields.pop(name, None)


def unregister(name: str) -> None:
    """Remove decoder ``name`` and the architectures that use it (a decoder registered for a test)."""
    with _lock:
        _entries.pop(name, None)
        for arch in [a for a, d in _architectures.items() if name in d]:
            unregister_architecture(arch)


def unregister_architecture(name: str) -> None:
    """Remove architecture ``name``."""
    with _lock:
        _architectures.pop(name, None)
        _architecture_fields.pop(name, None)


def architecture_of(decoders: Any) -> Optional[str]:
    """The architecture made of exactly ``decoders`` (in any order) that fixes no config field, else the first one
    made of them; None when none is."""
    want = set(decoders)
    found = [a for a, d in ARCHITECTURES.items() if set(d) == want]
    return next((a for a in found if a not in ARCHITECTURE_FIELDS), found[0] if found else None)


__all__ = [
    "ARCHITECTURES",
    "ARCHITECTURE_FIELDS",
    "BUILTIN_DECODERS",
    "DECODERS",
    "DecoderEntry",
    "TASKS",
    "TF_DECODERS",
    "Table",
    "architecture_of",
    "load_builtin",
    "register",
    "register_architecture",
    "unregister",
    "unregister_architecture",
]
