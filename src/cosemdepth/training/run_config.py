"""Run configuration files: YAML in, command-line overrides on top, YAML out.

A config file has up to four sections, ``model``, ``data``, ``train`` and ``debug`` (the fields of
:class:`cosemdepth.config.RunConfig`); a missing key takes the default of :mod:`cosemdepth.config` (the paper's
Mid-Air recipe). Overrides are ``KEY=VALUE`` strings with a dotted key, list items by index
(``train.lr=3e-4``, ``data.train.0.root=data/midair``, ``data.train.1.weight=0.5``); the value is read as YAML
(``true``, ``null``, ``[1, 2]``...) and converted to the field's type.

The shipped configs live in the package (``cosemdepth/configs/*.yaml``) and can be named without a path
(``--config midair``).
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path
from typing import Any, Iterable, Mapping

import yaml

from ..config import RunConfig
from ..errors import ConfigError


def builtin_configs() -> list[str]:
    """Names of the configs shipped with the package (``midair``, ``synthair-small``...)."""
    folder = importlib.resources.files("cosemdepth") / "configs"
    if not folder.is_dir():
        return []
    return sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def _resolve_path(config: str | Path) -> tuple[str, str]:
    """``(text, origin)`` of a config given as a path or as the name of a shipped config."""
    p = Path(config)
    if p.is_file():
        try:
            return p.read_text(encoding="utf-8"), str(p)
        except (OSError, UnicodeDecodeError) as e:
            raise ConfigError(f"{p}: cannot read the config file ({e})") from e
    if p.exists():
        raise ConfigError(f"{p}: the config must be a YAML file, this is a folder")
    name = str(config)
    if "/" not in name and not name.endswith((".yaml", ".yml")):
        res = importlib.resources.files("cosemdepth") / "configs" / f"{name}.yaml"
        if res.is_file():
            return res.read_text(encoding="utf-8"), f"cosemdepth/configs/{name}.yaml"
    shipped = builtin_configs()
    raise ConfigError(f"{config}: config file not found" + (f" (shipped configs: {shipped})" if shipped else ""))


def load_config_dict(config: str | Path) -> dict[str, Any]:
    """The raw nested dict of a YAML config file (a path, or the name of a shipped config)."""
    text, origin = _resolve_path(config)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{origin}: not valid YAML: {e}") from e
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{origin}: the top level must be a mapping with sections model/data/train/debug, "
                          f"got {type(data).__name__}")
    return data


def apply_override(d: dict[str, Any], override: str) -> None:
    """Apply one ``KEY=VALUE`` override to the nested dict ``d`` in place (see the module docstring)."""
    key, sep, raw = override.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(f"override {override!r}: expected KEY=VALUE, e.g. train.lr=3e-4")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    set_key(d, key, value)


def set_key(d: dict[str, Any], key: str, value: Any) -> None:
    """Set the dotted ``key`` (integer parts index lists) of the nested dict ``d`` to ``value``."""
    parts = key.split(".")
    node: Any = d
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        where = ".".join(parts[:i]) or "the config"
        if isinstance(node, list):
            if not part.isdigit():
                raise ConfigError(f"override {key!r}: {where} is a list; index it with a number, e.g. {where}.0")
            idx = int(part)
            if idx > len(node):
                raise ConfigError(f"override {key!r}: {where} has {len(node)} item(s); the next index is {len(node)}")
            if idx == len(node):
                node.append({})
            if last:
                node[idx] = value
            else:
                if not isinstance(node[idx], (dict, list)):
                    node[idx] = {}
                node = node[idx]
            continue
        if not isinstance(node, dict):
            raise ConfigError(f"override {key!r}: {where} is a value, not a section")
        if last:
            node[part] = value
        else:
            nxt = parts[i + 1]
            if part not in node or not isinstance(node[part], (dict, list)):
                node[part] = [] if nxt.isdigit() else {}
            node = node[part]


def resolve_config(
    config: str | Path | None = None,
    overrides: Iterable[str] = (),
    values: Mapping[str, Any] | None = None,
) -> RunConfig:
    """Build a :class:`RunConfig`: defaults, then the file ``config`` (if any), then ``values`` (``{dotted key:
    value}``, e.g. from explicit command-line flags), then the ``KEY=VALUE`` ``overrides`` in order."""
    d = load_config_dict(config) if config is not None else {}
    for key, value in (values or {}).items():
        set_key(d, key, value)
    for ov in overrides:
        apply_override(d, ov)
    return RunConfig.from_dict(d)


def dump_config(cfg: RunConfig) -> str:
    """The YAML text of a resolved config (every key, defaults included); loads back to an equal config."""
    return yaml.safe_dump(_plain(cfg.to_dict()), sort_keys=False, default_flow_style=None, width=100)


def _plain(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x


__all__ = ["apply_override", "builtin_configs", "dump_config", "load_config_dict", "resolve_config", "set_key"]
