"""Exported ONNX graphs run by ONNX Runtime against the original TensorFlow Co-SemDepth, interleaved, in one run.

    TFREF_PY=... COSEM_AUTHORS=... PYTHONPATH=src python benchmarks/onnx_vs_original.py \\
        --graphs before=OLD.onnx after=NEW.onnx [--rounds 2] [--size 384] [--warmup 3] [--frames 10] [--threads 2] \\
        [--out benchmarks/results/onnx_vs_original.json]

Each round times the original (``benchmarks/infer_vs_original.py``'s ``time_original``: the authors' code, random
weights of the same architecture, batch 1 streaming) and every graph (``cosemdepth export --onnx`` at the same size,
ONNX Runtime's CPU provider with ``--threads`` intra-op threads, the state fed back, the outputs read like the
original's ``.numpy()``); the order rotates from round to round, and each ratio is taken within its round. The load
average is recorded before every measurement. Without ``TFREF_PY`` / ``COSEM_AUTHORS`` the graphs are timed alone.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from infer_vs_original import _inputs, tfref_paths, time_original  # noqa: E402

from cosemdepth.bench.runner import hardware_info  # noqa: E402
from cosemdepth.export.runtime import OnnxStep  # noqa: E402


def time_graph(path: Path, size: int, warmup: int, frames: int, threads: int) -> dict:
    step = OnnxStep(path, threads=threads)
    times, state = [], None
    for i, frame in enumerate(_inputs(warmup + frames, size)):
        t0 = time.perf_counter()
        out, state = step.step(*frame, state)
        out.depth.numpy(), out.semantic.numpy()
        if i >= warmup:
            times.append(time.perf_counter() - t0)
    return {"median_s": statistics.median(times), "min_s": min(times), "max_s": max(times)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--graphs", nargs="+", required=True, metavar="NAME=PATH")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--size", type=int, default=384)
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path)
    a = p.parse_args(argv)
    graphs = dict(g.split("=", 1) for g in a.graphs)
    tf = tfref_paths()
    if tf is None:
        print("the original is not measured: set TFREF_PY, COSEM_AUTHORS (and TFREF_DIR if ../shared/tools/tfref is "
              "not beside the repository); timing the graphs alone", flush=True)
    names = (["original"] if tf else []) + list(graphs)
    rounds = []
    for r in range(a.rounds):
        order = names[r % len(names):] + names[: r % len(names)]
        row = {}
        for name in order:
            load = [round(x, 2) for x in os.getloadavg()]
            if name == "original":
                res = time_original([a.size], a.warmup, a.frames, a.threads, tf)
                med = res["by_size"][a.size]["median_s"]
                row[name] = {"median_s": med, "loadavg_before": load}
            else:
                row[name] = {**time_graph(Path(graphs[name]), a.size, a.warmup, a.frames, a.threads),
                             "loadavg_before": load}
            print(f"round {r + 1} {name}: {row[name]['median_s']:.4f} s/frame (load {load})", flush=True)
        if "original" in row:
            for name in graphs:
                row[name]["ratio_to_original"] = round(row[name]["median_s"] / row["original"]["median_s"], 3)
        rounds.append({"order": order, "results": row})
    rep = {"machine": hardware_info("cpu"), "size": a.size, "threads": a.threads, "warmup": a.warmup,
           "frames": a.frames, "graphs": graphs, "original": bool(tf), "rounds": rounds}
    print(json.dumps(rounds, indent=1))
    if a.out:
        a.out.write_text(json.dumps(rep, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
