"""The output policy of every command: where a command may write, and what it may replace.

One rule for every command that writes a folder or a file (predict, evaluate, demo, train, synth, splits, convert,
export, benchmark, view):

* An output is never the same as, never contains, and never lies inside an input of the command (dataset root,
  images folder, pose file, split folder, model folder, checkpoint...). Paths are compared after resolving symlinks,
  ``..`` and relative parts (:func:`real`). An input may name sub-folders where outputs are allowed
  (:class:`Input.carve_out`, e.g. a SynthAir root's ``splits/``).
* A folder that some command reads as input (a dataset, a split folder, a model, a training run or checkpoint, a
  TensorFlow checkpoint, a flight, a ROS 2 bag: :mod:`cosemdepth.output_safety.input_kinds`, recognised by the markers its
  readers need, whoever wrote it) is never another command's output: it is not replaced, written into or deleted,
  with or without ``--overwrite`` (:func:`check_not_other_input`). Only the command that produces that kind works
  on it, under the rules below (``synth`` resumes a SynthAir dataset, ``splits`` replaces its split folder,
  ``convert`` writes a model folder, ``train`` resumes a run), and only the sub-folders the kind opens
  (a dataset root's ``splits/``, for ``splits``) are written inside one.
* Every file a command writes is listed in the folder's marker :data:`MARKER` with its size and SHA-256. A file
  whose content changed since (a hand-corrected label PNG, an edited ``predictions.json``), a file the marker does
  not list, a link where a file was: each is the user's, and is never replaced or deleted.
* A folder is replaced (``mode="replace"``: predict, demo, splits) only when it does not exist, is empty, or holds
  a previous output and nothing else, every file unchanged. Without ``--overwrite`` only a previous output of the
  same command is replaced. The folder itself stays (a symlink stays and its target is written; an existing
  folder keeps its inode, mode, group and setgid bit): only its contents are replaced
  (:class:`cosemdepth.output_safety.staging.StagedDir`).
* A command that writes a few files into a folder (``mode="into"``: evaluate, convert) leaves the folder's other
  files alone and only replaces files of its own marker that are unchanged.
* Folders recognised by a command's own manifest (``recognize``: a training run's ``config.yaml``, a SynthAir
  dataset's ``synthair.json``) are resumed, never replaced (``mode="resume"``).
* A single output file (``export --onnx``, ``benchmark --json``, ``--rerun``) must not be a folder, its parent
  folder must exist, be a folder, be writable and lie in no input folder of any command. Once written it is
  recorded with its size and SHA-256 in its folder's marker (:func:`record_output_file`); an existing file is
  replaced only if that record lists it with the same content (and ``recognize``, where given, says it is the
  kind of file the command writes).

Anything else is a :class:`~cosemdepth.errors.ConfigError` naming the output and why; the caller checks before
writing anything, so nothing is touched.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Iterator, Sequence

from .. import __version__
from ..errors import ConfigError
from .atomic import atomic_write_text
from .input_kinds import identify
from .manifest import file_digest
from .replaceable import check_replaceable, probe_folder

MARKER = ".cosemdepth-output.json"
MARKER_FORMAT = "cosemdepth-output"
#: 1: a list of names; 2: every file with its size and SHA-256; 3: and the command that wrote it.
MARKER_VERSION = 3

#: The hidden work folders of a replacement inside the output folder (:class:`cosemdepth.output_safety.staging.StagedDir`):
#: the new output being written (holding :data:`LOCK_NAME`, locked while its run lives), the previous output while
#: it is moved out, and the previous output once it is entirely out. They share a token after the prefix.
STAGING_PREFIX = ".cosemdepth-partial-"
OLD_PREFIX = ".cosemdepth-old-"
DONE_PREFIX = ".cosemdepth-done-"
LOCK_NAME = ".cosemdepth-lock"
WORK_PREFIXES = (STAGING_PREFIX, OLD_PREFIX, DONE_PREFIX)


@dataclass(frozen=True)
class Input:
    """An input path of a command: ``label`` is how messages name it (``--root``, ``--model``...)."""

    label: str
    path: str | os.PathLike
    carve_out: tuple[str, ...] = ()  # sub-folders of ``path`` (relative) where outputs may go


def real(path: str | os.PathLike) -> Path:
    """The absolute path with symlinks, ``..`` and ``~`` resolved (also for paths that do not exist yet)."""
    return Path(os.path.realpath(os.path.expanduser(os.fspath(path))))


def _inside(a: Path, b: Path) -> bool:
    """``a`` is ``b`` or lies under it (both resolved)."""
    return a == b or b in a.parents


def model_inputs(path: str | os.PathLike | None, label: str = "--model") -> list[Input]:
    """The paths a model argument reads: the model folder (also for its ``config.json`` / ``model.safetensors``), or
    for a TensorFlow checkpoint prefix (``.../cp-0059.ckpt``) its folder when that holds a ``checkpoint`` file, else
    its files (``cp-0059.ckpt.index``, ``cp-0059.ckpt.data-*``)."""
    if path is None:
        return []
    p = Path(path)
    if p.is_file() and p.name in ("config.json", "model.safetensors"):
        return [Input(label, p.parent)]  # the model folder
    if p.exists():
        return [Input(label, p)]
    if not p.parent.is_dir():
        return []
    if (p.parent / "checkpoint").is_file():  # a TensorFlow checkpoint folder (the authors' train/ or best/)
        return [Input(label, p.parent)]
    return [Input(label, f) for f in p.parent.glob(p.name + ".*")]


def check_not_input(out: str | os.PathLike, inputs: Iterable[Input | None], what: str) -> None:
    """Raise :class:`ConfigError` if ``out`` is, contains or lies inside one of ``inputs``."""
    o = real(out)
    for inp in inputs:
        if inp is None or inp.path is None:
            continue
        i = real(inp.path)
        name = f"the {inp.label} {inp.path}"
        if o == i:
            raise ConfigError(f"{out}: the {what} is {name}, an input of this command; choose another {_kind(what)}")
        if _inside(i, o):
            raise ConfigError(
                f"{out}: the {what} contains {name}, an input of this command; choose another {_kind(what)}"
            )
        if _inside(o, i) and not any(_inside(o, real(i / c)) for c in inp.carve_out):
            raise ConfigError(
                f"{out}: the {what} lies inside {name}, an input of this command; choose a {_kind(what)} outside it"
            )


def check_not_other_input(out: str | os.PathLike, *, command: str | None, what: str, flag: bool = False) -> None:
    """Raise :class:`ConfigError` if ``out`` is, or lies inside, a folder that commands read as input
    (:func:`cosemdepth.output_safety.input_kinds.identify`), unless ``command`` produces that kind (``out`` itself) or the kind
    opens that sub-folder to it. ``command=None``: an output file, which no input folder holds. ``flag``: the
    command has ``--overwrite`` (the message says that it makes no difference)."""
    o = real(out)
    full = True  # up to the first existing folder (where the output creates its folder or file): any marker counts
    for folder in [o, *o.parents]:
        found = identify(folder, via=None if full else o.relative_to(folder).parts[0])
        full = full and not folder.is_dir()
        if found is None:
            continue
        kind, evidence = found
        if folder == o:
            if command in kind.writers:
                continue
            where = f"is {kind.name} ({evidence}{'' if o == Path(out).absolute() else f': {o}'})"
        else:
            if command is not None and (o.relative_to(folder).parts[0], command) in kind.open_inside:
                continue
            where = f"lies inside {folder}, {kind.name} ({evidence})"
        who = (
            f"cosemdepth {command} never writes there{', with or without --overwrite' if flag else ''}"
            if command
            else "no output goes there"
        )
        raise ConfigError(
            f"{out}: the {what} {where}, which commands read as input: {who}; choose another {_kind(what)}"
        )


def _kind(what: str) -> str:
    return "file" if "file" in what or "recording" in what else "folder"


def _why(e: OSError) -> str:
    return e.strerror or str(e)


def check_not_under_file(out: Path, what: str) -> None:
    """``out`` exists and is not a folder, or one of its ancestors is a file: :class:`ConfigError`."""
    for p in [out, *out.absolute().parents]:
        if p.exists():
            if not p.is_dir():
                if p in (out, out.absolute()):
                    raise ConfigError(f"{out}: {what} exists and is not a folder")
                raise ConfigError(f"{out}: cannot create the {what}: {p} is a file, not a folder")
            return


def probe_writable(folder: Path, message: str) -> None:
    """Raise :class:`ConfigError` (``message`` + the reason) unless a folder can be created in ``folder`` or, if
    it does not exist yet, in its nearest existing ancestor. Nothing is left behind."""
    p = folder.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    why = probe_folder(p)
    if why is not None:
        raise ConfigError(f"{message} ({p}: {why})")


# ----------------------------------------------------------------------------------------------------------------
# The marker


def read_marker(folder: str | os.PathLike) -> dict | None:
    """The marker of ``folder``, or None if there is none or it is damaged: ``{"command": str, "files": {relative
    path: {"size": int, "sha256": str, "command": str}}, ...}``; ``command`` is the command whose output the folder
    is, each file's ``command`` the one that wrote that file (absent from older markers: :func:`file_command`);
    files of a version-1 marker (names only) have ``None`` for size and checksum."""
    p = Path(folder) / MARKER
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("format") != MARKER_FORMAT or not isinstance(data.get("command"), str):
        return None
    files = data.get("files")
    if isinstance(files, list) and all(isinstance(f, str) for f in files):
        data["files"] = {f: {"size": None, "sha256": None} for f in files}
    elif not (isinstance(files, dict) and all(isinstance(f, str) and isinstance(e, dict) for f, e in files.items())):
        return None
    return data


def _skipped(name: str, skip: Sequence[str]) -> bool:
    return name == MARKER or name in skip


def list_files(folder: Path, skip: Sequence[str] = ()) -> list[str]:
    """Every file (and symlink) under ``folder``, relative, POSIX separators, sorted; the marker and the top-level
    entries named in ``skip`` excluded."""
    return sorted(rel for rel, _ in _walk(folder, skip))


def _walk(folder: Path, skip: Sequence[str] = ()) -> Iterator[tuple[str, bool]]:
    """``(relative path, is a folder)`` of every file, symlink and folder under ``folder`` (folders only where
    they hold nothing; symlinks are not followed)."""
    for dirpath, dirnames, filenames in os.walk(folder):
        base = Path(dirpath)
        if base == folder:
            dirnames[:] = [d for d in dirnames if not _skipped(d, skip)]
            filenames = [f for f in filenames if not _skipped(f, skip)]
        for name in filenames + [d for d in dirnames if (base / d).is_symlink()]:
            yield (base / name).relative_to(folder).as_posix(), False


def _subfolders(folder: Path, skip: Sequence[str] = ()) -> Iterator[Path]:
    for dirpath, dirnames, _ in os.walk(folder):
        if Path(dirpath) == folder:
            dirnames[:] = [d for d in dirnames if not _skipped(d, skip)]
        for d in dirnames:
            yield Path(dirpath) / d


def write_marker(
    folder: str | os.PathLike, command: str, files: Iterable[str], merge: bool = True, writer: str | None = None
) -> Path:
    """Write ``folder/.cosemdepth-output.json`` naming ``command`` (whose output the folder is) and the ``files``
    written (relative paths; each recorded with its size, SHA-256, read from disk, and the command that wrote it:
    ``writer``, default ``command``); with ``merge``, the other files of an existing marker are kept in the list,
    each with its own command."""
    folder = Path(folder)
    old = read_marker(folder) if merge else None
    entries = {f: {"command": file_command(old, f), **e} for f, e in old["files"].items()} if old is not None else {}
    for rel in files:
        p = folder / rel
        if p.is_symlink() or not p.is_file():
            entries.pop(rel, None)  # only regular files are ever ours
            continue
        size, digest = file_digest(p)
        entries[rel] = {"size": size, "sha256": digest, "command": writer or command}
    # no date: the same command writes the same bytes (a generated dataset is reproducible to the byte)
    data = {
        "format": MARKER_FORMAT,
        "version": MARKER_VERSION,
        "command": command,
        "cosemdepth_version": __version__,
        "files": dict(sorted(entries.items())),
    }
    path = folder / MARKER
    atomic_write_text(path, json.dumps(data, indent=1) + "\n")
    return path


def file_command(marker: dict, rel: str) -> str:
    """The command that wrote the file ``rel`` of ``marker``: its entry's, else (a marker of an older cosemdepth)
    the folder's."""
    entry = marker["files"].get(rel) or {}
    own = entry.get("command")
    return own if isinstance(own, str) else marker["command"]


def file_problem(folder: Path, rel: str, marker: dict | None) -> str | None:
    """Why the existing file ``folder/rel`` is not cosemdepth's to replace, or None if it is (listed in the marker,
    a regular file, same size and SHA-256 as recorded)."""
    p = folder / rel
    if marker is None:
        return f"not written by cosemdepth (no {MARKER} in {folder})"
    entry = marker["files"].get(rel)
    if entry is None:
        return f"not written by cosemdepth (not listed in {folder / MARKER})"
    if p.is_symlink() or not p.is_file():
        return "not written by cosemdepth (a link or a special file where it wrote a file)"
    if not isinstance(entry.get("sha256"), str):
        return f"listed in {MARKER} without a checksum (an older cosemdepth wrote it), so it may have changed since"
    try:
        size, digest = file_digest(p)
    except OSError as e:
        return f"cannot be read to check that cosemdepth wrote it ({_why(e)})"
    if size != entry.get("size") or digest != entry["sha256"]:
        return (
            f"changed since cosemdepth {file_command(marker, rel)} wrote it (not the SHA-256 that {MARKER} records), "
            "so it is yours"
        )
    return None


# ----------------------------------------------------------------------------------------------------------------
# Work folders of a replacement (written by cosemdepth.output_safety.staging.StagedDir)


def is_locked(lock: Path) -> bool:
    """Whether another open file holds the lock ``lock`` (a live run's staging folder)."""
    try:
        fd = os.open(lock, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)  # closing releases the probe's lock
    return False


def work_folders(folder: Path) -> dict[str, dict[str, Path]]:
    """The work folders in ``folder``, by token: ``{token: {"staging" | "old" | "done": path}}``."""
    out: dict[str, dict[str, Path]] = {}
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            for role, prefix in zip(("staging", "old", "done"), WORK_PREFIXES):
                if entry.name.startswith(prefix) and entry.is_dir(follow_symlinks=False):
                    out.setdefault(entry.name[len(prefix) :], {})[role] = Path(entry.path)
    return out


def _check_work_folders(out: Path, ignore: Sequence[str]) -> list[str]:
    """The names of the leftover work folders of finished runs in ``out`` (to be skipped as ours); a ConfigError if
    a live run is writing ``out`` or a replacement was interrupted."""
    skip = []
    for token, roles in work_folders(out).items():
        names = [p.name for p in roles.values()]
        if any(n in ignore for n in names):
            skip += names
            continue
        staging = roles.get("staging")
        if staging is not None and is_locked(staging / LOCK_NAME):
            raise ConfigError(
                f"{out}: another cosemdepth run is writing this folder ({staging.name}); wait for it, "
                "or choose another folder"
            )
        if "old" in roles or "done" in roles:
            raise ConfigError(
                f"{out}: holds an interrupted replacement ({', '.join(sorted(names))}); run the command "
                "again to complete it, or move those folders"
            )
        if staging is not None and (staging / LOCK_NAME).is_file():
            skip.append(staging.name)  # a killed run's partial output: ours, removed by the next replacement
    return skip


# ----------------------------------------------------------------------------------------------------------------
# The checks


def check_output_dir(
    out: str | os.PathLike,
    *,
    command: str,
    mode: str = "replace",
    what: str = "--out folder",
    inputs: Iterable[Input | None] = (),
    overwrite: bool | None = False,
    files: Sequence[str] = (),
    recognize: Callable[[Path], bool] | None = None,
    ignore: Sequence[str] = (),
) -> bool:
    """Check that ``out`` may be written by ``command`` (see the module docstring); write nothing.

    Args:
        mode: ``"replace"`` (the folder's contents are replaced as a whole), ``"into"`` (``files`` are written into
            it) or ``"resume"`` (a folder ``recognize`` accepts is continued).
        overwrite: for ``"replace"``: also replace another command's output; None: the command has no such flag.
        files: for ``"into"``: the relative paths the command will write (those known in advance).
        recognize: for ``"resume"``: is this non-empty folder one of the command's own (to be resumed)?
        ignore: for ``"replace"``: top-level work folders of the calling run (its staging folder).
    Returns:
        True if ``out`` exists and is not empty (a previous output: replaced, written into or resumed).
    Raises:
        ConfigError: ``out`` is a file or under one, overlaps an input of this command or is or lies in an input
            folder of any command, holds files that are not cosemdepth's unchanged output (that would be
            replaced), or cannot be written.
    """
    if mode not in ("replace", "into", "resume"):
        raise ValueError(f"unknown mode {mode!r}")
    out = Path(out)
    check_not_under_file(out, what)
    if mode == "replace" and real(out) in real(Path.cwd()).parents:
        raise ConfigError(f"{out}: the {what} holds the current folder; choose another folder")
    check_not_input(out, inputs, what)
    check_not_other_input(out, command=command, what=what, flag=mode == "replace" and overwrite is not None)
    target = real(out)  # a symlink's target, `..` resolved: the folder that is written
    skip: list[str] = []
    if mode == "replace" and target.is_dir():
        skip = _check_work_folders(target, ignore)
    busy = target.is_dir() and any(p.name not in skip for p in target.iterdir())
    if busy:
        marker = read_marker(target)
        if mode == "replace":
            _check_replaceable(target, marker, command, overwrite, what, skip)
        elif mode == "into":
            check_files_replaceable(target, files, marker)
        elif recognize is None or not recognize(out):
            raise ConfigError(
                f"{out}: the {what} is not empty and was not written by cosemdepth {command}; choose a "
                "new or empty folder"
            )
    if mode == "replace" or not out.exists():
        probe_writable(target if target.is_dir() else target.parent, f"{out}: cannot write the {what} here")
    else:
        probe_writable(out, f"{out}: cannot write the {what}")
    if mode == "replace":
        check_replaceable(out, what)  # a previous output that cannot be renamed aside and deleted
    elif mode == "into":
        for f in files:
            check_replaceable(out / f, what)
    return busy


def _check_replaceable(
    out: Path, marker: dict | None, command: str, overwrite: bool | None, what: str, skip: Sequence[str]
) -> None:
    how = f"move it, or choose another {_kind(what)}"
    if marker is None:
        hint = " (--overwrite only replaces folders that cosemdepth wrote)" if overwrite else ""
        raise ConfigError(
            f"{out}: the {what} exists and is not empty, and was not written by cosemdepth (no {MARKER})"
            f"; choose a new or empty folder{hint}"
        )
    if marker["command"] != command:
        if not overwrite:
            flag = "pass --overwrite to replace it, or " if overwrite is not None else ""
            raise ConfigError(
                f"{out}: the {what} holds the output of `cosemdepth {marker['command']}`, not of "
                f"`cosemdepth {command}`; {flag}choose another folder"
            )
        for sub in _subfolders(out, skip):  # another command's output never takes an input folder with it
            found = identify(sub)
            if found is not None:
                raise ConfigError(
                    f"{out}: the {what} holds {sub}, {found[0].name} ({found[1]}), which commands read "
                    f"as input; nothing was replaced: {how}"
                )
    files = list_files(out, skip)
    foreign = [f for f in files if f not in marker["files"]]
    if foreign:
        more = f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
        raise ConfigError(
            f"{out / foreign[0]}: {file_problem(out, foreign[0], marker)}{more}; nothing was replaced: {how}"
        )
    for f in files:
        problem = file_problem(out, f, marker)
        if problem is not None:
            raise ConfigError(f"{out / f}: {problem}; nothing was replaced: {how}")


def check_files_replaceable(folder: Path, files: Iterable[str], marker: dict | None = None) -> None:
    """Raise :class:`ConfigError` if one of ``files`` (relative to ``folder``) exists and is not cosemdepth's to
    replace (:func:`file_problem`: not listed in the folder's marker, or changed since), or is a folder."""
    folder = Path(folder)
    marker = read_marker(folder) if marker is None else marker
    for f in files:
        p = folder / f
        if p.is_dir() and not p.is_symlink():
            raise ConfigError(f"{p}: a folder is in the way of an output file")
        if p.exists() or p.is_symlink():
            problem = file_problem(folder, f, marker)
            if problem is not None:
                raise ConfigError(f"{p}: {problem}; nothing was replaced: move it, or choose another output folder")


def check_output_file(
    out: str | os.PathLike,
    *,
    what: str,
    inputs: Iterable[Input | None] = (),
    recognize: Callable[[Path], bool] | None = None,
) -> None:
    """Check that the single output file ``out`` can be written: not a folder, its parent folder exists (is a
    folder, writable), not an input, in no input folder of any command, and if it exists, ``recognize`` says
    cosemdepth wrote it."""
    out = Path(out)
    if out.is_dir():
        raise ConfigError(f"{out}: the {what} is a folder; give a file name")
    parent = out.absolute().parent
    for p in [parent, *parent.parents]:
        if p.exists():
            if not p.is_dir():
                raise ConfigError(f"{out}: cannot write the {what}: {p} is a file, not a folder")
            break
    if not parent.exists():
        raise ConfigError(f"{out}: cannot write the {what}: the folder {parent} does not exist")
    check_not_input(out, inputs, what)
    check_not_other_input(out, command=None, what=what)
    if out.name == MARKER:
        raise ConfigError(f"{out}: {MARKER} is the name of cosemdepth's output record; choose another file name")
    if out.exists() or out.is_symlink():
        if not out.is_file():
            raise ConfigError(f"{out}: the {what} exists and is not a regular file")
        target = real(out)  # a symlink names where to write: its target is what is replaced
        problem = file_problem(target.parent, target.name, read_marker(target.parent))
        if problem is None and recognize is not None and not recognize(out):
            problem = "not written by cosemdepth"
        if problem is not None:
            raise ConfigError(
                f"{out}: the {what} exists and cannot be replaced: {problem}; nothing was overwritten "
                "(move it, or choose another file name)"
            )
        check_replaceable(out, what)
    probe_writable(parent, f"{out}: cannot write the {what}")


def record_output_file(path: str | os.PathLike, command: str) -> Path:
    """Record the single output file ``path`` that ``command`` has just put in place (``export --onnx``,
    ``benchmark --json/--md``, ``view --rrd``...) with its size and SHA-256 in its folder's marker, so that
    :func:`check_output_file` replaces it later only while its content is unchanged. The file's entry names
    ``command``; an existing marker keeps the folder's command (the folder's other outputs stay those of their
    command); the marker of a symlink's target's folder is the one written."""
    target = real(path)
    old = read_marker(target.parent)
    folder_command = old["command"] if old is not None else command
    return write_marker(target.parent, folder_command, [target.name], merge=True, writer=command)


__all__ = [
    "DONE_PREFIX",
    "Input",
    "LOCK_NAME",
    "MARKER",
    "OLD_PREFIX",
    "STAGING_PREFIX",
    "check_files_replaceable",
    "check_not_input",
    "check_not_other_input",
    "check_not_under_file",
    "check_output_dir",
    "check_output_file",
    "file_command",
    "file_problem",
    "is_locked",
    "list_files",
    "model_inputs",
    "probe_writable",
    "read_marker",
    "real",
    "record_output_file",
    "work_folders",
    "write_marker",
]
