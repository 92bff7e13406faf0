"""Timing of streaming inference: per-step wall time (and process CPU time), warm-up excluded.

One measurement = one (architecture, device, precision, path, batch, resolution): build the model, select the path
(``fast`` with a dtype, or ``reference``), stream ``warmup`` frames (the first one resets) and then ``iters`` timed
frames that continue the trajectory. With batch B every step processes B frames (B independent streams), so
``ms/frame = step time / B`` and ``FPS = B / step time``.
"""

from __future__ import annotations

import contextlib
import copy
import os
import statistics
import time
from dataclasses import asdict, dataclass, field
from typing import Callable, Optional

import torch

from ..export.check import synthetic_sequence
from ..inference.fast_model import FastModel
from ..inference.graphs import make_streamer
from ..models import build_model
from ..models.config import MIDAIR_IMAGE_SIZE, ModelConfig
from ..models.model import SceneModel
from .memory import PeakMemory, exact_rss
from .noise import compare_times, spread

PRECISIONS = {"fp32": torch.float32, "bf16": torch.bfloat16, "fp16": torch.float16, "int8": "int8"}
#: int8 (CPU): synthetic frames that calibrate the activation ranges before timing (speed does not depend on them)
INT8_CALIBRATION_FRAMES = 4
#: A timed step is "quiet" when all other processes together used at most this many cores during it.
QUIET_OTHERS = 0.1


_MODEL = ModelConfig()


@dataclass
class BenchCase:
    """One measurement; the defaults are the model config's and the paper's image size."""

    arch: str = _MODEL.arch
    batch: int = 1
    height: int = MIDAIR_IMAGE_SIZE
    width: int = MIDAIR_IMAGE_SIZE
    device: str = "cpu"
    precision: str = "fp32"
    path: str = "fast"  # "fast", "reference", or "graph" (static buffers; a CUDA graph on GPU)
    warmup: int = 2
    iters: int = 10
    levels: int = _MODEL.levels
    num_classes: int = _MODEL.num_classes


@dataclass
class BenchResult:
    case: BenchCase
    params: int
    step_ms: list[float] = field(default_factory=list)
    cpu_ms: list[float] = field(default_factory=list)
    peak_mem_mb: float = 0.0
    mem_method: str = ""
    mem_exact: bool = True
    loadavg: Optional[list[float]] = None  # 1/5/15-minute load averages when the case started
    busy_before: Optional[float] = None  # CPU busy fraction (all processes) just before the case
    others: list[float] = field(default_factory=list)  # cores used by other processes during each timed step

    @property
    def ms_per_frame(self) -> list[float]:
        return [t / self.case.batch for t in self.step_ms]

    @property
    def others_cores(self) -> list[float]:
        """Cores used by other processes during each step, to 0.01 core: the values reported and judged quiet."""
        return [round(x, 2) for x in self.others]

    def quiet_ms_per_frame(self) -> list[float]:
        """Per-frame times of the quiet steps (other processes used at most ``QUIET_OTHERS`` cores)."""
        return [t for t, o in zip(self.ms_per_frame, self.others_cores) if o <= QUIET_OTHERS]

    def summary(self) -> dict:
        per_frame = sorted(self.ms_per_frame)
        quiet = self.quiet_ms_per_frame()
        med = statistics.median(per_frame)
        sp = spread(per_frame)
        d = {
            **asdict(self.case),
            "params": self.params,
            "median_ms_per_frame": round(med, 3),
            "p90_ms_per_frame": round(percentile(per_frame, 90), 3),
            "min_ms_per_frame": round(per_frame[0], 3),
            "q25_ms_per_frame": round(sp["q25"], 3),
            "q75_ms_per_frame": round(sp["q75"], 3),
            "max_ms_per_frame": round(sp["max"], 3),
            "fps": round(1000.0 / med, 2),
            "median_ms_per_step": round(statistics.median(self.step_ms), 3),
            "median_cpu_ms_per_frame": round(statistics.median(self.cpu_ms) / self.case.batch, 3)
            if self.cpu_ms
            else None,
            "peak_mem_mb": round(self.peak_mem_mb, 1),
            "mem_method": self.mem_method,
            "mem_exact": self.mem_exact,
            "quiet_steps": len(quiet),
            "quiet_median_ms_per_frame": round(statistics.median(quiet), 3) if quiet else None,
            "others_cores_per_step": self.others_cores,
            "loadavg_at_start": self.loadavg,
            "cpu_busy_before": self.busy_before,
            "step_ms": [round(t, 3) for t in self.step_ms],
        }
        return d


def percentile(sorted_values: list[float], q: float) -> float:
    """Linear-interpolation percentile of an already sorted list (numpy's default rule)."""
    if not sorted_values:
        raise ValueError("no values")
    pos = (len(sorted_values) - 1) * q / 100.0
    lo = int(pos)
    hi = min(lo + 1, len(sorted_values) - 1)
    return sorted_values[lo] + (sorted_values[hi] - sorted_values[lo]) * (pos - lo)


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def build(case: BenchCase, model: Optional[SceneModel] = None):
    """What ``case`` streams, on its device: the :class:`~cosemdepth.models.SceneModel` (path ``reference``), its
    :class:`~cosemdepth.inference.FastModel` (``fast``) or a static-buffer streamer (``graph``); ``model``: use
    these weights."""
    if case.precision == "int8" and torch.device(case.device).type != "cpu":
        raise ValueError(f"precision int8 runs on the CPU only, not on {case.device}")
    if model is None:
        torch.manual_seed(0)
        model = build_model(ModelConfig(arch=case.arch, levels=case.levels, num_classes=case.num_classes))
    model = model.to(case.device).eval()
    if case.path == "graph":
        return _GraphStepper(model, case)
    if case.path == "fast" and case.precision == "int8":
        rgb, rot, trans, intr = make_frames(case, INT8_CALIBRATION_FRAMES)
        frames = [
            (rgb[:, k], rot[:, k], trans[:, k], intr, torch.full((case.batch,), k == 0)) for k in range(rgb.shape[1])
        ]
        return FastModel(model, dtype="int8", calibration=frames)
    if case.path == "fast":
        return FastModel(model, dtype=PRECISIONS[case.precision])
    if case.path == "reference":
        if case.precision != "fp32":
            raise ValueError("the reference path runs in fp32 only")
        return model
    raise ValueError(f"path must be 'fast', 'graph' or 'reference', got {case.path!r}")


class _GraphStepper:
    """``step`` over a :class:`StaticStreamer` (a CUDA graph on GPU; the same static program eagerly on CPU)."""

    def __init__(self, model: SceneModel, case: BenchCase):
        self.model = model
        self.streamer = make_streamer(
            model, case.batch, case.height, case.width, dtype=PRECISIONS[case.precision], device=case.device
        )

    def step(self, rgb, rot, trans, intrinsics, reset, state):
        return self.streamer.step(rgb, rot, trans, intrinsics, reset), None

    def num_parameters(self) -> int:
        return self.model.num_parameters()


def make_frames(case: BenchCase, n: int = 4):
    """``n`` synthetic frames (cycled while streaming) on the case's device."""
    rgb, rot, trans, intr = synthetic_sequence(case.batch, n, case.height, case.width, seed=1)
    dev = torch.device(case.device)
    return rgb.to(dev), rot.to(dev), trans.to(dev), intr.to(dev)


def time_stream(
    steps: list[Callable[..., object]],
    case: BenchCase,
    frames=None,
) -> tuple[list[float], list[float], list[float]]:
    """Stream through every callable of ``steps`` in turn per frame (one model, or several run one after the other).

    Returns, per timed frame: wall milliseconds, this process's CPU milliseconds, and the cores used meanwhile by all
    other processes (from /proc/stat; empty where unavailable)."""
    dev = torch.device(case.device)
    rgb, rot, trans, intr = frames if frames is not None else make_frames(case)
    n = rgb.shape[1]
    states = [None] * len(steps)
    no_reset = torch.zeros(case.batch, dtype=torch.bool, device=dev)
    all_reset = torch.ones(case.batch, dtype=torch.bool, device=dev)
    wall, cpu, others = [], [], []
    with torch.inference_mode():
        for k in range(case.warmup + case.iters):
            i = k % n
            reset = all_reset if k == 0 else no_reset
            _sync(dev)
            b0 = _busy_seconds()
            t0, c0 = time.perf_counter(), time.process_time()
            for s, fn in enumerate(steps):
                _, states[s] = fn(rgb[:, i], rot[:, i], trans[:, i], intr, reset, states[s])
            _sync(dev)
            t1, c1 = time.perf_counter(), time.process_time()
            b1 = _busy_seconds()
            if k >= case.warmup:
                wall.append((t1 - t0) * 1e3)
                cpu.append((c1 - c0) * 1e3)
                if b0 is not None and b1 is not None:
                    # CPU seconds used by every other process during the step, per second of the step
                    others.append(max(b1 - b0 - (c1 - c0), 0.0) / max(t1 - t0, 1e-9))
    return wall, cpu, others


def _memory_pass(case: BenchCase, make_steps, frames) -> PeakMemory:
    """Peak memory of building the model(s) and streaming a reset frame and a normal one (the normal one is the
    peak: the refiners run), measured apart from the timing because exact CPU accounting slows allocation."""
    short = BenchCase(**{**asdict(case), "warmup": 0, "iters": 2})
    dev = torch.device(case.device)
    with exact_rss() if dev.type == "cpu" else contextlib.nullcontext():
        with PeakMemory(dev) as pm:
            steps = make_steps()
            time_stream(steps, short, frames)
            del steps
    return pm


def run_case(case: BenchCase, model: Optional[SceneModel] = None) -> BenchResult:
    """Build, warm up and time one case; then a separate pass measures the peak memory of building and streaming."""
    frames = make_frames(case)
    load = _loadavg()
    m = build(case, copy.deepcopy(model) if model is not None else None)
    wall, cpu, others = time_stream([m.step], case, frames)
    params = m.num_parameters()
    del m
    pm = _memory_pass(case, lambda: [build(case, copy.deepcopy(model) if model is not None else None).step], frames)
    res = BenchResult(case, params, wall, cpu, pm.extra / 2**20, pm.method, pm.exact, load)
    res.others = others
    return res


def run_separate(case: BenchCase) -> BenchResult:
    """M4Depth then M4Semantic on every frame (two models resident): the baseline of the joint-vs-separate check."""
    frames = make_frames(case)
    load = _loadavg()
    cases = [BenchCase(**{**asdict(case), "arch": a}) for a in ("m4depth", "m4semantic")]
    models = [build(c) for c in cases]
    wall, cpu, others = time_stream([m.step for m in models], case, frames)
    params = sum(m.num_parameters() for m in models)
    del models
    pm = _memory_pass(case, lambda: [build(c).step for c in cases], frames)
    res = BenchResult(BenchCase(**{**asdict(case), "arch": "m4depth+m4semantic"}), params, wall, cpu)
    res.others = others
    res.peak_mem_mb, res.mem_method, res.mem_exact, res.loadavg = pm.extra / 2**20, pm.method, pm.exact, load
    return res


def joint_vs_separate(joint: BenchResult, separate: BenchResult, min_quiet: int = 3) -> dict:
    """Time, parameters and peak memory of the joint model against the two single-task models run one after the
    other. Times compare the quiet steps when both runs have at least ``min_quiet`` of them, else all steps
    (``time_basis`` says which); ``joint_faster`` is "yes", "no" or "within noise" (:func:`.noise.compare_times`:
    the interquartile ranges of the two overlap), with each side's spread (min, quartiles, median, max)."""
    j, s = joint.summary(), separate.summary()
    quiet = (j["quiet_steps"] or 0) >= min_quiet and (s["quiet_steps"] or 0) >= min_quiet
    key = "quiet_median_ms_per_frame" if quiet else "median_ms_per_frame"
    jt = joint.quiet_ms_per_frame() if quiet else joint.ms_per_frame
    st = separate.quiet_ms_per_frame() if quiet else separate.ms_per_frame
    verdict = compare_times(jt, st)
    rounded = lambda d: {k: round(v, 3) for k, v in d.items()}  # noqa: E731
    return {
        "precision": joint.case.precision,
        "path": joint.case.path,
        "batch": joint.case.batch,
        "height": joint.case.height,
        "width": joint.case.width,
        "device": joint.case.device,
        "time_basis": "quiet steps" if quiet else "all steps",
        "joint_median_ms_per_frame": j[key],
        "separate_median_ms_per_frame": s[key],
        "joint_all_steps_median_ms_per_frame": j["median_ms_per_frame"],
        "separate_all_steps_median_ms_per_frame": s["median_ms_per_frame"],
        "joint_quiet_steps": j["quiet_steps"],
        "separate_quiet_steps": s["quiet_steps"],
        "joint_params": j["params"],
        "separate_params": s["params"],
        "joint_peak_mem_mb": j["peak_mem_mb"],
        "separate_peak_mem_mb": s["peak_mem_mb"],
        "joint_spread_ms_per_frame": rounded(spread(jt)),
        "separate_spread_ms_per_frame": rounded(spread(st)),
        "joint_faster": {"faster": "yes", "slower": "no"}.get(verdict, verdict),
        "joint_smaller_memory": j["peak_mem_mb"] < s["peak_mem_mb"],
        "joint_fewer_params": j["params"] < s["params"],
    }


def _loadavg() -> Optional[list[float]]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:  # pragma: no cover
        return None


_CLK_TCK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def _busy_seconds() -> Optional[float]:
    """CPU seconds spent busy by all processes since boot (/proc/stat), or None."""
    try:
        with open("/proc/stat") as f:
            vals = [int(v) for v in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    idle = vals[3] + (vals[4] if len(vals) > 4 else 0)
    return (sum(vals[:8]) - idle) / _CLK_TCK


def cpu_busy_fraction(window: float = 1.0) -> Optional[float]:
    """Fraction of all CPU time spent busy (any process) over ``window`` seconds, from /proc/stat; None if unknown."""

    def read():
        with open("/proc/stat") as f:
            vals = [int(v) for v in f.readline().split()[1:]]
        idle = vals[3] + (vals[4] if len(vals) > 4 else 0)
        return sum(vals), idle

    try:
        t0, i0 = read()
        time.sleep(window)
        t1, i1 = read()
    except (OSError, ValueError, IndexError):
        return None
    return 1.0 - (i1 - i0) / max(t1 - t0, 1)


def wait_for_idle(max_busy: float, timeout: float, window: float = 1.0) -> Optional[float]:
    """Wait (up to ``timeout`` s) until the machine is at most ``max_busy`` busy; returns the last busy fraction.

    On a shared machine other processes preempt the benchmark's threads, and a multi-threaded step waits for its
    slowest thread: timings taken under load can be many times the quiet ones.
    """
    deadline = time.monotonic() + timeout
    busy = cpu_busy_fraction(window)
    while busy is not None and busy > max_busy and time.monotonic() < deadline:
        busy = cpu_busy_fraction(window)
    return None if busy is None else round(busy, 3)
