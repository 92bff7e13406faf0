"""The command line of the GPU check (``scripts/gpu_check.sh``: ``python -m cosemdepth.cli.gpu_check``): its arguments
become a :class:`~cosemdepth.bench.gpu_check.Plan`, run by :class:`~cosemdepth.bench.gpu_check.Check` (the stages,
the report: :mod:`cosemdepth.bench.gpu_check`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from ..bench.gpu_check import (
    DEFAULT_BUDGET_S,
    DEFAULT_WEIGHTS,
    DRY_BATCHES,
    DRY_SIZE,
    GPU_BATCHES,
    GPU_SIZE,
    STAGES,
    Check,
    Plan,
)
from ..bench.gpu_check import __doc__ as _CHECK_DOC


def parse(argv=None) -> Plan:
    """The :class:`~cosemdepth.bench.gpu_check.Plan` of the command line ``argv`` (a bad argument: one line, exit 2)."""
    ap = argparse.ArgumentParser(prog="gpu_check", description=_CHECK_DOC.splitlines()[0])
    ap.add_argument("--dry-run", action="store_true", help="CPU, tiny size: plan every stage, run what the CPU can")
    ap.add_argument("--device", help="default: cuda (cpu with --dry-run)")
    ap.add_argument("--size", type=int, help=f"square image size (default {GPU_SIZE}; {DRY_SIZE} with --dry-run)")
    ap.add_argument("--batched", nargs="+", type=int, help=f"batched stage's batch sizes (default {GPU_BATCHES})")
    ap.add_argument("--budget", type=float, default=DEFAULT_BUDGET_S, help="seconds for all stages (default 480)")
    ap.add_argument("--warmup", type=int, help="warm-up steps per timed row (default 5; 1 with --dry-run)")
    ap.add_argument("--iters", type=int, help="timed steps per row (default 30; 2 with --dry-run)")
    ap.add_argument("--train-steps", type=int, help="timed training steps (default 10; 1 with --dry-run)")
    ap.add_argument(
        "--model",
        default=DEFAULT_WEIGHTS,
        help=f"weights folder (default {DEFAULT_WEIGHTS}); '' for a seeded random model",
    )
    ap.add_argument("--stages", nargs="+", choices=STAGES, default=list(STAGES), help="run only these stages")
    ap.add_argument("--keep", type=Path, help="keep the exported graph and engines in this folder")
    ap.add_argument("--out", type=Path, default=Path("gpu_check.json"), help="JSON report (default gpu_check.json)")
    a = ap.parse_args(argv)
    dry = a.dry_run
    device = a.device or ("cpu" if dry else "cuda")
    if not dry and device.startswith("cuda") and not torch.cuda.is_available():
        ap.error("CUDA is not available here: run with --dry-run (CPU) or on a GPU machine")
    if not a.out.parent.is_dir():
        ap.error(f"--out {a.out}: folder {a.out.parent} does not exist")
    for name in ("size", "warmup", "iters", "train_steps"):
        v = getattr(a, name)
        if v is not None and v < (0 if name == "warmup" else 1):
            ap.error(f"--{name.replace('_', '-')} must be positive, got {v}")
    return Plan(
        device=device,
        size=a.size or (DRY_SIZE if dry else GPU_SIZE),
        dry_run=dry,
        batches=tuple(a.batched or (DRY_BATCHES if dry else GPU_BATCHES)),
        budget_s=a.budget,
        warmup=a.warmup if a.warmup is not None else (1 if dry else 5),
        iters=a.iters or (2 if dry else 30),
        train_steps=a.train_steps or (1 if dry else 10),
        weights=a.model,
        out=a.out,
        keep=a.keep,
        stages=tuple(a.stages),
    )


def main(argv=None) -> int:
    plan = parse(argv)
    if plan.dry_run:
        torch.set_num_threads(min(2, torch.get_num_threads()))
    report = Check(plan).run()
    print(f"wrote {plan.out}: " + ", ".join(f"{v} {k}" for k, v in report["summary"].items()))
    return 1 if report["summary"]["failed"] or report["summary"]["error"] else 0


__all__ = ["main", "parse"]


if __name__ == "__main__":
    sys.exit(main())
