"""Outputs that appear whole or not at all: a staged output folder, and a set of files renamed into place together.

* :class:`StagedDir` (``cosemdepth predict``, ``cosemdepth demo``): everything is written into a hidden temporary
  folder beside ``OUT``; on success it is renamed to ``OUT`` (replacing a previous output of the same command); on any
  error it is deleted. A failed or interrupted run therefore leaves no partial output folder.
* :class:`OutputFiles` (``cosemdepth evaluate``): a few files written into an existing or new folder; every file is
  first written to a temporary file, then all are renamed into place.

Both check at the start that the output location is usable (not a file, writable), so that a long run does not fail
at its very end, and remove the folders they created if the run fails.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from ..errors import ConfigError
from .atomic import _default_mode, _fsync_dir


def missing_ancestors(path: Path) -> list[Path]:
    """``path`` and those of its ancestors that do not exist yet, deepest first."""
    out = []
    p = path.absolute()
    while not p.exists() and p != p.parent:
        out.append(p)
        p = p.parent
    return out


def remove_empty(folders: list[Path]) -> None:
    """Remove ``folders`` (deepest first, as :func:`missing_ancestors` lists them) while they are empty."""
    for d in folders:  # deepest first; stop at the first one that is not empty (someone else wrote there)
        try:
            d.rmdir()
        except OSError:
            break


def _dir_mode() -> int:
    """Permissions a plain ``mkdir`` would give a new folder (0777 minus the umask); mkdtemp creates 0700."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o777 & ~mask


def _why(e: OSError) -> str:
    return e.strerror or str(e)


def probe_writable(folder: Path, message: str) -> None:
    """Raise :class:`ConfigError` (``message`` + the reason) unless a folder can be created in ``folder`` or, if
    it does not exist yet, in its nearest existing ancestor. Nothing is left behind."""
    p = folder.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".probe.", dir=p))
    except OSError as e:
        raise ConfigError(f"{message} ({p}: {_why(e)})") from None


def _check_not_file(out: Path, what: str) -> None:
    for p in [out, *out.absolute().parents]:
        if p.exists():
            if not p.is_dir():
                if p == out.absolute() or p == out:
                    raise ConfigError(f"{out}: {what} exists and is not a folder")
                raise ConfigError(f"{out}: cannot create the {what}: {p} is a file, not a folder")
            return


class StagedDir:
    """Context manager that yields a temporary folder and turns it into ``out`` on a clean exit.

    Args:
        out: the output folder.
        marker: a file name that only this command writes (e.g. ``predictions.json``); an existing ``out`` holding it
            is a previous output of the same command and is replaced. Another non-empty ``out`` is an error unless
            ``overwrite``.
        overwrite: replace a non-empty ``out`` whatever it holds.
        what: how error messages call the folder (e.g. ``"--out"``).
    Raises:
        ConfigError: ``out`` is a file, is not empty (and not ours), or its parent folder is not writable.
    """

    def __init__(self, out: str | os.PathLike, marker: str, *, overwrite: bool = False, what: str = "output folder"):
        self.out = Path(out)
        self.marker = marker
        self.overwrite = overwrite
        self.what = what
        self.tmp: Path | None = None
        self._created: list[Path] = []

    def check(self) -> None:
        """The checks of ``__enter__``, without creating anything."""
        out = self.out
        _check_not_file(out, self.what)
        if out.is_dir() and not self.overwrite and not (out / self.marker).is_file():
            if any(out.iterdir()):
                raise ConfigError(
                    f"{out}: the {self.what} exists and is not empty (and holds no {self.marker} of a previous run); "
                    "choose a new folder, or pass --overwrite to replace it"
                )
        if out.absolute() == Path.cwd() or out.absolute() in Path.cwd().parents:
            raise ConfigError(f"{out}: the {self.what} cannot be the current folder or one of its parents")
        probe_writable(out.absolute().parent, f"{out}: cannot write the {self.what} here")

    def __enter__(self) -> Path:
        self.check()
        parent = self.out.absolute().parent
        self._created = missing_ancestors(parent)
        try:
            parent.mkdir(parents=True, exist_ok=True)
            self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.", suffix=".partial", dir=parent))
            os.chmod(self.tmp, _dir_mode())
        except OSError as e:
            remove_empty(self._created)
            raise ConfigError(f"{self.out}: cannot write the {self.what} here ({parent}: {_why(e)})") from None
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        assert self.tmp is not None
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            remove_empty(self._created)
            return False
        try:
            self._commit()
        except BaseException:
            shutil.rmtree(self.tmp, ignore_errors=True)
            remove_empty(self._created)
            raise
        return False

    def _commit(self) -> None:
        out, tmp = self.out.absolute(), self.tmp
        old = None
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            os.rename(out, old / "x")
        try:
            os.rename(tmp, out)
        except BaseException:
            if old is not None:  # put the previous output back
                os.rename(old / "x", out)
                old.rmdir()
            raise
        _fsync_dir(out.parent)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


class OutputFiles:
    """Collect files to write into ``folder``; on a clean exit write them all to temporary files, then rename them
    into place (other files in ``folder`` are left alone).

    ``__enter__`` checks that ``folder`` can be written (creating it if needed; it is removed again if the run
    fails). Use :meth:`add_text` / :meth:`add_bytes` inside the block.
    """

    def __init__(self, folder: str | os.PathLike, what: str = "output folder"):
        self.folder = Path(folder)
        self.what = what
        self.files: dict[str, bytes] = {}
        self._created: list[Path] = []

    def __enter__(self) -> "OutputFiles":
        _check_not_file(self.folder, self.what)
        self._created = missing_ancestors(self.folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            fd, probe = tempfile.mkstemp(prefix=".probe.", dir=self.folder)
            os.close(fd)
            os.unlink(probe)
        except OSError as e:
            remove_empty(self._created)
            raise ConfigError(f"{self.folder}: cannot write the {self.what} ({_why(e)})") from None
        return self

    def add_bytes(self, name: str, data: bytes) -> Path:
        self.files[name] = data
        return self.folder / name

    def add_text(self, name: str, text: str) -> Path:
        return self.add_bytes(name, text.encode("utf-8"))

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            remove_empty(self._created)
            return False
        temps: list[tuple[str, Path]] = []
        try:
            for name, data in self.files.items():
                fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=self.folder)
                temps.append((tmp, self.folder / name))
                os.chmod(tmp, _default_mode())
                with os.fdopen(fd, "wb") as f:
                    f.write(data)
                    f.flush()
                    os.fsync(f.fileno())
            for tmp, final in temps:
                os.replace(tmp, final)
        except BaseException as e:
            for tmp, _ in temps:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(tmp)
            remove_empty(self._created)
            if isinstance(e, OSError):
                raise ConfigError(f"{self.folder}: cannot write the {self.what} ({_why(e)})") from None
            raise
        _fsync_dir(self.folder)
        return False


__all__ = ["OutputFiles", "StagedDir", "missing_ancestors", "remove_empty"]
