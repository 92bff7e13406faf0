"""Interleaved A/B of our trainer's speed under settings: environment variables and/or config keys.

    PYTHONPATH=src python benchmarks/train_env_ab.py --tree TREE --split-dir SPLITS --variant NAME=SPEC ...
        [--rounds 3] [--precision bf16] [--steps 20] [--warmup 3] [--size 128] [--batch 3] [--seq-len 4]
        [--threads 2] [--work DIR] [--out benchmarks/results/train_env_ab]

Each ``SPEC`` is a comma-separated list of ``ENV=VALUE`` (an environment variable, upper case) or ``key=value`` (a
``--set`` of the run's config), ``-`` for none: e.g. ``default=-``, ``passive=OMP_WAIT_POLICY=PASSIVE``,
``no-retain=train.retain_host_memory=false``. Every round runs every variant once, in turn (the order alternates
between rounds), with :func:`train_vs_original.run_ours` (``cosemdepth train --config midair`` on the tree, the
timed steps after the warm-up, checkpoint intervals left out); each variant's steps/s is reported per round, with
the median over rounds and the median of its per-round ratio to the first variant. Writes ``OUT.json`` and
``OUT.md``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from cosemdepth.bench.runner import hardware_info  # noqa: E402
from cosemdepth.io.atomic import atomic_write_text  # noqa: E402
from train_vs_original import add_run_args, run_ours  # noqa: E402


def parse_variant(text: str) -> tuple[str, dict, list[str]]:
    """``NAME=SPEC`` -> (name, environment, extra trainer arguments)."""
    name, sep, spec = text.partition("=")
    if not sep or not name:
        raise SystemExit(f"--variant {text!r}: expected NAME=SPEC")
    env, args = {}, []
    for item in ([] if spec in ("", "-") else spec.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"--variant {text!r}: {item!r} is not KEY=VALUE")
        if key.isupper():
            env[key] = value
        else:
            args += ["--set", f"{key}={value}"]
    return name, env, args


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tree", type=Path, required=True, help="a Mid-Air-format tree")
    p.add_argument("--split-dir", type=Path, required=True, help="its split CSVs")
    p.add_argument("--variant", action="append", required=True, help="NAME=SPEC (see above); the first is the base")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--precision", choices=["fp32", "bf16"], default="bf16")
    add_run_args(p, steps=20, warmup=3)
    p.add_argument("--work", type=Path, help="working folder for the runs (default: a temporary one)")
    p.add_argument("--out", default="benchmarks/results/train_env_ab")
    a = p.parse_args(argv)
    variants = [parse_variant(v) for v in a.variant]
    tmp = tempfile.TemporaryDirectory(prefix="train_env_ab_") if a.work is None else None
    work = Path(tmp.name) if tmp else a.work
    work.mkdir(parents=True, exist_ok=True)
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    runs = {name: [] for name, _, _ in variants}
    try:
        for k in range(a.rounds):
            order = variants if k % 2 == 0 else variants[::-1]
            for name, env, args in order:
                r = run_ours(a, a.tree, a.split_dir, work, a.precision, f"_{name}_r{k + 1}", extra_args=args,
                             extra_env=env)
                runs[name].append(r)
                print(f"round {k + 1} {name}: {r['steps_per_s']:.3f} steps/s", flush=True)
    finally:
        if tmp:
            tmp.cleanup()
    base = variants[0][0]
    rows = []
    for name, env, args in variants:
        sps = [r["steps_per_s"] for r in runs[name]]
        ratios = [r["steps_per_s"] / b["steps_per_s"] for r, b in zip(runs[name], runs[base])]
        rows.append({"variant": name, "env": env, "args": args, "steps_per_s": sps,
                     "median_steps_per_s": statistics.median(sps), "median_ratio_to_base": statistics.median(ratios),
                     "loadavg_before": [r["loadavg_before"] for r in runs[name]]})
    report = {"config": {k: getattr(a, k) for k in ("precision", "steps", "warmup", "size", "batch", "seq_len",
                                                     "threads", "rounds", "workers")} | {"tree": str(a.tree)},
              "started": started, "machine": hardware_info("cpu"), "variants": rows}
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out.with_suffix(".json"), json.dumps(report, indent=2) + "\n")
    lines = [f"# Our trainer under settings ({a.size} px, batch {a.batch}, seq {a.seq_len}, {a.threads} threads, "
             f"{a.precision})", "",
             f"Started {started}, {report['machine'].get('cpu', 'CPU')}; {a.steps} timed steps after {a.warmup} "
             f"warm-up steps; {a.rounds} rounds, the variants in turn (order alternating).", "",
             "| variant | settings | steps/s per round | median | median ratio to " + base + " |",
             "|---|---|---|---:|---:|"]
    for r in rows:
        spec = ", ".join([f"{k}={v}" for k, v in r["env"].items()] + r["args"][1::2]) or "-"
        lines.append(f"| {r['variant']} | {spec} | {', '.join(f'{x:.3f}' for x in r['steps_per_s'])} | "
                     f"{r['median_steps_per_s']:.3f} | {r['median_ratio_to_base']:.2f}x |")
    atomic_write_text(out.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
