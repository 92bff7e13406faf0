"""The measurement harness: run metadata, a timing helper, and the one JSON shape of every benchmark result.

Every result file, whether written by an installed command (``cosemdepth benchmark``, ``cosemdepth fast-accuracy``)
or by a repository script (``benchmarks/*.py``), has this shape::

    {"tool": str,          # the script or command that wrote it ("conv_peak", "cosemdepth fast-accuracy")
     "schema": 1,          # SCHEMA
     "meta": {...},        # run_meta(): every key of META_KEYS; null where a value is not known
     "params": {...},      # what the run was asked to do (its arguments)
     "results": ...}       # what it measured (a dict or a list)

A tool may add further top-level sections of its own (``cosemdepth benchmark``: ``joint_vs_separate``).
:func:`validate` lists what is wrong with a report; :func:`write_report` refuses to write one that is invalid.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import shlex
import statistics
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path
from typing import Any, Callable, Mapping, Optional

import torch

from ..evaluation.evaluator import to_json
from ..output_safety.atomic import atomic_write_text

#: Version of the report shape below; a change of the shape raises it.
SCHEMA = 1
#: The top-level keys every report has.
TOP_KEYS = ("tool", "schema", "meta", "params", "results")
#: The keys of ``meta`` (run_meta's), each present in every report; ``None`` where not known (e.g. ``git_commit``
#: outside a checkout, ``onnxruntime`` when it is not installed, fields an older run did not record).
META_KEYS = (
    "date_utc",  # ISO 8601, "2026-12-04T10:00:00Z"
    "machine",  # OS, kernel and architecture (platform.platform())
    "cpu_model",  # /proc/cpuinfo's "model name"
    "cpu_flags",  # {flag: bool} for CPU_FLAGS
    "cpu_capability",  # the vector extension PyTorch's CPU kernels use ("AVX512", "AVX2"...)
    "cpu_count",  # logical CPUs the OS reports
    "threads",  # torch intra-op threads during the run
    "python",
    "torch",
    "numpy",
    "onnxruntime",
    "git_commit",  # the checkout the package was imported from
    "git_dirty",  # whether that checkout had uncommitted changes to tracked files
    "command",  # the command line of the run
    "loadavg",  # 1, 5 and 15-minute load averages at the start
)
#: The CPU flags that decide which kernels run (AVX2/AVX-512 fp32, bf16 and int8 dot products, AMX tiles).
CPU_FLAGS = ("avx2", "avx512f", "avx512_bf16", "avx512_vnni", "amx_tile", "amx_bf16", "amx_int8")
#: Meta keys a report must give a value for (the others may be null).
REQUIRED_META = ("date_utc", "torch")

_THIS = Path(__file__).resolve()
#: This file's path inside a checkout of the project (how the checkout is recognised).
_PATH_IN_CHECKOUT = Path("src", "cosemdepth", "bench", "harness.py")


def _cpuinfo() -> str:
    try:
        return Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return ""


def cpu_model(text: Optional[str] = None) -> Optional[str]:
    """The first ``model name`` of ``/proc/cpuinfo`` (or of ``text``), else ``None``."""
    for line in (_cpuinfo() if text is None else text).splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return None


def cpu_flags(text: Optional[str] = None) -> Optional[dict[str, bool]]:
    """``{flag: present}`` for :data:`CPU_FLAGS`, from the first ``flags`` line of ``/proc/cpuinfo`` (or ``text``);
    ``None`` where there is no such line (not Linux, or not x86)."""
    for line in (_cpuinfo() if text is None else text).splitlines():
        if line.startswith("flags"):
            have = set(line.split(":", 1)[1].split())
            return {f: f in have for f in CPU_FLAGS}
    return None


def git_state(path: Path = _THIS) -> tuple[Optional[str], Optional[bool]]:
    """``(commit, dirty)`` of the checkout ``path`` (this module) belongs to; ``(None, None)`` when the package was
    not imported from a checkout of the project (an installed wheel) or git is not available."""

    def git(*args: str) -> Optional[str]:
        try:
            done = subprocess.run(["git", "-C", str(path.parent), *args], capture_output=True, text=True, timeout=10)
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    top = git("rev-parse", "--show-toplevel")
    if top is None or Path(top).resolve() / _PATH_IN_CHECKOUT != path:
        return None, None
    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no")
    return commit, (None if status is None else bool(status))


def _version(dist: str) -> Optional[str]:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def _loadavg() -> Optional[list[float]]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:  # pragma: no cover - no load average on this OS
        return None


def command_line(argv: Optional[list[str]] = None) -> str:
    """The command line of this run: ``python benchmarks/x.py ARGS`` for a script, ``cosemdepth CMD ARGS`` for the
    CLI (its ``argv`` passed in)."""
    argv = list(sys.argv if argv is None else argv)
    if argv and argv[0].endswith(".py"):
        script = Path(argv[0])
        try:
            script = script.resolve().relative_to(Path.cwd())
        except ValueError:
            pass
        argv = ["python", str(script), *argv[1:]]
    return shlex.join(argv)


def run_meta(device: str = "cpu", command: Optional[str] = None, **extra: Any) -> dict[str, Any]:
    """What the numbers were measured on: every key of :data:`META_KEYS` (and, on CUDA, ``gpu`` and ``cuda``), plus
    ``extra``."""
    commit, dirty = git_state()
    meta: dict[str, Any] = {
        "date_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "machine": platform.platform(),
        "cpu_model": cpu_model() or platform.processor() or None,
        "cpu_flags": cpu_flags(),
        "cpu_capability": _cpu_capability(),
        "cpu_count": os.cpu_count(),
        "threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": _version("numpy"),
        "onnxruntime": _version("onnxruntime"),
        "git_commit": commit,
        "git_dirty": dirty,
        "command": command if command is not None else command_line(),
        "loadavg": _loadavg(),
    }
    if torch.device(device).type == "cuda" and torch.cuda.is_available():
        meta["gpu"] = torch.cuda.get_device_name(torch.device(device))
        meta["cuda"] = torch.version.cuda
    meta.update(extra)
    return meta


def _cpu_capability() -> Optional[str]:
    try:
        return torch.backends.cpu.get_cpu_capability()
    except (AttributeError, RuntimeError):  # pragma: no cover - exotic builds
        return None


def time_calls(
    fn: Callable[[], Any], *, warmup: int = 1, iters: int = 10, sync: Optional[Callable[[], Any]] = None
) -> list[float]:
    """Seconds of each of ``iters`` calls of ``fn()`` after ``warmup`` untimed ones (``time.perf_counter``;
    ``sync()``, e.g. ``torch.cuda.synchronize``, runs before each clock reading)."""
    if iters < 1:
        raise ValueError(f"iters must be at least 1, got {iters}")
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(iters):
        if sync:
            sync()
        t0 = time.perf_counter()
        fn()
        if sync:
            sync()
        out.append(time.perf_counter() - t0)
    return out


def summarize(times: list[float], scale: float = 1.0, digits: int = 4) -> dict[str, float]:
    """``{"n", "median", "min", "max", "mean"}`` of ``times`` times ``scale`` (e.g. 1e3 for milliseconds)."""
    if not times:
        raise ValueError("no times to summarize")
    xs = [t * scale for t in times]
    return {
        "n": len(xs),
        "median": round(statistics.median(xs), digits),
        "min": round(min(xs), digits),
        "max": round(max(xs), digits),
        "mean": round(statistics.fmean(xs), digits),
    }


def make_report(
    tool: str, params: Mapping[str, Any], results: Any, *, meta: Optional[Mapping[str, Any]] = None, **sections: Any
) -> dict[str, Any]:
    """A report of the shape above (``meta`` defaults to :func:`run_meta` now); ``sections`` are extra top-level
    sections."""
    clash = set(sections) & set(TOP_KEYS)
    if clash:
        raise ValueError(f"extra sections may not be named {sorted(clash)}")
    report = {
        "tool": tool,
        "schema": SCHEMA,
        "meta": dict(run_meta() if meta is None else meta),
        "params": dict(params),
        "results": results,
    }
    report.update(sections)
    return report


def validate(report: Any) -> list[str]:
    """What is wrong with ``report`` against the shape above (an empty list: nothing)."""
    if not isinstance(report, dict):
        return [f"a report is a JSON object, not {type(report).__name__}"]
    problems = [f"missing top-level key {k!r}" for k in TOP_KEYS if k not in report]
    if "tool" in report and not (isinstance(report["tool"], str) and report["tool"]):
        problems.append("'tool' must be a non-empty string")
    if "schema" in report and report["schema"] != SCHEMA:
        problems.append(f"'schema' must be {SCHEMA}, got {report['schema']!r}")
    if "params" in report and not isinstance(report["params"], dict):
        problems.append("'params' must be an object")
    if "results" in report and not isinstance(report["results"], (dict, list)):
        problems.append("'results' must be an object or a list")
    meta = report.get("meta")
    if "meta" in report and not isinstance(meta, dict):
        problems.append("'meta' must be an object")
    elif isinstance(meta, dict):
        problems += [f"meta lacks {k!r} (null when not known)" for k in META_KEYS if k not in meta]
        problems += [f"meta {k!r} must not be null" for k in REQUIRED_META if k in meta and meta[k] is None]
        date = meta.get("date_utc")
        if isinstance(date, str):
            try:
                _dt.datetime.strptime(date, "%Y-%m-%dT%H:%M:%SZ")
            except ValueError:
                problems.append(f"meta 'date_utc' must be YYYY-MM-DDTHH:MM:SSZ, got {date!r}")
        elif date is not None:
            problems.append("meta 'date_utc' must be a string")
        flags = meta.get("cpu_flags")
        if flags is not None and not (
            isinstance(flags, dict)
            and set(flags) == set(CPU_FLAGS)
            and all(isinstance(v, bool) for v in flags.values())
        ):
            problems.append(f"meta 'cpu_flags' must map exactly {list(CPU_FLAGS)} to true/false, or be null")
        for k in ("cpu_count", "threads"):
            v = meta.get(k)
            if v is not None and not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                problems.append(f"meta {k!r} must be a positive integer or null")
    return problems


def write_report(path: str | os.PathLike, report: Mapping[str, Any]) -> Path:
    """Write ``report`` as strict JSON (NaN and infinities as null) to ``path`` (temp file + rename); a ValueError,
    nothing written, when it does not have the shape above."""
    problems = validate(report)
    if problems:
        raise ValueError(f"not a valid benchmark report: {'; '.join(problems)}")
    path = Path(path)
    atomic_write_text(path, to_json(report))
    return path
