"""One command that validates a GPU: ``scripts/gpu_check.sh`` (``python -m cosemdepth.cli.gpu_check``; its arguments:
:mod:`cosemdepth.cli.gpu_check`).

Stages, in order, each recorded in one JSON report (rewritten after every stage, so a run stopped part-way still
leaves what it measured):

* ``cuda_tests``: the device tests of the suite (:data:`CUDA_TEST_FILES`) under pytest, on this machine's device;
* ``streaming``: batch-1 streaming at the check's size in fp32, fp16 and bf16, on the fast path and as a CUDA graph
  (``path = graph``), each timed and compared with the PyTorch reference path in float32 on the same flight;
* ``batched``: frames/s of the fast path at the batch sizes of ``--batched`` in fp16 and bf16;
* ``training``: training steps/s (the trainer's step: forward over a sequence, loss, backward, Adam) in fp32 and
  with bf16 autocast;
* ``ddp``: ``cosemdepth train`` under ``torchrun`` with 2 processes (needs 2 GPUs);
* ``onnxruntime``: the exported graph (``export_onnx``) run by ONNX Runtime's CUDA and TensorRT execution
  providers, each timed and compared with the PyTorch reference;
* ``tensorrt``: a TensorRT fp16 engine built from the same graph, timed and compared alike.

Every stage that cannot run here says why (``status = "not_run"`` and ``reason``); a stage whose outputs are further
from the PyTorch reference than its tolerance (:data:`TOLERANCES`) is ``"failed"``; one that raised is ``"error"``
with the message. The exit status is 1 when a stage failed or raised, else 0.

``--dry-run`` plans and runs the same stages on the CPU at a tiny size: what is meaningful there runs (fp32 and bf16
streaming, batched, training, ONNX Runtime's CPU provider in place of the GPU ones), the rest is reported as not run
with the reason. The test suite runs it.

The time budget (``--budget``, seconds) is shared by the stages: a stage that starts after it is spent is not run
(reason: the budget).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import torch

from ..models.outputs import StreamState

#: Schema name and version of the report (``schema`` key).
SCHEMA = "cosemdepth-gpu-check/1"
#: Stage names in the order they run.
STAGES = ("cuda_tests", "streaming", "batched", "training", "ddp", "onnxruntime", "tensorrt")
#: The test files whose tests run on the machine's device.
CUDA_TEST_FILES = (
    "tests/inference/test_device_paths.py",
    "tests/test_devices.py",
    "tests/inference/test_static_streamer.py",
)
#: Seconds all stages together may take (the check's promise: at most 8 minutes on one GPU).
DEFAULT_BUDGET_S = 480.0
#: The weights the check runs (shipped with the repository); a seeded random model when absent.
DEFAULT_WEIGHTS = "weights/synthair-cosemdepth"
#: Image size of the real run and of the dry run.
GPU_SIZE, DRY_SIZE = 384, 64
#: Frames of the flight every output comparison streams (frame 0 resets).
COMPARE_FRAMES = 6
#: Batch sizes of the batched stage (real run, dry run).
GPU_BATCHES, DRY_BATCHES = (8, 32), (2,)
#: Tolerances against the float32 PyTorch reference path on the same flight: the median relative depth difference
#: over the valid pixels (worst frame) and the share of equal argmax labels (worst frame). ``fp32``: float32
#: arithmetic with another summation order (TF32 off); ``reduced``: float16, bfloat16 or TF32 arithmetic.
TOLERANCES = {
    "fp32": {"depth_median_rel": 2e-3, "labels_equal": 0.999},
    "reduced": {"depth_median_rel": 2e-2, "labels_equal": 0.99},
}


@dataclass
class Plan:
    """What one run does: device, size, frames, batches, budget, output."""

    device: str
    size: int
    dry_run: bool
    batches: tuple[int, ...]
    budget_s: float
    warmup: int
    iters: int
    train_steps: int
    weights: Optional[str]
    out: Path
    keep: Optional[Path] = None  # folder for the exported graph and engine (default: a temporary one)
    stages: tuple[str, ...] = STAGES


@dataclass
class Stage:
    name: str
    status: str = "not_run"  # "ok", "failed", "error", "not_run"
    reason: Optional[str] = None
    seconds: float = 0.0
    results: list[dict] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "status": self.status,
            "reason": self.reason,
            "seconds": round(self.seconds, 2),
            "results": self.results,
        }


class NotRun(Exception):
    """A stage (or one row of it) cannot run here; the message is the reason."""


# ---------------------------------------------------------------------------------------------------- comparisons
def compare_outputs(ref: list, got: list, resets: list[bool]) -> dict:
    """Per-frame distance of ``got`` to ``ref`` (lists of ``(depth [B,1,H,W] | None, semantic [B,N,H,W] | None)``
    numpy pairs): the worst frame's median relative depth difference over the pixels where the reference depth is
    finite and positive (reset frames left out: no depth), and the worst frame's share of equal argmax labels."""
    depth_rel, labels = [], []
    for (rd, rs), (gd, gs), reset in zip(ref, got, resets):
        if rd is not None and gd is not None and not reset:
            ok = np.isfinite(rd) & (rd > 0)
            if ok.any():
                rel = np.abs(gd[ok] - rd[ok]) / rd[ok]
                depth_rel.append(float(np.median(rel)) if np.isfinite(rel).all() else float("inf"))
        if rs is not None and gs is not None:
            labels.append(float(np.mean(rs.argmax(1) == gs.argmax(1))))
    return {
        "depth_median_rel": max(depth_rel) if depth_rel else None,
        "labels_equal": min(labels) if labels else None,
        "frames": len(ref),
    }


def within(metrics: dict, tolerance: str) -> bool:
    tol = TOLERANCES[tolerance]
    d, lab = metrics.get("depth_median_rel"), metrics.get("labels_equal")
    return (d is None or d <= tol["depth_median_rel"]) and (lab is None or lab >= tol["labels_equal"])


def compare_stream(step: Callable, reference, frames, device: str) -> dict:
    """Stream ``frames = (rgb [B,T,3,H,W], rot, trans, intrinsics)`` (frame 0 resets) through ``step`` (the
    ``SceneModel.step`` contract, its state fed back) and, frame by frame on the same inputs and the same incoming
    state (``step``'s own), through ``reference`` (a float32 model on ``device``, TF32 off): like with like, so that
    rounding differences are not compounded through the recurrence. Returns :func:`compare_outputs` of sample 0."""
    rgb, rot, trans, intr = (t.to(device) for t in frames)
    b, n = rgb.shape[:2]
    ref_dev = next(reference.parameters()).device
    state, ref_outs, outs = None, [], []
    numpy = lambda t: None if t is None else t[:1].detach().float().cpu().numpy().copy()  # noqa: E731
    with torch.inference_mode():
        for k in range(n):
            reset = torch.full((b,), k == 0, dtype=torch.bool, device=device)
            args = (rgb[:, k], rot[:, k], trans[:, k], intr, reset)
            st_ref = (
                None
                if state is None or not state.flatten()
                else StreamState(
                    **{c: tuple(t.to(ref_dev, torch.float32) for t in v) for c, v in state.components.items()}
                )
            )
            with _no_tf32():
                ref, _ = reference.step(*(a.to(ref_dev) for a in args), st_ref)
            out, state = step(*args, state)
            ref_outs.append((numpy(ref.depth), numpy(ref.semantic)))
            outs.append((numpy(out.depth), numpy(out.semantic)))
    return compare_outputs(ref_outs, outs, [k == 0 for k in range(n)])


class _StatefulGraph:
    """A :class:`StaticStreamer` behind ``step`` returning its state buffers (a copy) as the next state."""

    def __init__(self, graph_stepper):
        self.streamer = graph_stepper.streamer

    def step(self, rgb, rot, trans, intrinsics, reset, state):
        out = self.streamer.step(rgb, rot, trans, intrinsics, reset)
        return out, self.streamer.current_state()


def time_steps(step: Callable, frames, device: str, warmup: int, iters: int) -> dict:
    """Median and spread of the wall time per step over ``iters`` steps after ``warmup`` (state carried)."""
    rgb, rot, trans, intr = (t.to(device) for t in frames)
    b, n = rgb.shape[:2]
    dev = torch.device(device)
    state, times = None, []
    with torch.inference_mode():
        for k in range(warmup + iters):
            reset = torch.full((b,), k == 0, dtype=torch.bool, device=device)
            i = k % n
            _sync(dev)
            t0 = time.perf_counter()
            _, state = step(rgb[:, i], rot[:, i], trans[:, i], intr, reset, state)
            _sync(dev)
            if k >= warmup:
                times.append((time.perf_counter() - t0) * 1e3)
    med = statistics.median(times)
    return {
        "batch": int(b),
        "median_ms_per_step": round(med, 3),
        "min_ms_per_step": round(min(times), 3),
        "max_ms_per_step": round(max(times), 3),
        "median_ms_per_frame": round(med / b, 3),
        "frames_per_s": round(1e3 * b / med, 2),
        "timed_steps": iters,
    }


def _sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


# ---------------------------------------------------------------------------------------------------- the stages
class Check:
    """Runs the stages of a :class:`Plan` and writes the report after each."""

    def __init__(self, plan: Plan):
        self.plan = plan
        self.cuda = plan.device.startswith("cuda")
        self.t0 = time.monotonic()
        self.stages: list[Stage] = []
        self._model = None
        self._frames = None
        self._reference = None
        self._onnx: dict[bool, Path] = {}
        self._tmp = None

    # ---- shared inputs
    def model(self):
        """The float32 model on the CPU (its modules); copies are moved and given their path per row."""
        if self._model is None:
            from ..models import build_model
            from ..models.config import ModelConfig

            w = self.plan.weights
            if w and Path(w).is_dir():
                from ..checkpoints.model_io import load_model

                self._model = load_model(w, "cpu", mode="reference")
            else:
                torch.manual_seed(0)
                levels = 3 if self.plan.dry_run else ModelConfig().levels
                self._model = build_model(ModelConfig(levels=levels)).eval()
        return self._model

    def frames(self, batch: int = 1):
        if self._frames is None:  # a rendered SynthAir flight; the dry run's smooth noise frames cost nothing to make
            from ..export.check import flight_sequence, synthetic_sequence

            make = synthetic_sequence if self.plan.dry_run else flight_sequence
            self._frames = make(1, COMPARE_FRAMES, self.plan.size, self.plan.size)
        return tuple(t.expand(batch, *t.shape[1:]).contiguous() for t in self._frames)

    def reference(self):
        """The model's reference path in float32 on the check's device (run with TF32 off)."""
        if self._reference is None:
            import copy

            self._reference = copy.deepcopy(self.model()).to(self.plan.device)
        return self._reference

    def compare(self, step: Callable, device: Optional[str] = None) -> dict:
        return compare_stream(step, self.reference(), self.frames(), device or self.plan.device)

    def workdir(self) -> Path:
        if self.plan.keep is not None:
            self.plan.keep.mkdir(parents=True, exist_ok=True)
            return self.plan.keep
        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="gpu-check-")
        return Path(self._tmp.name)

    def onnx_graph(self, reset_float: bool = False) -> Path:
        """The model's streaming step exported at the check's size, batch 1 (``reset_float``: for TensorRT)."""
        if reset_float not in self._onnx:
            from ..export.onnx import export_onnx

            name = "step-reset-float.onnx" if reset_float else "step.onnx"
            self._onnx[reset_float] = export_onnx(
                self.model(), self.workdir() / name, self.plan.size, self.plan.size, reset_float=reset_float
            )
        return self._onnx[reset_float]

    # ---- running
    def left_s(self) -> float:
        return self.plan.budget_s - (time.monotonic() - self.t0)

    def run(self) -> dict:
        for name in STAGES:
            stage = Stage(name)
            self.stages.append(stage)
            if name not in self.plan.stages:
                stage.reason = "not selected (--stages)"
            elif self.left_s() <= 0:
                stage.reason = f"the time budget ({self.plan.budget_s:g} s) was spent before this stage"
            else:
                t = time.monotonic()
                try:
                    getattr(self, "stage_" + name)(stage)
                    ran = [r for r in stage.results if r.get("status", "ok") != "not_run"]
                    if stage.status == "not_run" and ran:
                        stage.status = "ok"
                    elif stage.status == "not_run":  # every row planned, none could run here
                        stage.reason = "; ".join(dict.fromkeys(r.get("reason", "") for r in stage.results))
                except NotRun as e:
                    stage.status, stage.reason = "not_run", str(e)
                except Exception as e:  # noqa: BLE001 - a broken stage is reported, the others still run
                    stage.status = "error"
                    stage.reason = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
                    stage.results.append({"traceback": traceback.format_exc(limit=6)})
                stage.seconds = time.monotonic() - t
                if stage.status == "ok" and any(r.get("ok") is False for r in stage.results):
                    stage.status = "failed"
            self.write()
            print(
                f"{name:>12}: {stage.status}"
                + (f" ({stage.reason})" if stage.reason else "")
                + f" [{stage.seconds:.1f} s]",
                flush=True,
            )
        if self._tmp is not None:
            self._tmp.cleanup()
        return self.report()

    def report(self) -> dict:
        from .harness import run_meta

        meta = run_meta(self.plan.device, command="gpu_check " + " ".join(sys.argv[1:]))
        meta.update(
            {
                "dry_run": self.plan.dry_run,
                "device": self.plan.device,
                "size": [self.plan.size, self.plan.size],
                "weights": self.plan.weights if self.plan.weights and Path(self.plan.weights).is_dir() else None,
                "budget_s": self.plan.budget_s,
                "elapsed_s": round(time.monotonic() - self.t0, 1),
                "gpu_count": torch.cuda.device_count() if torch.cuda.is_available() else 0,
                "tolerances": TOLERANCES,
            }
        )
        counts = {s: sum(st.status == s for st in self.stages) for s in ("ok", "failed", "error", "not_run")}
        return {"schema": SCHEMA, "meta": meta, "stages": [s.to_dict() for s in self.stages], "summary": counts}

    def write(self) -> None:
        out = self.plan.out
        tmp = out.with_name(out.name + ".tmp")
        tmp.write_text(json.dumps(self.report(), indent=1) + "\n", encoding="utf-8")
        os.replace(tmp, out)

    # ---- stage: the test suite's device tests
    def stage_cuda_tests(self, stage: Stage) -> None:
        if self.plan.dry_run:
            raise NotRun("dry run: the device tests run with the suite itself (on the CPU there)")
        if not self.cuda:
            raise NotRun(f"device {self.plan.device} is not CUDA")
        root = Path(__file__).resolve().parents[3]
        files = [f for f in CUDA_TEST_FILES if (root / f).is_file()]
        if not files:
            raise NotRun("the test files are not here (installed package without the repository's tests/)")
        junit = self.workdir() / "cuda-tests.xml"
        cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={junit}", *files]
        r = subprocess.run(
            cmd,
            cwd=root,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            timeout=max(30.0, min(180.0, self.left_s())),
        )
        counts = _junit_counts(junit)
        stage.results.append(
            {"files": files, "returncode": r.returncode, **counts, "ok": r.returncode == 0, "tail": r.stdout[-1500:]}
        )

    # ---- stage: batch-1 streaming
    def stage_streaming(self, stage: Stage) -> None:
        from ..devices import bf16_convolutions

        precisions = ["fp32", "fp16", "bf16"]
        paths = ["fast", "graph"]
        for precision in precisions:
            for path in paths:
                row = {"precision": precision, "path": path, "batch": 1}
                stage.results.append(row)
                if path == "graph" and not self.cuda:
                    row.update(
                        status="not_run",
                        reason="CUDA graphs need CUDA (the same static program runs "
                        "eagerly on the CPU in tests/inference/test_static_streamer.py)",
                    )
                    continue
                if precision == "fp16" and not self.cuda:
                    row.update(status="not_run", reason="fp16 convolutions are for CUDA (on the CPU: bf16)")
                    continue
                if precision == "bf16" and not bf16_convolutions(self.plan.device):
                    row.update(status="not_run", reason="no bf16 convolutions on this CPU")
                    continue
                if self.left_s() <= 0:
                    row.update(status="not_run", reason="time budget spent")
                    continue
                self._torch_row(row, precision, path, batch=1)

    def _torch_row(self, row: dict, precision: str, path: str, batch: int, compare: bool = True) -> None:
        from .runner import BenchCase, build

        tol = "fp32" if precision == "fp32" else "reduced"
        case = BenchCase(
            arch=self.model().config.arch,
            batch=batch,
            height=self.plan.size,
            width=self.plan.size,
            device=self.plan.device,
            precision=precision,
            path=path,
            levels=self.model().config.levels,
            num_classes=self.model().config.num_classes,
        )
        import copy

        with _no_tf32() if precision == "fp32" else contextlib.nullcontext():
            stepper = build(case, copy.deepcopy(self.model()))
            if compare:
                metrics = self.compare(_StatefulGraph(stepper).step if path == "graph" else stepper.step)
                row.update(metrics, tolerance=tol, ok=within(metrics, tol))
            if path == "graph":  # a new streamer: the comparison above left its buffers mid-flight
                stepper = build(case, copy.deepcopy(self.model()))
            row.update(
                time_steps(stepper.step, self.frames(batch), self.plan.device, self.plan.warmup, self.plan.iters)
            )
        row["status"] = "ok" if row.get("ok", True) else "failed"

    # ---- stage: batched throughput
    def stage_batched(self, stage: Stage) -> None:
        from ..devices import bf16_convolutions

        precisions = ["fp16", "bf16"] if self.cuda else (["bf16"] if bf16_convolutions("cpu") else ["fp32"])
        for precision in precisions:
            for batch in self.plan.batches:
                row = {"precision": precision, "path": "fast", "batch": batch}
                stage.results.append(row)
                if self.left_s() <= 0:
                    row.update(status="not_run", reason="time budget spent")
                    continue
                self._torch_row(row, precision, "fast", batch, compare=False)

    # ---- stage: training steps/s
    def stage_training(self, stage: Stage) -> None:
        from ..data.toy import ToyDataset
        from ..devices import bf16_convolutions
        from ..models import build_model
        from ..training.config import RunConfig
        from ..training.data import collate, to_device
        from ..training.trainer import bf16_autocast, compute_loss, forward_batch, prepare_for_training

        dev = torch.device(self.plan.device)
        cfg = RunConfig.from_dict(
            {"model": {"levels": self.model().config.levels}, "data": {"train": [{"name": "toy"}]}}
        )
        b = 1 if self.plan.dry_run else cfg.train.batch_size
        data = ToyDataset(length=b, size=(self.plan.size, self.plan.size))
        batch = to_device(collate([data[i] for i in range(b)]), dev)
        for bf16 in (False, True):
            row = {
                "precision": "bf16 autocast" if bf16 else "fp32",
                "batch": b,
                "size": self.plan.size,
                "seq_len": int(batch["rgb"].shape[1]),
            }
            stage.results.append(row)
            if bf16 and not bf16_convolutions(dev):
                row.update(status="not_run", reason="no bf16 convolutions on this CPU")
                continue
            torch.manual_seed(0)
            model = prepare_for_training(build_model(cfg.model), dev, cfg.train.channels_last).train()
            opt = torch.optim.Adam(model.parameters(), lr=1e-4, eps=1e-7)
            losses = []

            def step() -> None:
                with bf16_autocast(dev, bf16):
                    out = forward_batch(model, batch)
                loss = compute_loss(out, batch, cfg).total
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                losses.append(float(loss.detach()))
                _sync(dev)

            step()
            times = []
            for _ in range(self.plan.train_steps):
                t = time.perf_counter()
                step()
                times.append(time.perf_counter() - t)
            med = statistics.median(times)
            finite = all(np.isfinite(losses))
            row.update(
                median_s_per_step=round(med, 4),
                steps_per_s=round(1 / med, 3),
                timed_steps=len(times),
                losses_finite=finite,
                ok=finite,
                status="ok" if finite else "failed",
            )
            model = opt = step = None  # free the model before the next precision

    # ---- stage: DDP under torchrun
    def stage_ddp(self, stage: Stage) -> None:
        if self.plan.dry_run:
            raise NotRun("dry run: two-process DDP on the CPU (gloo) is tests/training/test_ddp.py")
        n = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if n < 2:
            raise NotRun(f"DDP needs 2 GPUs, this machine has {n}")
        run = self.workdir() / "ddp-run"
        shutil.rmtree(run, ignore_errors=True)
        sets = {
            "model.levels": self.model().config.levels,
            "data.train.0.name": "toy",
            "data.train.0.options": json.dumps({"length": 64}),
            "data.size": 128,
            "data.num_workers": 0,
            "train.batch_size": 2,
            "train.max_steps": 30,
            "train.epochs": 100,
            "train.device": "cuda",
            "train.bf16": "true",
            "train.checkpoint_every": 0,
            "train.validate_every_epochs": 0,
            "train.progress": "false",
            "train.image_every": 0,
            "train.log_every": 1,
        }
        cmd = [
            sys.executable,
            "-m",
            "torch.distributed.run",
            "--standalone",
            "--nnodes=1",
            "--nproc_per_node=2",
            "-m",
            "cosemdepth",
            "train",
            "--out",
            str(run),
        ]
        for k, v in sets.items():
            cmd += ["--set", f"{k}={v}"]
        t = time.perf_counter()
        r = subprocess.run(
            cmd,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            timeout=max(30.0, min(240.0, self.left_s())),
        )
        wall = time.perf_counter() - t
        row = {"processes": 2, "returncode": r.returncode, "wall_s": round(wall, 2), "tail": r.stdout[-1500:]}
        events = _read_jsonl(run / "events.jsonl")
        train = [e for e in events if e.get("kind") == "train"]
        start = next((e for e in events if e.get("kind") == "start"), {})
        row["world_size"] = start.get("world_size")
        row["steps"] = len(train)
        if len(train) >= 3:
            span = train[-1]["time"] - train[1]["time"]
            row["steps_per_s"] = round((len(train) - 2) / span, 3) if span > 0 else None
        row["ok"] = r.returncode == 0 and row["world_size"] == 2 and len(train) == sets["train.max_steps"]
        stage.results.append(row)

    # ---- stage: ONNX Runtime's GPU providers
    def stage_onnxruntime(self, stage: Stage) -> None:
        try:
            import onnxruntime as ort
        except ImportError:
            raise NotRun("onnxruntime is not importable (pip install onnxruntime-gpu)") from None
        available = ort.get_available_providers()
        wanted = [
            ("CUDAExecutionProvider", {"use_tf32": "0"}, "fp32"),
            ("TensorrtExecutionProvider", {"trt_fp16_enable": "False"}, "reduced"),
        ]
        if self.plan.dry_run:  # the machinery, on the provider every build has
            wanted = [("CPUExecutionProvider", {}, "fp32")] + wanted
        for name, options, tol in wanted:
            row = {"provider": name, "onnxruntime": ort.__version__, "batch": 1}
            stage.results.append(row)
            if name not in available:
                row.update(status="not_run", reason=f"not in this onnxruntime build's providers {available}")
                continue
            if name != "CPUExecutionProvider" and not self.cuda:
                row.update(status="not_run", reason=f"device {self.plan.device} is not CUDA")
                continue
            if self.left_s() <= 0:
                row.update(status="not_run", reason="time budget spent")
                continue
            from ..export.runtime import OnnxStep

            providers = (
                [(name, options)] if name == "CPUExecutionProvider" else [(name, options), "CPUExecutionProvider"]
            )
            if name == "TensorrtExecutionProvider":
                cache = self.workdir() / "trt-cache"
                cache.mkdir(exist_ok=True)
                providers[0] = (
                    name,
                    {**options, "trt_engine_cache_enable": "True", "trt_engine_cache_path": str(cache)},
                )
            graph = self.onnx_graph()
            t = time.perf_counter()
            step = OnnxStep(graph, providers=providers)
            row["session_s"] = round(time.perf_counter() - t, 2)
            row["providers_used"] = step.providers
            metrics = self.compare(step.step, "cpu")
            row.update(metrics, tolerance=tol, ok=within(metrics, tol))
            row.update(time_steps(step.step, self.frames(), "cpu", self.plan.warmup, self.plan.iters))
            row["status"] = "ok" if row["ok"] else "failed"

    # ---- stage: a TensorRT fp16 engine
    def stage_tensorrt(self, stage: Stage) -> None:
        try:
            import tensorrt as trt
        except ImportError:
            raise NotRun("tensorrt is not importable (pip install tensorrt)") from None
        if not self.cuda:
            raise NotRun(f"device {self.plan.device} is not CUDA")
        from ..export.tensorrt import TrtStep, build_engine

        t = time.perf_counter()
        plan_file = build_engine(self.onnx_graph(reset_float=True), self.workdir() / "step-fp16.plan", fp16=True)
        row = {"engine": "fp16", "tensorrt": trt.__version__, "batch": 1, "build_s": round(time.perf_counter() - t, 1)}
        stage.results.append(row)
        step = TrtStep(plan_file, self.plan.device)
        metrics = self.compare(step.step)
        row.update(metrics, tolerance="reduced", ok=within(metrics, "reduced"))
        row.update(time_steps(step.step, self.frames(), self.plan.device, self.plan.warmup, self.plan.iters))
        row["status"] = "ok" if row["ok"] else "failed"


@contextlib.contextmanager
def _no_tf32():
    """Float32 convolutions and matrix products in float32 on CUDA (not TF32) inside the block."""
    keep = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
    try:
        yield
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = keep


def _junit_counts(path: Path) -> dict:
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError):
        return {}
    suites = [root] if root.tag == "testsuite" else list(root)
    keys = ("tests", "failures", "errors", "skipped")
    return {k: sum(int(s.get(k, 0)) for s in suites) for k in keys}


def _read_jsonl(path: Path) -> list[dict]:
    try:
        return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    except (OSError, ValueError):
        return []
