"""Outputs that appear whole or not at all: a staged output folder, and a set of files renamed into place together.

* :class:`StagedDir` (``cosemdepth predict``, ``cosemdepth demo``): everything is written into a hidden temporary
  folder beside ``OUT``; on success the output marker (:mod:`cosemdepth.io.outdir`) listing every file is written
  and the folder is renamed to ``OUT`` (replacing a previous output that the output policy allows to replace); on any
  error it is deleted. A failed or interrupted run therefore leaves no partial output folder.
* :class:`OutputFiles` (``cosemdepth evaluate``): a few files written into an existing or new folder; every file is
  first written to a temporary file, then all are renamed into place (only files that do not exist yet or that
  cosemdepth wrote are replaced), and the folder's marker is updated.

Both apply the output policy of :mod:`cosemdepth.io.outdir` at the start (so that a long run does not fail at its
very end, and nothing is touched if the output is not allowed) and again just before the output is put in place,
and remove the folders they created if the run fails.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from ..errors import ConfigError
from .atomic import _default_mode, _fsync_dir
from .outdir import Input, check_files_replaceable, check_not_under_file, check_output_dir, list_files, write_marker


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


class StagedDir:
    """Context manager that yields a temporary folder and turns it into ``out`` on a clean exit.

    Args:
        out: the output folder.
        command: the command writing it (recorded in the marker; a previous output of the same command is replaced).
        overwrite: also replace an output of another cosemdepth command (never a folder cosemdepth did not write).
        what: how error messages call the folder (e.g. ``"--out folder"``).
        inputs: the command's inputs, which ``out`` must not be, contain or lie inside.
    Raises:
        ConfigError: the output policy refuses ``out`` (see :func:`cosemdepth.io.outdir.check_output_dir`).
    """

    def __init__(self, out: str | os.PathLike, command: str, *, overwrite: bool = False,
                 what: str = "output folder", inputs=()):
        self.out = Path(out)
        self.command = command
        self.overwrite = overwrite
        self.what = what
        self.inputs: list[Input] = [i for i in inputs if i is not None]
        self.tmp: Path | None = None
        self._created: list[Path] = []

    def check(self) -> None:
        """The checks of ``__enter__``, without creating anything."""
        check_output_dir(self.out, command=self.command, mode="replace", what=self.what, inputs=self.inputs,
                         overwrite=self.overwrite)

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
            inside = _staged_name(exc, self.tmp, self.out)
            if inside is not None:  # name the file as the user will know it, not by the hidden staging folder
                raise OSError(exc.errno, exc.strerror, inside) from None
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
        self.check()  # again: the folder may have changed during the run
        write_marker(tmp, self.command, list_files(tmp), merge=False)
        old = None
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
            try:
                os.rename(out, old / "x")
            except OSError as e:  # nothing moved: the previous output stays, and so must nothing else
                old.rmdir()
                raise ConfigError(f"{self.out}: cannot replace the {self.what} ({_why(e)}); it was left as it was "
                                  "and nothing was written") from None
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


def _staged_name(exc, tmp: Path, out: Path) -> str | None:
    """For an OSError about a file inside the staging folder ``tmp``: that file's path under ``out``; else None."""
    if not isinstance(exc, OSError) or exc.errno is None or exc.filename is None or exc.filename2 is not None:
        return None
    try:
        rel = Path(os.fsdecode(exc.filename)).absolute().relative_to(tmp.absolute())
    except (ValueError, TypeError):
        return None
    return str(out / rel)


class OutputFiles:
    """Collect files to write into ``folder``; on a clean exit write them all to temporary files, then rename them
    into place (other files in ``folder`` are left alone).

    ``__enter__`` checks that ``folder`` can be written (creating it if needed; it is removed again if the run
    fails). Use :meth:`add_text` / :meth:`add_bytes` inside the block.
    """

    def __init__(self, folder: str | os.PathLike, what: str = "output folder", *, command: str,
                 names=(), inputs=()):
        self.folder = Path(folder)
        self.what = what
        self.command = command
        self.names = tuple(names)
        self.inputs = [i for i in inputs if i is not None]
        self.files: dict[str, bytes] = {}
        self._created: list[Path] = []

    def __enter__(self) -> "OutputFiles":
        check_not_under_file(self.folder, self.what)
        check_output_dir(self.folder, command=self.command, mode="into", what=self.what, inputs=self.inputs,
                         files=self.names)
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
            check_files_replaceable(self.folder, self.files)
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
            write_marker(self.folder, self.command, self.files)
        except BaseException as e:
            for tmp, _ in temps:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(tmp)
            remove_empty(self._created)
            if isinstance(e, OSError) and not isinstance(e, ConfigError):
                raise ConfigError(f"{self.folder}: cannot write the {self.what} ({_why(e)})") from None
            raise
        _fsync_dir(self.folder)
        return False


__all__ = ["OutputFiles", "StagedDir", "missing_ancestors", "remove_empty"]
