"""Opening dataset folders and text files with :class:`DatasetError`\\ s that name the path and the problem."""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import DatasetError


def dataset_root(root: str | os.PathLike) -> Path:
    """``root`` as a :class:`Path`; a :class:`DatasetError` if it is not an existing folder."""
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset root not found (or not a folder)")
    return root


def read_text(path: Path, what: str) -> str:
    """The text of ``path``; a :class:`DatasetError` ``"<path>: <what> not found"`` or ``"<path>: cannot read
    <what> (<reason>)"`` if it is missing or unreadable (``what`` names the kind of file, e.g. ``"split CSV"``)."""
    try:
        return path.read_text()
    except FileNotFoundError:
        raise DatasetError(f"{path}: {what} not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot read {what} ({e})") from None


def is_dir(path: Path) -> bool:
    """``path.is_dir()``, also False when the path cannot even be looked up (e.g. a name longer than the file system
    allows, from a damaged split file), where :meth:`Path.is_dir` raises."""
    try:
        return path.is_dir()
    except OSError:
        return False
