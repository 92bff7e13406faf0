"""The output policy of every command: where a command may write, and what it may replace.

One rule for every command that writes a folder or a file (predict, evaluate, demo, train, synth, splits, convert,
export, benchmark):

* An output is never the same as, never contains, and never lies inside an input of the command (dataset root,
  images folder, pose file, split folder, model folder, checkpoint...). Paths are compared after resolving symlinks,
  ``..`` and relative parts (:func:`real`). An input may name sub-folders where outputs are allowed
  (:class:`Input.carve_out`, e.g. a SynthAir root's ``splits/``).
* A folder is only replaced (``mode="replace"``: predict, demo) when it does not exist, is empty, or was written by
  cosemdepth: it holds the marker :data:`MARKER`, which the command writes last and which lists every file it wrote,
  and it holds nothing else. Without ``--overwrite`` only a previous output of the same command is replaced.
* A command that writes a few files into a folder (``mode="into"``: evaluate, convert, splits) leaves the folder's
  other files alone and only replaces files that the marker says cosemdepth wrote.
* Folders recognised by a command's own manifest (``recognize``: a training run's ``config.yaml``, a SynthAir
  dataset's ``synthair.json``) are resumed, never replaced (``mode="resume"``).
* A single output file (``export --onnx``, ``benchmark --json``) must not be a folder, its parent folder must exist,
  be a folder and be writable, and an existing file is replaced only if ``recognize`` says cosemdepth wrote it.

Anything else is a :class:`~cosemdepth.errors.ConfigError` naming the output and why; the caller checks before
writing anything, so nothing is touched.
"""

from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Sequence

from .. import __version__
from ..errors import ConfigError
from .atomic import atomic_write_text
from .replaceable import check_replaceable

MARKER = ".cosemdepth-output.json"
MARKER_FORMAT = "cosemdepth-output"


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
            raise ConfigError(f"{out}: the {what} contains {name}, an input of this command; choose another "
                              f"{_kind(what)}")
        if _inside(o, i) and not any(_inside(o, real(i / c)) for c in inp.carve_out):
            raise ConfigError(f"{out}: the {what} lies inside {name}, an input of this command; choose a "
                              f"{_kind(what)} outside it")


def _kind(what: str) -> str:
    return "file" if "file" in what else "folder"


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
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".probe.", dir=p))
    except OSError as e:
        raise ConfigError(f"{message} ({p}: {_why(e)})") from None


# ----------------------------------------------------------------------------------------------------------------
# The marker


def read_marker(folder: str | os.PathLike) -> dict | None:
    """The marker of ``folder`` (``{"command", "files", ...}``), or None if there is none or it is damaged."""
    p = Path(folder) / MARKER
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    if (not isinstance(data, dict) or data.get("format") != MARKER_FORMAT or not isinstance(data.get("command"), str)
            or not isinstance(data.get("files"), list) or not all(isinstance(f, str) for f in data["files"])):
        return None
    return data


def list_files(folder: Path) -> list[str]:
    """Every file (and symlink) under ``folder``, relative, POSIX separators, sorted; the marker excluded."""
    out = []
    for dirpath, dirnames, filenames in os.walk(folder):
        base = Path(dirpath)
        for name in filenames + [d for d in dirnames if (base / d).is_symlink()]:
            rel = (base / name).relative_to(folder).as_posix()
            if rel != MARKER:
                out.append(rel)
    return sorted(out)


def write_marker(folder: str | os.PathLike, command: str, files: Iterable[str], merge: bool = True) -> Path:
    """Write ``folder/.cosemdepth-output.json`` naming ``command`` and the ``files`` it wrote (relative paths); with
    ``merge``, the files of an existing marker are kept in the list."""
    folder = Path(folder)
    names = set(files)
    old = read_marker(folder) if merge else None
    if old is not None:
        names |= set(old["files"])
    # no date: the same command writes the same bytes (a generated dataset is reproducible to the byte)
    data = {"format": MARKER_FORMAT, "command": command, "cosemdepth_version": __version__, "files": sorted(names)}
    path = folder / MARKER
    atomic_write_text(path, json.dumps(data, indent=1) + "\n")
    return path


# ----------------------------------------------------------------------------------------------------------------
# The checks


def check_output_dir(
    out: str | os.PathLike,
    *,
    command: str,
    mode: str = "replace",
    what: str = "--out folder",
    inputs: Iterable[Input | None] = (),
    overwrite: bool = False,
    files: Sequence[str] = (),
    recognize: Callable[[Path], bool] | None = None,
) -> bool:
    """Check that ``out`` may be written by ``command`` (see the module docstring); write nothing.

    Args:
        mode: ``"replace"`` (the folder is replaced as a whole), ``"into"`` (``files`` are written into it) or
            ``"resume"`` (a folder ``recognize`` accepts is continued).
        files: for ``"into"``: the relative paths the command will write (those known in advance).
        recognize: for ``"resume"``: is this non-empty folder one of the command's own (to be resumed)?
    Returns:
        True if ``out`` exists and is not empty (a previous output: replaced, written into or resumed).
    Raises:
        ConfigError: ``out`` is a file or under one, overlaps an input, holds files cosemdepth did not write (that
            would be replaced), or cannot be written.
    """
    if mode not in ("replace", "into", "resume"):
        raise ValueError(f"unknown mode {mode!r}")
    out = Path(out)
    check_not_under_file(out, what)
    if mode == "replace" and _inside(real(Path.cwd()), real(out)):
        raise ConfigError(f"{out}: the {what} cannot be the current folder or one of its parents")
    check_not_input(out, inputs, what)
    busy = out.is_dir() and any(out.iterdir())
    if busy:
        marker = read_marker(out)
        if mode == "replace":
            _check_replaceable(out, marker, command, overwrite, what)
        elif mode == "into":
            check_files_replaceable(out, files, marker)
        elif recognize is None or not recognize(out):
            raise ConfigError(f"{out}: the {what} is not empty and was not written by cosemdepth {command}; choose a "
                              "new or empty folder")
    if mode == "replace" or not out.exists():
        probe_writable(out.absolute().parent, f"{out}: cannot write the {what} here")
    else:
        probe_writable(out, f"{out}: cannot write the {what}")
    if mode == "replace":
        check_replaceable(out, what)  # a previous output that cannot be renamed aside and deleted
    elif mode == "into":
        for f in files:
            check_replaceable(out / f, what)
    return busy


def _check_replaceable(out: Path, marker: dict | None, command: str, overwrite: bool, what: str) -> None:
    if marker is None:
        hint = (" (--overwrite only replaces folders that cosemdepth wrote)" if overwrite else "")
        raise ConfigError(f"{out}: the {what} exists and is not empty, and was not written by cosemdepth (no {MARKER})"
                          f"; choose a new or empty folder{hint}")
    if marker["command"] != command and not overwrite:
        raise ConfigError(f"{out}: the {what} holds the output of `cosemdepth {marker['command']}`, not of "
                          f"`cosemdepth {command}`; pass --overwrite to replace it, or choose another folder")
    ours = set(marker["files"])
    foreign = [f for f in list_files(out) if f not in ours]
    if foreign:
        more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
        raise ConfigError(f"{out}: the {what} holds {foreign[0]}{more}, which cosemdepth did not write; nothing was "
                          "replaced (move those files, or choose another folder)")


def check_files_replaceable(folder: Path, files: Iterable[str], marker: dict | None = None) -> None:
    """Raise :class:`ConfigError` if one of ``files`` (relative to ``folder``) exists and is not listed in the
    folder's marker (i.e. cosemdepth did not write it), or is a folder."""
    marker = read_marker(folder) if marker is None else marker
    ours = set(marker["files"]) if marker else set()
    for f in files:
        p = folder / f
        if p.is_dir() and not p.is_symlink():
            raise ConfigError(f"{p}: a folder is in the way of an output file")
        if (p.exists() or p.is_symlink()) and f not in ours:
            raise ConfigError(f"{p}: exists and was not written by cosemdepth (not listed in {folder / MARKER}); "
                              "nothing was overwritten (move it, or choose another output folder)")


def check_output_file(
    out: str | os.PathLike,
    *,
    what: str,
    inputs: Iterable[Input | None] = (),
    recognize: Callable[[Path], bool] | None = None,
) -> None:
    """Check that the single output file ``out`` can be written: not a folder, its parent folder exists (is a
    folder, writable), not an input, and if it exists, ``recognize`` says cosemdepth wrote it."""
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
    if out.exists() or out.is_symlink():
        if not out.is_file():
            raise ConfigError(f"{out}: the {what} exists and is not a regular file")
        if recognize is None or not recognize(out):
            raise ConfigError(f"{out}: the {what} exists and was not written by cosemdepth; nothing was overwritten "
                              "(move it, or choose another file name)")
        check_replaceable(out, what)
    probe_writable(parent, f"{out}: cannot write the {what}")


__all__ = ["Input", "MARKER", "check_files_replaceable", "check_not_input", "check_not_under_file",
           "check_output_dir", "check_output_file", "list_files", "model_inputs", "probe_writable", "read_marker",
           "real", "write_marker"]
