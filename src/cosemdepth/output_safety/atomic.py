"""Atomic file writes: write to a temporary file in the same folder, flush, fsync, then rename over the target.

A reader never sees a half-written file, and a crash (even SIGKILL) leaves either the old file or the new one. A write
that fails (a full disk, a read-only or immutable folder) removes the temporary file and raises an :class:`OSError`
that names ``path`` (a writer's ``write()`` names no file; the temporary name means nothing to the user). A path that
is a symlink is written through: the link's target is replaced and the link stays.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from pathlib import Path
from typing import IO, Iterator

try:
    import resource
except ImportError:  # pragma: no cover - Windows
    resource = None


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO]:
    """Open a temporary file beside ``path``; on a clean exit it replaces ``path`` atomically.

    On an exception the temporary file is removed and ``path`` is left untouched.
    """
    if not any(m in mode for m in "wx"):
        raise ValueError(f"atomic_open is for writing, got mode {mode!r}")
    with atomic_path(path) as tmp, open(tmp, mode.replace("x", "w")) as f:
        yield f
        f.flush()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` for a library that writes by file name (PIL, h5py, safetensors...).

    The caller writes to the yielded path; on a clean exit it is renamed over ``path``. The temporary name keeps
    the target's suffix so that libraries choosing a format from the extension still work.
    """
    path = Path(path)
    if path.is_symlink():  # a link names where to write: its target is replaced, the link stays
        path = Path(os.path.realpath(path))
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
        os.close(fd)
        yield Path(tmp)
        # the mode is set after the caller has written: some writers (safetensors) replace the file with a 0600 one
        os.chmod(tmp, _default_mode())
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        report = write_error(e, tmp, path) if isinstance(e, OSError) and e.filename in (None, tmp) else None
        if tmp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        if report is not None:
            raise report from None
        raise
    _fsync_dir(path.parent)


def write_error(e: OSError, tmp: str | os.PathLike | None, path: str | os.PathLike) -> OSError:
    """The OSError to report for a failed write of ``path`` (through its temporary file ``tmp``), naming ``path``.

    A writer that checks its byte counts (numpy's ``tofile``: "16384 requested and 5088 written") reports a short
    write without an errno; the cause is then read from the machine: a file system with no free block left
    (ENOSPC), or a temporary file as large as the process's file-size limit (EFBIG, ``ulimit -f``); else EIO."""
    if e.errno is not None:
        return OSError(e.errno, e.strerror or os.strerror(e.errno), str(path))
    code = errno.EIO
    folder = Path(path).absolute().parent
    try:
        st = os.statvfs(folder)
        if (st.f_bfree if os.geteuid() == 0 else st.f_bavail) == 0:
            code = errno.ENOSPC
    except (OSError, AttributeError):  # pragma: no cover - a system without statvfs
        pass
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0] if resource is not None else -1
    if code == errno.EIO and tmp is not None and limit not in (-1, getattr(resource, "RLIM_INFINITY", -1)):
        with contextlib.suppress(OSError):
            if os.path.getsize(tmp) >= limit:
                code = errno.EFBIG
    why = os.strerror(code) if code != errno.EIO else f"{os.strerror(code)}: {e}"
    return OSError(code, why, str(path))


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically: a reader sees the old file or the whole new one."""
    with atomic_open(path, "wb") as f:
        f.write(data)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_write_bytes`)."""
    atomic_write_bytes(path, text.encode("utf-8"))


def _default_mode() -> int:
    """Permissions a plain ``open()`` would give a new file (0666 minus the umask); mkstemp creates files 0600."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
