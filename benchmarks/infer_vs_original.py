"""Our inference paths against the original TensorFlow Co-SemDepth, on the same machine, in one run.

    TFREF_PY=... COSEM_AUTHORS=... python benchmarks/infer_vs_original.py \
        [--sizes 384 192] [--warmup 3] [--frames 20] [--threads N] [--paths reference fast-fp32 fast-bf16 fast-int8] \
        [--graphs NAME=FILE.onnx ...] [--out benchmarks/results/infer_vs_original]

For each size (square, batch 1, streaming: one frame per call, the first one resets, the state carried): the
original's median seconds per frame (``shared/tools/tfref/make_reference.py --bench``, the authors' code imported
unmodified, random weights of the same architecture: 5 levels, 7 classes), then ours on every path with a model of
the same architecture. Also runs ``benchmarks/conv_peak.py`` at the same thread count: the machine's convolution
floor (the frame's 81 GFLOP at 384x384, a quarter of it at 192x192, at the measured rate of the model's largest
convolution) in fp32, bf16 and int8, and the fraction of that floor each path reaches (floor / time: 1.0 = the frame
costs no more than its convolutions at peak). ``--graphs`` adds exported graphs (``cosemdepth export --onnx`` at the
one ``--sizes`` given) run by ONNX Runtime's CPU provider with ``--threads`` intra-op threads, the state fed back:
rows ``onnx:NAME``. Writes ``OUT.json`` (the benchmark report shape) and ``OUT.md``.

Without ``TFREF_PY`` / ``COSEM_AUTHORS`` (see ``shared/tools/tfref/README.md``) it says so, measures ours only and
writes no ratio. Timings on a shared machine are indicative: the report records the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from cosemdepth.bench.harness import make_report, write_report
from cosemdepth.output_safety.atomic import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
TFREF_DIR = ROOT.parent / "shared" / "tools" / "tfref"
#: our paths: name -> (optimize mode, dtype, precision whose conv floor applies)
PATHS = {
    "reference": ("reference", None, "fp32"),
    "fast-fp32": ("fast", "float32", "fp32"),
    "fast-bf16": ("fast", "bfloat16", "bf16"),
    "fast-int8": ("fast", "int8", "int8"),
}
FRAME_GFLOP_384 = 81.0


def tfref_paths() -> tuple[Path, Path, Path] | None:
    """(python, authors' code, tfref folder) from the environment, or None when the oracle is not set up."""
    py, authors = os.environ.get("TFREF_PY"), os.environ.get("COSEM_AUTHORS")
    tfdir = Path(os.environ.get("TFREF_DIR", TFREF_DIR))
    if (
        not py
        or not authors
        or not Path(py).exists()
        or not Path(authors).is_dir()
        or not (tfdir / "make_reference.py").exists()
    ):
        return None
    return Path(py), Path(authors), tfdir


def time_original(sizes, warmup, frames, threads, tf) -> dict:
    py, authors, tfdir = tf
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [
            str(py),
            "make_reference.py",
            str(authors),
            "--out",
            tmp,
            "--no-reference",
            "--bench",
            str(frames),
            "--bench-warmup",
            str(warmup),
            "--bench-sizes",
            *map(str, sizes),
            "--intra-threads",
            str(threads),
            "--inter-threads",
            str(threads),
        ]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, cwd=tfdir, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"the original's benchmark failed (exit {proc.returncode}): {proc.stderr.strip()[-2000:]}")
        bench = json.loads((Path(tmp) / "bench.json").read_text())
    return {
        "command": " ".join(cmd),
        "wall_s": round(time.perf_counter() - t0, 1),
        "by_size": {r["size"]: r for r in bench["bench"]},
        "threads": bench.get("threads"),
    }


def _inputs(n: int, size: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    base = torch.rand(1, 3, size + 8, size + 8, generator=g)
    for i in range(n):
        rgb = base[:, :, i % 8 : i % 8 + size, 4 : 4 + size].contiguous()
        yield (
            rgb,
            torch.tensor([[1.0, 0.0, 0.0, 0.0]]),
            torch.tensor([[0.0, 0.0, 0.5]]),
            torch.tensor([[size / 2, size / 2, size / 2, size / 2]]),
            torch.tensor([i == 0]),
        )


def time_ours(name: str, size: int, warmup: int, frames: int) -> dict:
    from cosemdepth.inference import FastModel
    from cosemdepth.models import build_model
    from cosemdepth.models.config import ModelConfig

    mode, dtype, _ = PATHS[name]
    torch.manual_seed(0)
    model = build_model(ModelConfig(arch="cosemdepth", levels=5, num_classes=7)).eval()
    if mode == "reference":
        pass
    elif dtype == "int8":  # activation ranges from two frames of the same kind (not timed)
        model = FastModel(model, dtype, calibration=list(_inputs(2, size, seed=1)))
    else:
        model = FastModel(model, dtype)
    times, state = [], None
    with torch.inference_mode():
        for i, frame in enumerate(_inputs(warmup + frames, size)):
            t0 = time.perf_counter()
            out, state = model.step(*frame, state)
            out.depth.float().numpy(), out.semantic.float().numpy()  # like the original's .numpy()
            if i >= warmup:
                times.append(time.perf_counter() - t0)
    return {
        "median_s": statistics.median(times),
        "min_s": min(times),
        "timed_frames": len(times),
        "warmup_frames": warmup,
    }


def conv_floors(threads: int, iters: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "conv_peak.json"
        cmd = [
            sys.executable,
            str(ROOT / "benchmarks" / "conv_peak.py"),
            "--threads",
            str(threads),
            "--iters",
            str(iters),
            "--out",
            str(out),
        ]
        subprocess.run(cmd, check=True, capture_output=True)
        rep = json.loads(out.read_text())
    prec = {"float32": "fp32", "bfloat16": "bf16", "int8": "int8"}
    return {prec[r["dtype"]]: r for r in rep["results"]["rows"] if r["threads"] == threads} | {
        "command": " ".join(cmd[1:])
    }


def time_graph(path: Path, size: int, warmup: int, frames: int, threads: int) -> dict:
    """An exported graph run by ONNX Runtime (CPU provider), streamed like :func:`time_ours`."""
    from cosemdepth.export.runtime import OnnxStep

    step = OnnxStep(path, threads=threads, provenance=False)  # an older export (before/after) is timed too
    times, state = [], None
    for i, frame in enumerate(_inputs(warmup + frames, size)):
        t0 = time.perf_counter()
        out, state = step.step(*frame, state)
        out.depth.numpy(), out.semantic.numpy()
        if i >= warmup:
            times.append(time.perf_counter() - t0)
    return {
        "median_s": statistics.median(times),
        "min_s": min(times),
        "timed_frames": len(times),
        "warmup_frames": warmup,
    }


def markdown(rep: dict) -> str:
    m, prm, res = rep["meta"], rep["params"], rep["results"]
    lines = [
        f"# Inference vs the original, side by side ({m['date_utc']})",
        "",
        f"Machine: {m.get('cpu_model', '?')} ({m.get('cpu_capability', '?')}); {prm['threads']} threads; batch 1 "
        f"streaming; {prm['warmup']} warm-up + {prm['frames']} timed frames; load average before {m['loadavg']}, "
        f"after {res['loadavg_after']}. Indicative when the load average exceeds the thread count.",
        "",
    ]
    if res["original"] is None:
        lines += [f"**Original not measured**: {res['original_missing']}", ""]
    floors = res["conv_floor_ms_384"]
    lines += [
        "Convolution floor of a 384x384 frame at this machine's measured peak (`conv_peak.py`): "
        + ", ".join(f"{k} {v} ms" for k, v in floors.items()),
        "",
        "| size | path | median s/frame | x original | fraction of floor |",
        "|---|---|---|---|---|",
    ]
    for size, rows in res["by_size"].items():
        for name, r in rows.items():
            ratio = "" if r.get("ratio_to_original") is None else f"{r['ratio_to_original']:.2f}x"
            frac = "" if r.get("floor_fraction") is None else f"{100 * r['floor_fraction']:.0f} %"
            lines.append(f"| {size} | {name} | {r['median_s']:.4f} | {ratio} | {frac} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", nargs="+", type=int, default=[384, 192])
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    p.add_argument("--paths", nargs="+", choices=list(PATHS), default=list(PATHS))
    p.add_argument("--conv-iters", type=int, default=10)
    p.add_argument(
        "--graphs",
        nargs="+",
        default=[],
        metavar="NAME=FILE",
        help="exported ONNX graphs (at the one --sizes given) timed in ONNX Runtime as rows onnx:NAME",
    )
    p.add_argument(
        "--out",
        default=str(ROOT / "benchmarks" / "results" / "infer_vs_original"),
        help="output path without extension: OUT.json, OUT.md",
    )
    a = p.parse_args(argv)
    graphs = {}
    for g in a.graphs:
        name, sep, path = g.partition("=")
        if not sep or not Path(path).is_file():
            p.error(f"--graphs {g}: give NAME=FILE with an existing exported graph")
        graphs[name] = path
    if graphs and len(a.sizes) != 1:
        p.error("--graphs: give the one --sizes the graphs were exported at")
    for k in ("warmup", "frames", "threads", "conv_iters"):
        if getattr(a, k) < (0 if k == "warmup" else 1):
            p.error(f"--{k.replace('_', '-')} must be at least {0 if k == 'warmup' else 1}")
    if any(s < 32 or s % 32 for s in a.sizes):
        p.error("--sizes must be multiples of 32 (the 5-level pyramid)")
    torch.set_num_threads(a.threads)
    load_before = os.getloadavg()
    tf = tfref_paths()
    original, missing = None, None
    if tf is None:
        missing = "TFREF_PY and COSEM_AUTHORS are not set (or do not exist): see shared/tools/tfref/README.md"
        print(f"original not measured: {missing}")
    else:
        original = time_original(a.sizes, a.warmup, a.frames, a.threads, tf)
        print("original", {s: round(r["median_s"], 4) for s, r in original["by_size"].items()})
    floors = conv_floors(a.threads, a.conv_iters)
    floor_384 = {k: v["frame_conv_floor_ms"] for k, v in floors.items() if k != "command"}
    results = {}
    for size in a.sizes:
        rows = {}
        if original is not None:
            rows["original (TF)"] = {
                "median_s": original["by_size"][size]["median_s"],
                "ratio_to_original": 1.0,
                "floor_fraction": floor_384["fp32"] * (size / 384) ** 2 / 1e3 / original["by_size"][size]["median_s"],
            }
        for name in a.paths:
            r = time_ours(name, size, a.warmup, a.frames)
            prec = PATHS[name][2]
            if prec in floor_384:
                r["floor_fraction"] = floor_384[prec] * (size / 384) ** 2 / 1e3 / r["median_s"]
                r["floor_precision"] = prec
            if original is not None:
                r["ratio_to_original"] = r["median_s"] / original["by_size"][size]["median_s"]
            rows[name] = r
            print(
                size,
                name,
                round(r["median_s"], 4),
                {k: round(v, 3) for k, v in r.items() if k.endswith(("_to_original", "fraction"))},
            )
        for name, path in graphs.items():
            r = time_graph(Path(path), size, a.warmup, a.frames, a.threads)
            if original is not None:
                r["ratio_to_original"] = r["median_s"] / original["by_size"][size]["median_s"]
            rows[f"onnx:{name}"] = r
            print(size, f"onnx:{name}", round(r["median_s"], 4))
        results[size] = rows
    params = {
        "sizes": a.sizes,
        "warmup": a.warmup,
        "frames": a.frames,
        "threads": a.threads,
        "paths": a.paths,
        "graphs": graphs,
        "conv_iters": a.conv_iters,
        "batch": 1,
        "model": "cosemdepth, 5 levels, 7 classes, random weights (seed 0)",
    }
    results = {
        "by_size": results,
        "original": original,
        "original_missing": missing,
        "conv_floors": floors,
        "conv_floor_ms_384": floor_384,
        "loadavg_after": [round(x, 2) for x in os.getloadavg()],
    }
    rep = make_report("infer_vs_original", params, results)
    rep["meta"]["loadavg"] = [round(x, 2) for x in load_before]
    out = Path(a.out)
    write_report(out.with_suffix(".json"), rep)
    atomic_write_text(out.with_suffix(".md"), markdown(json.loads(json.dumps(rep))))
    print(f"wrote {out}.json and .md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
