"""The optional dependencies: which Python module comes from which package and extra, and one way to ask for them.

:func:`require` imports an optional module where a feature needs it and otherwise raises a one-line
:class:`~cosemdepth.errors.ConfigError` saying what to install; a command calls it before it starts the work that
needs the module (nothing is written first). :func:`missing_package` turns any other failed import of a third-party
module into the same kind of message (the command-line error boundary uses it).
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import ConfigError

#: Importable module -> (the package that provides it, the cosemdepth extra that installs it); the extras of
#: ``pyproject.toml`` (``tests/test_optional.py`` checks that they agree).
OPTIONAL_PACKAGES: dict[str, tuple[str, str]] = {
    "onnx": ("onnx", "export"),
    "onnxruntime": ("onnxruntime", "export"),
    "rosbags": ("rosbags", "ros"),
    "rerun": ("rerun-sdk", "viz"),
    "pyulog": ("pyulog", "flight"),
    "pymavlink": ("pymavlink", "flight"),
    "pymap3d": ("pymap3d", "flight"),
    "av": ("av", "flight"),
    "cyclonedds": ("cyclonedds", "live"),
}


def install_hint(module: str) -> str:
    """How to install the package of ``module``: ``pip install 'cosemdepth[export]'`` or ``pip install NAME``."""
    top = module.split(".")[0]
    if top in OPTIONAL_PACKAGES:
        package, extra = OPTIONAL_PACKAGES[top]
        return f"pip install 'cosemdepth[{extra}]' (or pip install {package})"
    return f"pip install {top}"


def require(module: str, purpose: str) -> ModuleType:
    """``import module``, or a :class:`ConfigError`: "``purpose`` needs the Python package P, which is not installed
    (or cannot be imported here: ...); pip install ..." (``purpose``: e.g. ``"export --check"``)."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        raise ConfigError(_message(module, purpose, e)) from None


def missing_package(e: BaseException) -> str | None:
    """The one-line message for an import of a third-party module that failed (``e`` or an exception it was raised
    from); None if there is none, or it is a module of this package (a bug, not the environment)."""
    err = _import_error_in(e)
    if err is None:
        return None
    name = err.name or ""
    if not name or name.split(".")[0] == "cosemdepth":
        return None
    return _message(name, "this command", err)


def _message(module: str, purpose: str, e: ImportError) -> str:
    top = module.split(".")[0]
    package = OPTIONAL_PACKAGES.get(top, (top, ""))[0]
    missing = isinstance(e, ModuleNotFoundError) and (e.name or "").split(".")[0] == top
    why = "which is not installed" if missing else f"which cannot be imported here ({_first_line(e)})"
    return f"{purpose} needs the Python package {package}, {why}; {install_hint(module)}"


def _import_error_in(e: BaseException) -> ImportError | None:
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, ImportError):
            return e
        e = e.__cause__ or e.__context__
    return None


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0][:200] if text else type(e).__name__


__all__ = ["OPTIONAL_PACKAGES", "install_hint", "missing_package", "require"]
