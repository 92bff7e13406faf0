"""The one typed coercer of the configs: a nested mapping (a model folder's ``config.json``, a YAML run config, the
``--set KEY=VALUE`` overrides) into a dataclass, each value converted to its field's type.

:func:`from_mapping` builds a dataclass (missing keys take the field defaults, unknown keys are refused);
:func:`coerce` converts one value to one type. The types understood are ``bool``, ``int``, ``float``, ``str``,
``Literal[...]``, ``Optional[X]`` / ``X | None``, ``Union[...]``, ``tuple[X, ...]``, ``tuple[X, Y]``, ``list[X]``,
``dict`` and nested dataclasses. Strings convert as a command line spells them (``"3e-4"`` is a float, ``"yes"`` is
true), and a scalar where a ``tuple[X, ...]`` / ``list[X]`` is expected is a list of one. Every error is one line,
``KEY: what is wrong`` (a :class:`~cosemdepth.errors.ConfigError`), with ``KEY`` dotted from the top
(``data.train[0].weight``).

This sits at the bottom of the package (it imports only :mod:`cosemdepth.errors`): the model config and the run
config both build through it.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any, Literal, Mapping, Union

from .errors import ConfigError

#: The spellings of true and false a string may use (case-insensitive), as YAML 1.1 and command lines do.
TRUE = ("true", "yes", "on", "1")
FALSE = ("false", "no", "off", "0")


def from_mapping(cls: type, d: Any, prefix: str = "") -> Any:
    """Build dataclass ``cls`` from the mapping ``d`` (None: every default), converting values to the field types.

    ``prefix`` is the dotted key of ``d`` for error messages (``""`` at the top, ``"model"`` for a model config).
    A :class:`ConfigError` raised by ``cls`` itself (its ``__post_init__`` checks) that does not name its section
    gets ``prefix: `` in front.
    """
    what = prefix or "the config"
    if d is None:
        d = {}
    if not isinstance(d, Mapping):
        raise ConfigError(f"{what} must be a mapping of keys to values, got {type(d).__name__} {d!r}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    unknown = [k for k in d if k not in names]
    if unknown:
        keys = ", ".join(repr(join(prefix, str(k))) for k in unknown)
        raise ConfigError(
            f"unknown config key{'s' if len(unknown) > 1 else ''} {keys}; valid keys"
            f"{' of ' + repr(prefix) if prefix else ''}: {names}"
        )
    kwargs = {k: coerce(v, hints[k], join(prefix, k)) for k, v in d.items()}
    try:
        return cls(**kwargs)
    except ConfigError as e:
        section = prefix.split(".")[0].split("[")[0]
        if section and not str(e).startswith(section):
            raise ConfigError(f"{prefix}: {e}") from None
        raise


def join(prefix: str, key: str) -> str:
    """``prefix.key`` (``key`` alone at the top)."""
    return f"{prefix}.{key}" if prefix else key


def coerce(value: Any, tp: Any, key: str) -> Any:
    """``value`` converted to the type ``tp``; :class:`ConfigError` ``"KEY: expected ..., got VALUE"`` if it cannot
    be. :class:`TypeError` for a type this module does not understand (a programming error, not a user's)."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (Union, types.UnionType):
        return _union(value, args, key)
    if origin is Literal:
        if any(value == a and type(value) is type(a) for a in args):
            return value
        if isinstance(value, bool):  # YAML 1.1 reads off/no/on/yes as booleans: the one choice so spelt
            spelt = [a for a in args if isinstance(a, str) and a.lower() in (TRUE if value else FALSE)]
            if len(spelt) == 1:
                return spelt[0]
        raise ConfigError(f"{key}: expected one of {', '.join(map(repr, args))}, got {value!r}")
    if value is None:
        raise ConfigError(f"{key}: a value is required, got null")
    if dataclasses.is_dataclass(tp):
        return value if isinstance(value, tp) else from_mapping(tp, value, key)
    if origin in (tuple, list):
        return _sequence(value, origin, args, key)
    if tp is dict or origin is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(f"{key}: expected a mapping, got {value!r}")
        return dict(value)
    if tp is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.strip().lower() in TRUE + FALSE:
            return value.strip().lower() in TRUE
        raise ConfigError(f"{key}: expected true or false, got {value!r}")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        if isinstance(value, str):
            try:
                return int(value.strip())
            except ValueError:
                pass
        raise ConfigError(f"{key}: expected an integer, got {value!r}")
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if isinstance(value, str):
            try:
                return float(value.strip())
            except ValueError:
                pass
        raise ConfigError(f"{key}: expected a number, got {value!r}")
    if tp is str:
        if isinstance(value, str):
            return value
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return str(value)
        raise ConfigError(f"{key}: expected a string, got {value!r}")
    raise TypeError(f"unsupported config type {tp!r} for {key}")


def _union(value: Any, args: tuple, key: str) -> Any:
    if value is None and type(None) in args:
        return None
    options = [a for a in args if a is not type(None)]
    if bool in options and (
        isinstance(value, bool) or (isinstance(value, str) and value.strip().lower() in TRUE + FALSE)
    ):
        return coerce(value, bool, key)  # a spelling of true/false is the bool, not the string
    errors = []
    for a in options:
        try:
            return coerce(value, a, key)
        except ConfigError as e:
            errors.append(str(e).removeprefix(f"{key}: "))
    if len(errors) == 1:
        raise ConfigError(f"{key}: {errors[0]}")
    raise ConfigError(f"{key}: invalid value {value!r} ({'; '.join(errors)})")


def _sequence(value: Any, origin: type, args: tuple, key: str) -> Any:
    variadic = origin is list or not args or args[-1] is Ellipsis
    if variadic and not isinstance(value, (list, tuple)):
        value = [value]  # a scalar where a list of any length fits: a list of one
    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{key}: expected a list of {len(args)} values, got {value!r}")
    if variadic:
        item = args[0] if args else Any
        return origin(coerce(v, item, f"{key}[{i}]") for i, v in enumerate(value))
    if len(value) != len(args):
        raise ConfigError(f"{key}: expected a list of {len(args)} values, got {list(value)!r}")
    return tuple(coerce(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args)))


__all__ = ["FALSE", "TRUE", "coerce", "from_mapping", "join"]
