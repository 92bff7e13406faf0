"""The command line's error boundary: which exceptions are the user's input or environment, and their one line.

:func:`error_line` returns the message ``cosemdepth CMD: error: ...`` prints (exit 2) for:

* a :class:`~cosemdepth.errors.CosemdepthError` (bad input: its message), also one raised in a data-loading worker
  (PyTorch re-raises it with the worker's traceback in the message: the original message is kept);
* a failed import of a third-party module (:func:`cosemdepth.optional.missing_package`: what to install);
* a file-system error (:class:`OSError`, or a library error carrying one: ``[Errno N]``, Rust's ``os error N``)
  that names a file, or whose errno is an environment problem (:data:`ENVIRONMENT_ERRNOS`: a full disk, a quota, a
  read-only or immutable folder, too many open files...), with what to do about it;
* memory exhaustion (:class:`MemoryError`, CUDA out of memory, the CPU allocator's failure).

Anything else is a bug and keeps its traceback. The commands write through temporary files and staged folders, so
an error that reaches this boundary has left no partial output behind.
"""

from __future__ import annotations

import errno
import os
import re

from ..errors import CosemdepthError
from ..optional import missing_package

#: errno -> what to do, for the errors that come from the machine rather than from the program.
ENVIRONMENT_ERRNOS: dict[int, str] = {
    errno.ENOSPC: "the disk is full: free some space, or write the output to another disk",
    errno.EDQUOT: "the disk quota is exceeded: free some space, or write the output elsewhere",
    errno.EFBIG: "the file is larger than the file system or the process's file-size limit (ulimit -f) allows: "
    "write it elsewhere or raise the limit",
    errno.EROFS: "the file system is read-only: choose a path on a writable disk",
    errno.EACCES: "check the permissions, or choose another path",
    errno.EPERM: "the file or folder may be immutable or append-only (lsattr shows it): choose another path",
    errno.EMFILE: "too many open files: raise the limit (ulimit -n), or use fewer --workers",
    errno.ENFILE: "too many open files on this system: close some programs, or use fewer --workers",
    errno.EIO: "an input/output error: the disk or network file system failed; check it and run again",
    errno.ENOMEM: "out of memory: use a smaller --size or batch, or free some memory",
    errno.ENAMETOOLONG: "the file name is too long: choose a shorter path",
}

#: How libraries write an errno into the messages of their own exception types.
_ERRNO_PATTERNS = (re.compile(r"\[Errno (\d+)\]"), re.compile(r"os error (\d+)"), re.compile(r"errno = (\d+)"))

#: The allocators' messages when memory runs out (PyTorch's CPU allocator, CUDA, MPS).
_OUT_OF_MEMORY = re.compile(r"can't allocate memory|not enough memory|out of memory|failed to allocate", re.IGNORECASE)


def error_line(e: BaseException, outputs: list[str] = ()) -> str | None:
    """The one-line message for ``e`` if it is an input or environment problem, else None (see the module docstring).
    ``outputs``: how the command's output arguments read (``--out runs/a``), named when an error names no file."""
    if isinstance(e, CosemdepthError):
        return _one_line(_worker_message(str(e)))
    missing = missing_package(e)
    if missing is not None:
        return missing
    os_error = os_error_in(e)
    if os_error is not None:  # libraries put line breaks in theirs (h5py: the HDF5 error stack)
        return _one_line(_os_error_line(os_error, outputs))
    if out_of_memory(e):
        advice = ENVIRONMENT_ERRNOS[errno.ENOMEM]
        return f"{_one_line(_worker_message(str(e)) or type(e).__name__)[:300]}; {advice}"
    return None


def os_error_in(e: BaseException) -> OSError | None:
    """The file-system error behind ``e`` (``e`` itself, an exception it was raised from, or an errno a library wrote
    into its message), if it names a file or is an environment problem; else None."""
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno is not None:
            if e.filename is not None or e.errno in ENVIRONMENT_ERRNOS:
                return e
        elif not isinstance(e, CosemdepthError):
            for pattern in _ERRNO_PATTERNS:
                m = pattern.search(str(e))
                if m and int(m.group(1)) in ENVIRONMENT_ERRNOS:
                    code = int(m.group(1))
                    return OSError(code, os.strerror(code))
        e = e.__cause__ or e.__context__
    return None


def out_of_memory(e: BaseException) -> bool:
    """Whether ``e`` says that memory ran out (a MemoryError, or an allocator's RuntimeError)."""
    if isinstance(e, MemoryError):
        return True
    name = type(e).__name__
    return isinstance(e, RuntimeError) and (name == "OutOfMemoryError" or bool(_OUT_OF_MEMORY.search(str(e))))


def _os_error_line(e: OSError, outputs) -> str:
    where = e.filename if e.filename2 is None else f"{e.filename} -> {e.filename2}"
    reason = e.strerror or os.strerror(e.errno)
    advice = ENVIRONMENT_ERRNOS.get(e.errno)
    if where is None:
        where = "writing " + ", ".join(outputs) if outputs else "a file"
        return f"{where}: {reason}" + (f"; {advice}" if advice else "")
    return f"{where}: {reason}" + (f"; {advice}" if advice and e.errno not in (errno.ENOENT, errno.EACCES) else "")


def _worker_message(text: str) -> str:
    """The original message of an exception PyTorch re-raised from a DataLoader worker (``Caught X in DataLoader
    worker process N. Original Traceback ... module.X: message``); other messages unchanged."""
    if "Original Traceback" not in text:
        return text
    last = [line for line in text.splitlines() if line.strip()][-1]
    return re.sub(r"^[\w.]+: ", "", last.strip(), count=1)


def _one_line(text: str) -> str:
    # whatever a wrapped library message holds (YAML and JSON parsers put line breaks in theirs)
    return "; ".join(part.strip() for part in text.splitlines() if part.strip())


__all__ = ["ENVIRONMENT_ERRNOS", "error_line", "os_error_in", "out_of_memory"]
