"""Peak memory of a block of code, and a description of the machine (for reports).

Peak memory:

* CUDA: ``torch.cuda.max_memory_allocated`` after ``reset_peak_memory_stats`` (tensors only, as PyTorch counts them);
* CPU (Linux): the process's resident-set high-water mark ``VmHWM`` from ``/proc/self/status``, reset at the start
  by writing ``5`` to ``/proc/self/clear_refs``, minus the resident set at the start (``VmRSS``); where the reset
  is not possible the high-water mark since the process started is used (an upper bound, said in ``method``), and
  elsewhere ``resource.getrusage`` (also since process start).
"""

from __future__ import annotations

import os
import platform
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import torch

from ..devices import resolve_device  # re-exported: the commands import it from here


def _status_kb(field: str) -> int | None:
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return None
    m = re.search(rf"^{field}:\s+(\d+)\s+kB", text, re.M)
    return int(m.group(1)) if m else None


def _reset_hwm() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _rusage_max_mb() -> float | None:
    try:
        import resource  # deferred: a Unix-only module
    except ImportError:  # pragma: no cover - Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024.0 / 1024.0 if sys.platform == "darwin" else peak / 1024.0


@dataclass
class PeakMemory:
    """``with PeakMemory(device) as pm: ...`` then ``pm.peak_mb`` (MiB) and ``pm.method`` (how it was measured)."""

    device: torch.device | str = "cpu"
    peak_mb: float | None = None
    method: str = ""

    def __enter__(self) -> "PeakMemory":
        self.device = torch.device(self.device)
        self._baseline_kb = None
        self._reset = False
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
            torch.cuda.reset_peak_memory_stats(self.device)
            self._cuda_base = torch.cuda.memory_allocated(self.device)
        else:
            self._reset = _reset_hwm()
            self._baseline_kb = _status_kb("VmRSS")
        return self

    def __exit__(self, *exc) -> bool:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
            self.peak_mb = (torch.cuda.max_memory_allocated(self.device) - self._cuda_base) / 2**20
            self.method = "cuda max_memory_allocated minus the allocation at the start"
            return False
        hwm = _status_kb("VmHWM")
        if hwm is not None and self._baseline_kb is not None:
            self.peak_mb = max(hwm - self._baseline_kb, 0) / 1024.0
            self.method = (
                "cpu resident-set peak (VmHWM, reset at the start) minus the resident set at the start"
                if self._reset
                else "cpu resident-set peak since process start (VmHWM) minus the resident set at the start"
            )
        else:
            self.peak_mb = _rusage_max_mb()
            self.method = "cpu resident-set peak since process start (getrusage)"
        return False


def cpu_model(default: str) -> str:
    """The CPU model name (the first ``model name`` of ``/proc/cpuinfo``), or ``default`` where there is none."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return default


def machine_info(device: torch.device | str = "cpu") -> dict[str, object]:
    """CPU model, core count, torch threads, GPU name, versions: what a results table should name."""
    info: dict[str, object] = {
        "cpu": cpu_model(platform.processor() or platform.machine()),
        "cpu_cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "os": f"{platform.system()} {platform.release()}",
        "python": platform.python_version(),
        "torch": torch.__version__,
        "device": str(device),
    }
    device = torch.device(device)
    if device.type == "cuda" and torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(device)
    return info


__all__ = ["PeakMemory", "cpu_model", "machine_info", "resolve_device"]
