"""Training speed side by side: the authors' original TensorFlow trainer and ours, on one tree, one machine.

    python benchmarks/train_vs_original.py [--tree DIR] [--steps 30] [--warmup 5] [--size 128]
        [--batch 3] [--seq-len 4] [--threads 2] [--precision fp32 bf16] [--workers N] [--rounds R]
        [--order rotate|fixed] [--no-original] [--work DIR] [--out benchmarks/results/train_vs_original]

1. Builds a small SynthAir tree (``cosemdepth synth``: 2 climates x 3 flights, 80 frames, 256 px; not 384: the original's
   ``prepare`` takes 384 px label files for already mapped ones) unless ``--tree``
   names one.
2. With ``TFREF_PY`` (the TensorFlow venv's python) and ``COSEM_AUTHORS`` (the exported authors' repository) set
   (see ``../shared/tools/tfref/README.md``): the original's ``train_reference.py`` writes its split CSVs
   (``prepare``) and trains ``--warmup + --steps`` steps (``train``, ``--threads`` intra- and inter-op threads);
   its throughput is the wall time between the ends of steps ``warmup`` and ``warmup + steps``. Without them it
   says so and measures ours alone, on the tree's own split CSVs.
3. Ours: ``cosemdepth train --config midair`` on the same split CSVs, the same size, batch, sequence length, step
   count and thread count, once per ``--precision`` (``bf16``: ``--bf16``), with the trainer's defaults otherwise
   (channels-last convolutions, the multi-tensor Keras Adam). Steps/s from the ``train`` events
   (logged every step) after the warm-up: the intervals in which the trainer wrote a checkpoint (every epoch end
   of this small tree; the original saves only at the end) are left out and their count reported; the rate with
   them is reported too, and the mean time a step waited for the data loader (``data_wait_s``).
4. The machine's convolution floor (``benchmarks/conv_peak.py``, 3x3 128->128 at 192x192, fp32 and bf16, at
   ``--threads``): a training step is ``3 x`` the forward's convolution work (forward, input and weight gradients)
   over ``batch x seq_len`` frames; the fraction of that floor each trainer reaches is reported.

The runs are sequential (never two at a time). With ``--rounds R`` the sequence (original, ours per precision) runs R
times, its order rotated from round to round (``--order rotate``, the default: round k starts with the k-th run, so
on a host that slows under sustained load no trainer always runs first, on the rested host; ``--order fixed`` keeps
the order); every round's ratios are taken within the round and the report adds the median of the rounds' ratios: on a
host whose speed drifts by tens of percent within minutes (measured: the same step from 1.09 to 1.68 s), one round
can favour either side. Writes ``OUT.json`` and ``OUT.md``; the machine's load average
before each run is recorded (the numbers are only as good as the machine was quiet).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cosemdepth.bench.harness import make_report, write_report
from cosemdepth.devices import bf16_convolutions, no_bf16_reason
from cosemdepth.output_safety.atomic import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]

TFREF = ROOT.parent / "shared" / "tools" / "tfref"
#: Forward multiply-accumulates of the Co-SemDepth network per frame at 384x384 (design 12.2: 81 GFLOP = 40.5 GMAC).
FRAME_GFLOP_384 = 81.0


def _env() -> dict:
    env = dict(os.environ)
    return env


def _load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def _run(cmd: list[str], log: Path, env: dict | None = None, cwd: Path | None = None) -> None:
    print("$", " ".join(str(c) for c in cmd), flush=True)
    with open(log, "w") as f:
        r = subprocess.run([str(c) for c in cmd], stdout=f, stderr=subprocess.STDOUT, env=env or _env(), cwd=cwd)
    if r.returncode:
        tail = log.read_text(errors="replace").splitlines()[-15:]
        raise SystemExit(f"failed ({r.returncode}): {' '.join(str(c) for c in cmd)}\n" + "\n".join(tail))


def build_tree(work: Path) -> Path:
    tree = work / "synthair"
    if not (tree / "synthair.json").is_file() or '"complete"' not in (tree / "synthair.json").read_text():
        _run(
            [
                sys.executable,
                "-m",
                "cosemdepth",
                "synth",
                "--out",
                tree,
                "--trajectories",
                3,
                "--frames",
                80,
                "--size",
                256,
                "--climates",
                "sunny",
                "cloudy",
                "--no-progress",
            ],
            work / "synth.log",
        )
    return tree


def run_original(a, tree: Path, work: Path, tfpy: str, authors: str, tag: str = "") -> tuple[dict, Path]:
    prep = work / "tf_prep"
    if not (prep / "prepare.json").is_file():
        _run(
            [
                tfpy,
                TFREF / "train_reference.py",
                authors,
                "--data",
                tree,
                "--prep",
                prep,
                "--stages",
                "prepare",
                "--sets",
                "SynthAir",
                "--val-trajectories",
            ],
            work / "tf_prepare.log",
            env=dict(os.environ),
        )
    out = work / f"tf_train{tag}"
    if a.reuse_original and (out / "results.json").is_file():
        res = json.loads((out / "results.json").read_text())
        thr = res["train"]["throughput"] if "train" in res else res["throughput"]
        return {
            "steps_per_s": thr["steps_per_s"],
            "s_per_step_median": thr.get("s_per_step_median"),
            "steps_timed": thr["steps_timed"],
            "loadavg_before": None,
            "reused": str(out / "results.json"),
            "log": str(work / f"tf_train{tag}.log"),
        }, prep / "splits"
    load = _load()
    t0 = time.time()
    _run(
        [
            tfpy,
            TFREF / "train_reference.py",
            authors,
            "--prep",
            prep,
            "--out",
            out,
            "--stages",
            "train",
            "--steps",
            a.warmup + a.steps,
            "--warmup-steps",
            a.warmup,
            "--size",
            a.size,
            "--batch",
            a.batch,
            "--seq-len",
            a.seq_len,
            "--intra-threads",
            a.threads,
            "--inter-threads",
            a.threads,
            "--overwrite",
        ],
        work / f"tf_train{tag}.log",
        env=dict(os.environ),
    )
    res = json.loads((out / "results.json").read_text())
    thr = res["train"]["throughput"] if "train" in res else res["throughput"]
    return {
        "steps_per_s": thr["steps_per_s"],
        "s_per_step_median": thr.get("s_per_step_median"),
        "steps_timed": thr["steps_timed"],
        "loadavg_before": load,
        "wall_s": time.time() - t0,
        "log": str(work / f"tf_train{tag}.log"),
    }, prep / "splits"


def run_ours(
    a,
    tree: Path,
    splits: Path,
    work: Path,
    precision: str,
    tag: str = "",
    *,
    extra_args: tuple = (),
    extra_env: dict | None = None,
) -> dict:
    """Our trainer on the tree (the command below plus ``extra_args``, the environment plus ``extra_env``); steps/s
    after the warm-up from its ``train`` events."""
    from cosemdepth.training.events import read_events

    run_dir = work / f"ours_{precision}{tag}"
    if run_dir.exists():
        shutil.rmtree(run_dir)
    cmd = [
        sys.executable,
        "-m",
        "cosemdepth",
        "train",
        "--config",
        "midair",
        "--data-root",
        tree,
        "--split-dir",
        splits,
        "--out",
        run_dir,
        "--max-steps",
        a.warmup + a.steps,
        "--batch-size",
        a.batch,
        "--device",
        "cpu",
        "--no-progress",
        "--set",
        f"data.size={a.size}",
        "--set",
        f"data.seq_len={a.seq_len}",
        "--set",
        f"data.db_seq_len={max(a.seq_len, 4)}",
        "--set",
        f"train.num_threads={a.threads}",
        "--set",
        "train.log_every=1",
        "--set",
        "train.validate_every_epochs=0",
        "--set",
        "train.image_every=0",
        "--set",
        "train.checkpoint_every=0",
        "--set",
        f"train.epochs={10**6}",
        "--set",
        "data.validate=false",
    ]
    if a.workers is not None:
        cmd += ["--set", f"data.num_workers={a.workers}"]
    if precision == "bf16":
        cmd.append("--bf16")
    cmd += list(extra_args)
    load = _load()
    t0 = time.time()
    env = _env()
    env["OMP_NUM_THREADS"] = str(a.threads)
    env.update(extra_env or {})
    _run(cmd, work / f"ours_{precision}{tag}.log", env=env)
    events = read_events(run_dir / "events.jsonl")
    train = {e["step"]: e["time"] for e in events if e["kind"] == "train"}
    others = [e["time"] for e in events if e["kind"] in ("checkpoint", "validation", "epoch_end")]
    steps = sorted(s for s in train if s > a.warmup)
    kept, dropped, all_dt = [], 0, []
    for s in steps:
        if s - 1 not in train:
            continue
        t_prev, t_cur = train[s - 1], train[s]
        all_dt.append(t_cur - t_prev)
        if any(t_prev < t <= t_cur for t in others):
            dropped += 1
        else:
            kept.append(t_cur - t_prev)
    kept_sorted = sorted(kept)
    waits = [e["data_wait_s"] for e in events if e["kind"] == "train" and e["step"] > a.warmup and "data_wait_s" in e]
    return {
        "steps_per_s": len(kept) / sum(kept),
        "steps_per_s_incl_checkpoints": len(all_dt) / sum(all_dt),
        "s_per_step_median": kept_sorted[len(kept_sorted) // 2],
        "steps_timed": len(kept),
        "data_wait_s_mean": sum(waits) / len(waits) if waits else None,
        "intervals_with_checkpoint_left_out": dropped,
        "loadavg_before": load,
        "wall_s": time.time() - t0,
        "num_workers": a.workers if a.workers is not None else "config default (midair: 4)",
        "run_dir": str(run_dir),
    }


def conv_floor(a, work: Path) -> dict:
    out = work / "conv_peak.json"
    _run(
        [sys.executable, ROOT / "benchmarks" / "conv_peak.py", "--threads", a.threads, "--out", out],
        work / "conv_peak.log",
    )
    rows = json.loads(out.read_text())["results"]["rows"]
    gflops = {r["dtype"]: r["gflops_at_min"] for r in rows if r["threads"] == a.threads}
    frame_gflop = FRAME_GFLOP_384 * (a.size / 384) ** 2
    step_gflop = 3 * frame_gflop * a.batch * a.seq_len
    return {
        "gflops": gflops,
        "step_gflop": round(step_gflop, 1),
        "floor_steps_per_s": {k: v / step_gflop for k, v in gflops.items()},
        "note": "step = 3 x forward convolution work (forward + input and weight gradients) of batch x seq_len "
        "frames at the size; peak GFLOP/s of the model's largest 3x3 convolution (best of 10)",
    }


def finish_round(rnd: dict, floor: dict) -> None:
    """Adds each trainer's ratio to the round's original and its fraction of the conv floor."""
    original = rnd["original"]
    for prec, r in rnd["ours"].items():
        if original:
            r["ratio_to_original"] = r["steps_per_s"] / original["steps_per_s"]
        r["fraction_of_floor"] = (
            r["steps_per_s"] / floor["floor_steps_per_s"]["bfloat16" if prec == "bf16" else "float32"]
        )
    if original:
        original["fraction_of_fp32_floor"] = original["steps_per_s"] / floor["floor_steps_per_s"]["float32"]


def combine_rounds(rounds: list[dict]) -> tuple[dict | None, dict]:
    """The rounds' medians: steps/s, s/step and fraction of the floor of each trainer, and the median of the
    per-round ratios (not the ratio of the medians). One round: that round itself."""
    if len(rounds) == 1:
        return rounds[0]["original"], rounds[0]["ours"]

    def med(xs):
        return statistics.median(xs) if xs and None not in xs else None

    keys = (
        "steps_per_s",
        "s_per_step_median",
        "fraction_of_floor",
        "fraction_of_fp32_floor",
        "ratio_to_original",
        "steps_per_s_incl_checkpoints",
        "data_wait_s_mean",
    )
    original = None
    if rounds[0]["original"]:
        runs = [r["original"] for r in rounds]
        original = {k: med([r.get(k) for r in runs]) for k in keys if k in runs[0]}
        original["loadavg_before"] = "-"
    ours = {}
    for prec in rounds[0]["ours"]:
        runs = [r["ours"][prec] for r in rounds]
        ours[prec] = {k: med([r.get(k) for r in runs]) for k in keys if k in runs[0]}
        ours[prec]["loadavg_before"] = "-"
        ours[prec]["intervals_with_checkpoint_left_out"] = sum(r["intervals_with_checkpoint_left_out"] for r in runs)
    return original, ours


def table_rows(rnd: dict, why: str | None, prefix: str) -> list[str]:
    original, rows = rnd["original"], []
    if original:
        rows.append(
            f"| {prefix}original (TensorFlow, fp32) | {original['steps_per_s']:.3f} | "
            f"{original['s_per_step_median'] or float('nan'):.2f} | 1.00x | "
            f"{100 * original['fraction_of_fp32_floor']:.0f}% | {original['loadavg_before']} |"
        )
    else:
        rows.append(f"| {prefix}original | not run: {why} | | | | |")
    for prec, r in rnd["ours"].items():
        ratio = f"{r['ratio_to_original']:.2f}x" if original else "-"
        rows.append(
            f"| {prefix}ours {prec} | {r['steps_per_s']:.3f} | {r['s_per_step_median']:.2f} | {ratio} | "
            f"{100 * r['fraction_of_floor']:.0f}% | {r['loadavg_before']} |"
        )
    return rows


def add_run_args(p: argparse.ArgumentParser, steps: int, warmup: int) -> None:
    """The options :func:`run_ours` reads (timed and warm-up steps, size, batch, sequence length, threads, workers)."""
    p.add_argument("--steps", type=int, default=steps, help="timed steps (after the warm-up)")
    p.add_argument("--warmup", type=int, default=warmup, help="first steps left out (tracing, pipeline start)")
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--batch", type=int, default=3)
    p.add_argument("--seq-len", type=int, default=4)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--workers", type=int, default=None, help="our data.num_workers (default: the config's)")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tree", type=Path, help="a Mid-Air-format tree to train on (default: build a SynthAir one)")
    add_run_args(p, steps=30, warmup=5)
    p.add_argument("--precision", nargs="+", choices=["fp32", "bf16"], default=["fp32", "bf16"])
    p.add_argument(
        "--rounds",
        type=int,
        default=1,
        help="repeat the sequence (original, ours per precision) this many times and report every round "
        "and the median of the rounds' ratios (a host whose speed drifts hits both sides alike)",
    )
    p.add_argument(
        "--order",
        choices=["rotate", "fixed"],
        default="rotate",
        help="with --rounds: rotate the order of the runs from round to round (round k starts with the "
        "k-th of original, ours per precision), or keep that order in every round",
    )
    p.add_argument("--no-original", action="store_true", help="do not run the original even if available")
    p.add_argument(
        "--reuse-original",
        action="store_true",
        help="reuse the original's results.json already in --work (its run is the slow part)",
    )
    p.add_argument("--work", type=Path, help="working folder, kept (default: a temporary one, removed)")
    p.add_argument("--out", default="benchmarks/results/train_vs_original")
    a = p.parse_args(argv)
    left_out = {}
    if "bf16" in a.precision and not bf16_convolutions("cpu"):  # our --bf16 refuses to train here
        left_out["bf16"] = no_bf16_reason()
        a.precision = [p for p in a.precision if p != "bf16"]
        print(f"ours --bf16 is not run: {left_out['bf16']}", flush=True)

    tmp = None
    if a.work is None:
        tmp = tempfile.TemporaryDirectory(prefix="train_vs_original_")
        work = Path(tmp.name)
    else:
        work = a.work
        work.mkdir(parents=True, exist_ok=True)
    try:
        tree = a.tree or build_tree(work)
        tfpy, authors = os.environ.get("TFREF_PY"), os.environ.get("COSEM_AUTHORS")
        original, splits = None, tree / "splits"
        if a.no_original:
            why = "--no-original"
        elif not (tfpy and authors):
            why = "TFREF_PY and/or COSEM_AUTHORS not set (see ../shared/tools/tfref/README.md)"
        else:
            why = None
        if why:
            print(f"the original is not run: {why}; measuring ours alone", flush=True)
        rounds = []
        for k in range(a.rounds):
            tag = f"_r{k + 1}" if a.rounds > 1 else ""
            jobs = ([] if why else ["original"]) + list(a.precision)
            if a.order == "rotate":  # round k starts with job k: every trainer runs once in every position
                jobs = jobs[k % len(jobs) :] + jobs[: k % len(jobs)]
            rnd = {"original": None, "ours": {}, "order": jobs}
            for job in jobs:
                if job == "original":
                    rnd["original"], splits = run_original(a, tree, work, tfpy, authors, tag)
                    print(f"round {k + 1} original:", json.dumps(rnd["original"]), flush=True)
                else:
                    rnd["ours"][job] = run_ours(a, tree, splits, work, job, tag)
                    print(f"round {k + 1} ours {job}:", json.dumps(rnd["ours"][job]), flush=True)
            rnd["ours"] = {prec: rnd["ours"][prec] for prec in a.precision}
            rounds.append(rnd)
        floor = conv_floor(a, work)
    finally:
        if tmp is not None:
            tmp.cleanup()

    for rnd in rounds:
        finish_round(rnd, floor)
    original, ours = combine_rounds(rounds)
    params = {
        "size": a.size,
        "batch": a.batch,
        "seq_len": a.seq_len,
        "threads": a.threads,
        "steps": a.steps,
        "warmup": a.warmup,
        "rounds": a.rounds,
        "order": a.order,
        "precision": a.precision,
        "tree": str(a.tree) if a.tree else "SynthAir, 2 climates x 3 flights, 80 frames, 256 px (built by this script)",
        "splits": "the original's prepare" if original else "the tree's own",
    }
    results = {
        "original": original,
        "original_missing": why,
        "ours": ours,
        "rounds": rounds,
        "conv_floor": floor,
        "precisions_left_out": left_out,
    }
    report = make_report("train_vs_original", params, results)
    out = Path(a.out)
    write_report(out.with_suffix(".json"), report)
    m = report["meta"]

    def order(rnd: dict) -> str:
        return ", ".join(job if job == "original" else f"ours {job}" for job in rnd["order"])

    setup = f"{a.steps} timed steps after {a.warmup} warm-up steps"
    if a.rounds > 1:
        setup += f"; {a.rounds} rounds of ({order(rounds[0])}) one after the other"
        if a.order == "rotate":
            setup += (
                ", the order rotated from round to round ("
                + "; ".join(f"round {k + 1}: {order(rnd)}" for k, rnd in enumerate(rounds))
                + ")"
            )
        setup += ", each ratio taken within its round"
    md = [
        f"# Training speed, side by side ({a.size} px, batch {a.batch}, seq {a.seq_len}, {a.threads} threads)",
        "",
        f"{m['date_utc']}, {m['cpu_model']} ({m['cpu_count']} CPUs, {m['cpu_capability']}), torch {m['torch']}; {setup}.",
        "",
        "| trainer | steps/s | s/step (median) | vs original | of its conv floor | load before |",
        "|---|---:|---:|---:|---:|---|",
    ]
    runs = []  # (label, our run) of every round, for the notes below the table
    for k, rnd in enumerate(rounds):
        prefix = f"round {k + 1}: " if a.rounds > 1 else ""
        md += table_rows(rnd, why, prefix)
        runs += [(prefix + prec, r) for prec, r in rnd["ours"].items()]
    if a.rounds > 1:
        md += table_rows({"original": original, "ours": ours}, why, "median of the rounds: ")
    md += [
        "",
        f"Conv floor: {floor['gflops']} GFLOP/s (3x3 128->128 at 192x192, {a.threads} threads); a step is "
        f"{floor['step_gflop']} GFLOP -> floor "
        + ", ".join(f"{k} {v:.2f} steps/s" for k, v in floor["floor_steps_per_s"].items())
        + ".",
        "Ours: intervals with a checkpoint left out ("
        + ", ".join(
            f"{k}: {r['intervals_with_checkpoint_left_out']}, with them {r['steps_per_s_incl_checkpoints']:.3f} steps/s"
            for k, r in runs
        )
        + ").",
        "Ours: mean time a step waited for the data loader: "
        + ", ".join(
            f"{k}: {r['data_wait_s_mean']:.3f} s" if r.get("data_wait_s_mean") is not None else f"{k}: -"
            for k, r in runs
        )
        + ".",
    ]
    md += [f"Ours --{k}: not run, {v}." for k, v in left_out.items()]
    atomic_write_text(out.with_suffix(".md"), "\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
