"""Stream many frames and check that memory stays flat (no growth beyond warm-up), in every inference mode.

    python benchmarks/memory_flat.py [--frames 10000] [--size 64 64]
        [--modes reference fast-fp32 fast-bf16 fast-int8] [--jobs 2] [--out FILE]

Each mode runs in a fresh process (``--jobs`` at a time, one thread each), so every mode's RSS starts from a clean
interpreter; the JSON has one entry per mode (RSS before the first frame, after warm-up, at the end) and ``ok`` when
every mode is flat. fast-int8 calibrates on its first 8 frames (part of the warm-up).

Samples the resident set size (CPU; /proc/self/status VmRSS, with glibc returning large freed blocks at once, see
cosemdepth.bench.memory) or the CUDA allocation every ``--every`` frames. After ``--warmup`` frames the RSS is the
baseline; the run passes when the largest later sample exceeds it by at most ``--tolerance-mb`` and a least-squares
line through the later samples grows by less than that tolerance over the whole run. Resets every
``--reset-every`` frames, as a flight log with several trajectories would. Writes JSON.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from cosemdepth.bench.harness import make_report, write_report
from cosemdepth.bench.memory import rss_bytes, trim, use_mmap_for_large_allocations
from cosemdepth.export.check import synthetic_sequence
from cosemdepth.inference import FastModel
from cosemdepth.models import build_model

MODES = {
    "reference": ("reference", None),
    "fast-fp32": ("fast", "fp32"),
    "fast-bf16": ("fast", "bf16"),
    "fast-int8": ("fast", "int8"),
}


def run_modes(a, argv) -> int:
    """Every mode of ``--modes`` in its own process (``--jobs`` at a time); one JSON with all of them."""
    passthrough = [x for x in argv if x not in a.modes]
    results, procs = {}, []
    with tempfile.TemporaryDirectory() if a.work_dir is None else contextlib.nullcontext(a.work_dir) as tmp:
        pending = list(a.modes)
        while pending or procs:
            while pending and len(procs) < a.jobs:
                mode = pending.pop(0)
                path, precision = MODES[mode]
                out = f"{tmp}/{mode}.json"
                cmd = [
                    sys.executable,
                    __file__,
                    *_strip(passthrough),
                    "--single",
                    "--path",
                    path,
                    "--out",
                    out,
                    *(["--precision", precision] if precision else []),
                ]
                procs.append((mode, out, subprocess.Popen(cmd)))
            time.sleep(1)
            for item in [x for x in procs if x[2].poll() is not None]:
                procs.remove(item)
                mode, out, proc = item
                results[mode] = (
                    json.loads(Path(out).read_text())["results"]
                    if Path(out).exists()
                    else {"ok": False, "error": proc.returncode}
                )
    ok = all(r["ok"] for r in results.values())
    params = {
        "frames": a.frames,
        "size": a.size,
        "modes": list(a.modes),
        "jobs": a.jobs,
        "arch": a.arch,
        "threads_each": a.threads,
        "warmup": a.warmup,
        "reset_every": a.reset_every,
        "every": a.every,
        "tolerance_mb": a.tolerance_mb,
        "device": a.device,
    }
    write_report(a.out, make_report("memory_flat", params, {"ok": ok, "modes": {m: results[m] for m in a.modes}}))
    for m in a.modes:
        r = results[m]
        print(
            f"{m:>10}: {'FLAT' if r['ok'] else 'GROWING'} RSS start {r.get('rss_start_mb')} MB, after warm-up "
            f"{r.get('baseline_mb')} MB, end {r.get('rss_end_mb')} MB, max growth {r.get('max_growth_after_warmup_mb')}"
            f" MB, {r.get('ms_per_frame')} ms/frame"
        )
    print(f"wrote {a.out}")
    return 0 if ok else 1


def _strip(argv: list[str]) -> list[str]:
    """``argv`` without ``--modes``, ``--jobs`` and ``--out`` (and their values)."""
    out, skip = [], False
    for x in argv:
        if x in ("--modes", "--jobs", "--out", "--work-dir"):
            skip = True
            continue
        if skip and not x.startswith("--"):
            continue
        skip = False
        out.append(x)
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--modes", nargs="+", choices=list(MODES), default=list(MODES))
    p.add_argument("--jobs", type=int, default=2, help="modes run at once, one process (and thread) each")
    p.add_argument("--single", action="store_true", help="run one mode (--path, --precision) in this process")
    p.add_argument("--work-dir", help="keep each mode's JSON here (written every --write-every frames while it runs)")
    p.add_argument("--write-every", type=int, default=1000, help="write the partial result every N frames")
    p.add_argument("--frames", type=int, default=10_000)
    p.add_argument("--size", nargs=2, type=int, default=[64, 64], metavar=("H", "W"))
    p.add_argument("--arch", default="cosemdepth")
    p.add_argument("--path", choices=["fast", "reference"], default="fast")
    p.add_argument("--precision", choices=["fp32", "bf16", "int8"], default="fp32")
    p.add_argument("--device", default="cpu")
    p.add_argument("--warmup", type=int, default=200)
    p.add_argument("--every", type=int, default=100)
    p.add_argument("--reset-every", type=int, default=1000)
    p.add_argument("--tolerance-mb", type=float, default=2.0)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", default="benchmarks/results/memory_flat.json")
    a = p.parse_args(argv)
    if not a.single:
        return run_modes(a, argv)
    torch.set_num_threads(a.threads)
    use_mmap_for_large_allocations()
    dev = torch.device(a.device)
    h, w = a.size
    torch.manual_seed(0)
    model = build_model(arch=a.arch).to(dev).eval()
    if a.path == "fast":
        model = FastModel(model, a.precision)
    rgb, rot, trans, intr = (t.to(dev) for t in synthetic_sequence(1, 8, h, w))
    cuda = dev.type == "cuda"

    def mem() -> int:
        if cuda:
            torch.cuda.synchronize(dev)
            return torch.cuda.memory_allocated(dev)
        return rss_bytes()

    if not cuda:
        trim()
    start = mem()

    samples = []  # (frame, bytes)
    state = None
    t0 = time.perf_counter()
    with torch.inference_mode():
        for k in range(a.frames):
            i = k % 8
            reset = torch.tensor([k % a.reset_every == 0], device=dev)
            _, state = model.step(rgb[:, i], rot[:, i], trans[:, i], intr, reset, state)
            if (k + 1) % a.every == 0:
                if not cuda:
                    trim()
                samples.append((k + 1, mem()))
            if (k + 1) % a.write_every == 0 and k + 1 < a.frames and k + 1 > a.warmup + a.every:
                report(a, samples, start, k + 1, time.perf_counter() - t0, cuda, final=False)
    return report(a, samples, start, a.frames, time.perf_counter() - t0, cuda, final=True)


def report(a, samples, start, done, elapsed, cuda, final) -> int:
    """Write the result over the frames ``done`` so far (``final``: the whole run) and return the exit status."""
    h, w = a.size
    after = [(f, b) for f, b in samples if f > a.warmup]
    base = after[0][1]
    growth_max = max(b for _, b in after) - base
    n = len(after)
    xs = [f for f, _ in after]
    ys = [b for _, b in after]
    mx, my = sum(xs) / n, sum(ys) / n
    slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / max(sum((x - mx) ** 2 for x in xs), 1e-9)
    trend = slope * (xs[-1] - xs[0])
    tol = a.tolerance_mb * 2**20
    ok = growth_max <= tol and abs(trend) <= tol
    result = {
        "ok": ok if final else None,
        "frames": a.frames,
        "frames_done": done,
        "size": [h, w],
        "arch": a.arch,
        "path": a.path,
        "precision": a.precision,
        "device": a.device,
        "threads": a.threads,
        "warmup_frames": a.warmup,
        "reset_every": a.reset_every,
        "rss_start_mb": round(start / 2**20, 2),
        "baseline_mb": round(base / 2**20, 2),
        "rss_end_mb": round(samples[-1][1] / 2**20, 2),
        "max_growth_after_warmup_mb": round(growth_max / 2**20, 3),
        "trend_over_run_mb": round(trend / 2**20, 3),
        "tolerance_mb": a.tolerance_mb,
        "seconds": round(elapsed, 1),
        "ms_per_frame": round(elapsed / done * 1e3, 2),
        "method": "torch.cuda.memory_allocated" if cuda else "VmRSS (/proc/self/status) after malloc_trim",
        "samples_mb": [[f, round(b / 2**20, 2)] for f, b in samples],
    }
    write_report(a.out, make_report("memory_flat", {k: v for k, v in vars(a).items() if k != "out"}, result))
    if not final:
        return 0
    print(
        f"{'FLAT' if ok else 'GROWING'}: {a.frames} frames at {h}x{w}, baseline {result['baseline_mb']} MB after "
        f"{a.warmup} frames, max growth {result['max_growth_after_warmup_mb']} MB, trend "
        f"{result['trend_over_run_mb']} MB ({result['ms_per_frame']} ms/frame); wrote {a.out}"
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
