"""Outputs that appear whole or not at all: a staged output folder, and a set of files renamed into place together.

* :class:`StagedDir` (``cosemdepth predict``, ``cosemdepth demo``, ``cosemdepth splits``): everything is written
  into a hidden staging folder inside ``OUT`` (:data:`~cosemdepth.output_safety.outdir.STAGING_PREFIX`; created with the usual
  permissions if ``OUT`` is new). On success the output marker (:mod:`cosemdepth.output_safety.outdir`) listing every file
  with its checksum is written and the contents of ``OUT`` are replaced by the staged ones: the previous output is
  moved aside (its marker first), the new files are moved in (the marker last), the previous output is deleted.
  ``OUT`` itself is never replaced: a symlink stays and its target receives the output; an existing folder keeps
  its inode, mode, group and setgid bit, and the new files, made inside it, get its group as any file would. On any
  error the staging folder is deleted (and ``OUT`` if the run created it), so a failed or interrupted run leaves
  the previous output as it was.
* :class:`OutputFiles` (``cosemdepth evaluate``): a few files written into an existing or new folder; every file is
  first written to a temporary file, then all are renamed into place (only files that do not exist yet or that
  cosemdepth wrote and nobody changed since are replaced), and the folder's marker is updated.

Both apply the output policy of :mod:`cosemdepth.output_safety.outdir` at the start (so that a long run does not fail at its
very end, and nothing is touched if the output is not allowed) and again just before the output is put in place,
and remove the folders they created if the run fails.

A run killed while it replaces a folder's contents (between a few renames) leaves its work folders in ``OUT``;
the next :class:`StagedDir` on ``OUT`` finishes that replacement if the previous output was entirely moved aside,
else puts the previous output back (:func:`recover`), and deletes the partial output of a run killed earlier. A
staging folder is known to belong to a dead run because nobody holds its lock file any more.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import tempfile
from pathlib import Path

from ..errors import ConfigError
from .atomic import _default_mode, _fsync_dir
from .outdir import (
    DONE_PREFIX,
    LOCK_NAME,
    MARKER,
    OLD_PREFIX,
    STAGING_PREFIX,
    Input,
    check_files_replaceable,
    check_not_input,
    check_not_other_input,
    check_not_under_file,
    check_output_dir,
    is_locked,
    list_files,
    real,
    work_folders,
    write_marker,
)
from .replaceable import probe_folder


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


def _why(e: OSError) -> str:
    return e.strerror or str(e)


def recover(folder: Path) -> None:
    """Finish or undo the replacements of ``folder``'s contents that killed runs left, and delete their partial
    outputs (work folders whose lock nobody holds; see the module docstring). A live run's are left alone."""
    for roles in work_folders(folder).values():
        staging = roles.get("staging")
        if staging is None or not (staging / LOCK_NAME).is_file() or is_locked(staging / LOCK_NAME):
            continue  # not ours, or its run is alive
        if "old" in roles:  # the previous output was being moved aside: put it back
            for name in sorted(os.listdir(roles["old"]), key=lambda n: n == MARKER):  # its marker last
                os.rename(roles["old"] / name, folder / name)
            roles["old"].rmdir()
        elif "done" in roles and (staging / MARKER).is_file():  # the new output was being moved in: finish
            _move_contents(staging, folder)
            shutil.rmtree(roles["done"])
        _fsync_dir(folder)
        shutil.rmtree(staging)


def _move_contents(src: Path, dst: Path, journal: list | None = None) -> None:
    """Rename every entry of ``src`` (but its lock) into ``dst``, the output marker last."""
    for name in sorted((n for n in os.listdir(src) if n != LOCK_NAME), key=lambda n: n == MARKER):
        os.rename(src / name, dst / name)
        if journal is not None:
            journal.append((src / name, dst / name))


class StagedDir:
    """Context manager that yields a staging folder and on a clean exit makes its contents those of ``out``.

    Args:
        out: the output folder (a symlink to a folder: its target).
        command: the command writing it (recorded in the marker; a previous output of the same command is replaced).
        overwrite: also replace an output of another cosemdepth command (never files cosemdepth did not write or
            that changed since, never a folder that commands read as input); None: the command has no such flag.
        what: how error messages call the folder (e.g. ``"--out folder"``).
        inputs: the command's inputs, which ``out`` must not be, contain or lie inside.
    Raises:
        ConfigError: the output policy refuses ``out`` (see :func:`cosemdepth.output_safety.outdir.check_output_dir`).
    """

    def __init__(
        self,
        out: str | os.PathLike,
        command: str,
        *,
        overwrite: bool | None = False,
        what: str = "output folder",
        inputs=(),
    ):
        self.out = Path(out)
        self.command = command
        self.overwrite = overwrite
        self.what = what
        self.inputs: list[Input] = [i for i in inputs if i is not None]
        self.tmp: Path | None = None
        self.target: Path | None = None
        self._created: list[Path] = []
        self._lock: int | None = None

    def check(self) -> None:
        """The checks of ``__enter__``, without creating anything (the work folders of a killed run in ``out`` are
        first dealt with, see :func:`recover`)."""
        check_not_under_file(self.out, self.what)
        check_not_input(self.out, self.inputs, self.what)
        check_not_other_input(self.out, command=self.command, what=self.what, flag=self.overwrite is not None)
        target = real(self.out)
        if target.is_dir():
            try:
                recover(target)
            except OSError as e:
                raise ConfigError(f"{self.out}: cannot clean up after an interrupted run ({_why(e)})") from None
        self._check()

    def _check(self, ignore=()) -> None:
        check_output_dir(
            self.out,
            command=self.command,
            mode="replace",
            what=self.what,
            inputs=self.inputs,
            overwrite=self.overwrite,
            ignore=ignore,
        )

    def __enter__(self) -> Path:
        self.check()
        target = real(self.out)
        self._created = missing_ancestors(target)
        try:
            target.mkdir(parents=True, exist_ok=True)  # a new folder: the usual permissions, its parent's group
            self.tmp = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX, dir=target))
            self._lock = os.open(self.tmp / LOCK_NAME, os.O_WRONLY | os.O_CREAT, 0o644)
            fcntl.flock(self._lock, fcntl.LOCK_EX)  # held while this run lives: its staging is not a leftover
        except OSError as e:
            self._discard()
            raise ConfigError(f"{self.out}: cannot write the {self.what} here ({target}: {_why(e)})") from None
        self.target = target
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        assert self.tmp is not None
        if exc_type is not None:
            tmp = self.tmp
            self._discard()
            inside = _staged_name(exc, tmp, self.out)
            if inside is not None:  # name the file as the user will know it, not by the hidden staging folder
                raise OSError(exc.errno, exc.strerror, inside) from None
            return False
        try:
            self._commit()
        except BaseException as e:
            self._discard()
            if isinstance(e, OSError) and not isinstance(e, ConfigError):
                raise ConfigError(f"{self.out}: cannot write the {self.what} ({_why(e)})") from None
            raise
        self._discard()  # only the lock is left in the staging folder
        return False

    def _discard(self) -> None:
        """Delete the staging folder and release its lock; remove the folders this run created if they are empty."""
        if self.tmp is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None
        remove_empty(self._created)

    def _commit(self) -> None:
        target, tmp = self.target, self.tmp
        assert target is not None and tmp is not None
        self._check(ignore=(tmp.name,))  # again: the folder may have changed during the run
        write_marker(tmp, self.command, list_files(tmp, skip=(LOCK_NAME,)), merge=False)
        token = tmp.name[len(STAGING_PREFIX) :]
        leftovers = [p for t, roles in work_folders(target).items() if t != token for p in roles.values()]
        old = target / f"{OLD_PREFIX}{token}"
        done = target / f"{DONE_PREFIX}{token}"
        keep = {tmp.name, old.name, *(p.name for p in leftovers)}
        old.mkdir()
        journal: list[tuple[Path, Path]] = []
        try:
            # the previous output aside, its marker first (from then on the folder is no output of ours) ...
            for name in sorted((n for n in os.listdir(target) if n not in keep), key=lambda n: n != MARKER):
                os.rename(target / name, old / name)
                journal.append((target / name, old / name))
            os.rename(old, done)
            journal.append((old, done))
            _move_contents(tmp, target, journal)  # ... the new one in, its marker last
        except BaseException:
            for src, dst in reversed(journal):
                with contextlib.suppress(OSError):
                    os.rename(dst, src)
            with contextlib.suppress(OSError):
                old.rmdir()
            raise
        _fsync_dir(target)
        shutil.rmtree(done, ignore_errors=True)
        for p in leftovers:  # partial outputs of killed runs (the check found no live run and no half replacement)
            shutil.rmtree(p, ignore_errors=True)


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

    def __init__(self, folder: str | os.PathLike, what: str = "output folder", *, command: str, names=(), inputs=()):
        self.folder = Path(folder)
        self.what = what
        self.command = command
        self.names = tuple(names)
        self.inputs = [i for i in inputs if i is not None]
        self.files: dict[str, bytes] = {}
        self._created: list[Path] = []

    def __enter__(self) -> "OutputFiles":
        check_not_under_file(self.folder, self.what)
        check_output_dir(
            self.folder, command=self.command, mode="into", what=self.what, inputs=self.inputs, files=self.names
        )
        target = real(self.folder)  # a symlink to a folder: its target
        self._created = missing_ancestors(target)
        try:
            target.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            remove_empty(self._created)
            raise ConfigError(f"{self.folder}: cannot write the {self.what} ({_why(e)})") from None
        why = probe_folder(target)
        if why is not None:
            remove_empty(self._created)
            raise ConfigError(f"{self.folder}: cannot write the {self.what} ({why})")
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


__all__ = ["OutputFiles", "StagedDir", "missing_ancestors", "recover", "remove_empty"]
