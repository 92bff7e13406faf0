"""Output safety: what a command may write where (output policy, input detection), atomic writes, staged output
folders replaced in one rename, and manifests of what was written.

Attributes are imported lazily (importing the package loads none of its modules)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "atomic_write_bytes": ".atomic",
    "atomic_write_text": ".atomic",
    "atomic_open": ".atomic",
    "StagedDir": ".staging",
    "OutputFiles": ".staging",
    "check_output_dir": ".outdir",
    "check_output_file": ".outdir",
    "validate_manifest": ".manifest",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
