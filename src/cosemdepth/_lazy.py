"""Lazily imported package attributes (PEP 562), so that importing a package does not load torch & co."""

from __future__ import annotations

import importlib
from typing import Any, Callable, Mapping


def lazy_getattr(package: str, table: Mapping[str, str | tuple[str, str]]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package`` that imports ``table[name]`` on first access.

    ``table`` maps an attribute name to ``(module, attribute)`` or to ``module`` alone (same attribute name); a
    module name may be relative to ``package`` (``".render"``). Other names raise :class:`AttributeError`.
    """

    def __getattr__(name: str) -> Any:
        if name in table:
            target = table[name]
            module, attr = (target, name) if isinstance(target, str) else target
            return getattr(importlib.import_module(module, package), attr)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
