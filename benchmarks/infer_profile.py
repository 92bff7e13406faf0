"""Where a streamed frame's time goes on the fast path: torch.profiler by op, convolutions against everything else.

    PYTHONPATH=src python benchmarks/infer_profile.py [--size 384] [--threads 2] [--precision bf16 int8]
        [--frames 3] [--model weights/synthair-cosemdepth] [--out benchmarks/results/infer_profile_384]

For each precision: the model on the fast path (int8: calibrated on 4 synthetic frames first), 3 warm-up frames,
then ``--frames`` profiled frames of one trajectory (batch 1). Self CPU time per op (the time of an op minus the ops
it calls), per frame; ops are grouped as convolutions (oneDNN fp32/bf16 and int8 convolution kernels) or other.
Wall time per frame is measured in a separate unprofiled pass (the profiler adds overhead per op). Writes
``OUT.json`` and ``OUT.md``. Timings are indicative on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections import defaultdict
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cosemdepth import load_model  # noqa: E402
from cosemdepth.bench.runner import hardware_info  # noqa: E402
from cosemdepth.export.check import synthetic_sequence  # noqa: E402
from cosemdepth.io.atomic import atomic_write_text  # noqa: E402

CONV_OPS = ("mkldnn::_convolution_pointwise", "onednn::qconv2d_pointwise", "aten::mkldnn_convolution",
            "aten::_convolution", "aten::convolution", "aten::conv2d", "quantized::conv2d")
PRECISION_DTYPES = {"fp32": "float32", "bf16": "bfloat16", "int8": "int8"}


def frames_for(size: int, n: int, seed: int):
    rgb, rot, trans, intr = synthetic_sequence(1, n, size, size, seed=seed)
    return [(rgb[:, k], rot[:, k], trans[:, k], intr, torch.tensor([k == 0])) for k in range(n)]


def prepare(model_path: str, precision: str, size: int):
    model = load_model(model_path, mode="reference")
    options = {"calibration": frames_for(size, 4, seed=2)} if precision == "int8" else {}
    return model.optimize("fast", PRECISION_DTYPES[precision], **options)


def stream(model, frames, state=None):
    with torch.inference_mode():
        for k, (rgb, rot, trans, intr, reset) in enumerate(frames):
            _, state = model.step(rgb, rot, trans, intr, reset if state is None else torch.tensor([False]), state)
    return state


def profile_one(model_path: str, precision: str, size: int, n: int) -> dict:
    model = prepare(model_path, precision, size)
    warm, timed = frames_for(size, 3, seed=1), frames_for(size, n, seed=3)
    state = stream(model, warm)
    walls = []
    for fr in timed:  # unprofiled wall time per frame
        t = time.perf_counter()
        state = stream(model, [fr], state)
        walls.append(time.perf_counter() - t)
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        state = stream(model, timed, state)
    by_op = defaultdict(lambda: [0, 0.0])
    for e in prof.key_averages():
        by_op[e.key][0] += e.count
        by_op[e.key][1] += e.self_cpu_time_total / 1e3  # ms
    ops = sorted(({"op": k, "calls_per_frame": c / n, "self_ms_per_frame": ms / n} for k, (c, ms) in by_op.items()),
                 key=lambda r: -r["self_ms_per_frame"])
    total = sum(r["self_ms_per_frame"] for r in ops)
    conv = sum(r["self_ms_per_frame"] for r in ops if r["op"] in CONV_OPS)
    return {"precision": precision, "wall_ms_per_frame": [round(w * 1e3, 1) for w in walls],
            "wall_median_ms": round(statistics.median(walls) * 1e3, 1), "profiled_self_ms_per_frame": round(total, 1),
            "conv_ms_per_frame": round(conv, 1), "other_ms_per_frame": round(total - conv, 1),
            "conv_share": round(conv / total, 3), "ops": [{**r, "self_ms_per_frame": round(r["self_ms_per_frame"], 2)}
                                                          for r in ops if r["self_ms_per_frame"] >= 0.05]}


def markdown(report: dict, top: int = 15) -> str:
    m = report["meta"]
    lines = [f"# Fast-path frame profile ({report['size']} px, batch 1, {report['threads']} threads) — indicative", "",
             f"Machine: {m.get('cpu')}, load average at start {m.get('loadavg_start')}; {report['date']}.", "",
             "| precision | wall ms/frame (median, unprofiled) | profiled self ms/frame | convolutions | other | "
             "conv share |", "|---|---:|---:|---:|---:|---:|"]
    for r in report["runs"]:
        lines.append(f"| {r['precision']} | {r['wall_median_ms']} | {r['profiled_self_ms_per_frame']} | "
                     f"{r['conv_ms_per_frame']} | {r['other_ms_per_frame']} | {r['conv_share']:.0%} |")
    for r in report["runs"]:
        lines += ["", f"## {r['precision']}: top ops by self time", "", "| op | calls/frame | self ms/frame |",
                  "|---|---:|---:|"]
        lines += [f"| `{o['op']}` | {o['calls_per_frame']:g} | {o['self_ms_per_frame']} |" for o in r["ops"][:top]]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=384)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--precision", nargs="+", choices=list(PRECISION_DTYPES), default=["bf16", "int8"])
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--model", default=str(Path(__file__).resolve().parents[1] / "weights" / "synthair-cosemdepth"))
    ap.add_argument("--out", default=None, help="output prefix (default: print only)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.set_num_threads(args.threads)
    report = {"meta": hardware_info("cpu"), "size": args.size, "threads": args.threads,
              "date": time.strftime("%Y-%m-%d"), "runs": []}
    for p in args.precision:
        r = profile_one(args.model, p, args.size, args.frames)
        report["runs"].append(r)
        print(f"{p}: wall {r['wall_median_ms']} ms/frame; profiled {r['profiled_self_ms_per_frame']} ms = conv "
              f"{r['conv_ms_per_frame']} + other {r['other_ms_per_frame']}", flush=True)
        for o in r["ops"][:12]:
            print(f"    {o['op']:<45} {o['calls_per_frame']:>6g} {o['self_ms_per_frame']:>8.2f}", flush=True)
    if args.out:
        atomic_write_text(Path(args.out + ".json"), json.dumps(report, indent=1) + "\n")
        atomic_write_text(Path(args.out + ".md"), markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
