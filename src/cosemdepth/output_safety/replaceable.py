"""Can an existing output be replaced? Checked before a command runs, so that a run never fails at its very end.

Replacing a previous output renames it aside and deletes it, or renames a new file over it. Both fail on an
immutable or append-only file or folder (``chattr +i`` / ``+a``; permissions do not stop root, these flags do), on a
folder that cannot take a new entry (read-only file system, no write permission), and on a read-only file system.
:func:`check_replaceable` tries what can be tried without changing anything (creating and removing an empty folder
inside every folder of the output) and reads the immutable and append-only flags of every entry
(``FS_IOC_GETFLAGS``, Linux; elsewhere :func:`fs_flags` reports none).
"""

from __future__ import annotations

import array
import os
import sys
import tempfile
from pathlib import Path

from ..errors import ConfigError

#: ``FS_IOC_GETFLAGS`` and the flags of ``linux/fs.h`` this module reads.
_FS_IOC_GETFLAGS = 0x80086601
FS_IMMUTABLE_FL = 0x00000010
FS_APPEND_FL = 0x00000020


def fs_flags(path: str | os.PathLike) -> int:
    """The inode flags of ``path`` (``lsattr``), 0 where the system or the file system does not report them."""
    if not sys.platform.startswith("linux"):
        return 0
    import fcntl  # POSIX only

    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0))
    except OSError:
        return 0  # unreadable or a symlink: what it holds is not what is replaced
    try:
        buf = array.array("i", [0])  # the kernel writes an int, whatever the macro says
        fcntl.ioctl(fd, _FS_IOC_GETFLAGS, buf, True)
        return int(buf[0])
    except OSError:
        return 0  # the file system has no such flags (ENOTTY, EINVAL...)
    finally:
        os.close(fd)


def _locked(path: Path) -> str | None:
    flags = fs_flags(path)
    if flags & FS_IMMUTABLE_FL:
        return "immutable"
    if flags & FS_APPEND_FL:
        return "append-only"
    return None


def probe_folder(folder: str | os.PathLike) -> str | None:
    """Why ``folder`` cannot take a new entry (and lose it again), or None. An immutable or append-only folder is
    reported from its flags, without trying (an append-only folder takes the probe but never lets it go). The
    folder's times are put back: a check that passes leaves the folder as it found it."""
    folder = Path(folder)
    why = _locked(folder)
    if why:
        return (
            f"the folder is {why}: entries can{'not be added or' if why == 'immutable' else ' be added but not'} "
            f"removed (chattr -{'i' if why == 'immutable' else 'a'} removes that)"
        )
    try:
        st = os.stat(folder)
        probe = tempfile.mkdtemp(prefix=".probe.", dir=folder)
    except OSError as e:
        return e.strerror or str(e)
    try:
        os.rmdir(probe)
    except OSError as e:
        return f"a new entry could not be removed again ({e.strerror or e}): {probe} is left"
    try:
        os.utime(folder, ns=(st.st_atime_ns, st.st_mtime_ns))
    except OSError:
        pass  # times are not worth failing a run over
    return None


def check_replaceable(path: str | os.PathLike, what: str) -> None:
    """Raise a one-line :class:`ConfigError` naming the entry in the way unless the existing output ``path`` (a file,
    or a folder and everything in it) can be renamed and deleted; a missing ``path`` passes."""
    path = Path(path)
    if not (path.exists() or path.is_symlink()):
        return
    why = _locked(path)
    if why:
        raise ConfigError(
            f"{path}: the {what} is {why} (chattr -{'i' if why == 'immutable' else 'a'} removes that), "
            "so it cannot be replaced; nothing was written"
        )
    if path.is_symlink() or not path.is_dir():
        return
    for dirpath, dirnames, filenames in os.walk(path):
        base = Path(dirpath)
        reason = probe_folder(base)
        if reason:
            raise ConfigError(
                f"{base}: cannot replace the {what}: this folder in it cannot be changed ({reason}); "
                "nothing was written"
            )
        for name in dirnames + filenames:
            entry = base / name
            why = _locked(entry)
            if why:
                raise ConfigError(
                    f"{entry}: cannot replace the {what}: this entry in it is {why} (chattr -"
                    f"{'i' if why == 'immutable' else 'a'} removes that); nothing was written"
                )


__all__ = ["FS_APPEND_FL", "FS_IMMUTABLE_FL", "check_replaceable", "fs_flags", "probe_folder"]
