"""Does torch.compile help on this CPU? Times the static streaming step compiled by Inductor against the eager fast
engine (fp32 and bf16 hidden layers) at one size, and writes JSON.

    PYTHONPATH=src python benchmarks/compile_probe.py [--scope step|refiner] [--size 384 384] [--iters 5] [--out FILE]

``--scope refiner`` compiles only the level-1 depth refiner (15 GMAC at 384x384, the largest single block) and
compares it with the engine's packed refiner, which uses the same fused oneDNN kernels.

What is compiled: the reference modules in static mode (no data-dependent branch), eval, channels-last, under
``torch.inference_mode`` with ``torch._inductor.config.freezing = True`` (weights folded and pre-packed, convolutions
fused with their activations by Inductor's oneDNN passes). bf16 uses CPU autocast around the compiled step.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cosemdepth.bench.runner import hardware_info  # noqa: E402
from cosemdepth.export.check import synthetic_sequence  # noqa: E402
from cosemdepth.export.onnx import StreamingStep  # noqa: E402
from cosemdepth.io.atomic import atomic_write_text  # noqa: E402
from cosemdepth.models import build_model  # noqa: E402


def timed(fn, warmup: int, iters: int) -> list[float]:
    out = []
    for k in range(warmup + iters):
        t0 = time.perf_counter()
        fn(k)
        if k >= warmup:
            out.append((time.perf_counter() - t0) * 1e3)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", nargs=2, type=int, default=[384, 384])
    p.add_argument("--iters", type=int, default=5)
    p.add_argument("--threads", type=int)
    p.add_argument("--precisions", nargs="+", default=["fp32", "bf16"])
    p.add_argument("--scope", choices=["step", "refiner"], default="step")
    p.add_argument("--out", default="benchmarks/results/compile_probe.json")
    a = p.parse_args(argv)
    if a.scope == "refiner":
        return refiner_probe(a)
    if a.threads:
        torch.set_num_threads(a.threads)
    import torch._inductor.config as inductor_config

    inductor_config.freezing = True
    h, w = a.size
    torch.manual_seed(0)
    model = build_model().eval()
    rgb, rot, trans, intr = synthetic_sequence(1, 4, h, w)
    step = StreamingStep(model)
    state0 = step.example_inputs(1, h, w)[5:]
    report = {"size": [h, w], "machine": hardware_info("cpu"), "rows": []}
    for prec in a.precisions:
        dtype = torch.bfloat16 if prec == "bf16" else torch.float32
        # eager fast engine
        model.optimize("fast", dtype=dtype)
        st = {"s": None}

        def eager(k):
            _, st["s"] = model.step(rgb[:, k % 4], rot[:, k % 4], trans[:, k % 4], intr, torch.tensor([k == 0]), st["s"])

        with torch.inference_mode():
            ts = timed(eager, 2, a.iters)
        report["rows"].append({"precision": prec, "path": "fast (eager)", "median_ms": statistics.median(ts), "ms": ts})
        print(report["rows"][-1])
        # compiled static reference step
        model.optimize("reference")
        model.set_numerics(static=True)
        m_cl = model.to(memory_format=torch.channels_last)
        compiled = torch.compile(StreamingStep(m_cl))
        amp = torch.autocast("cpu", dtype=torch.bfloat16) if prec == "bf16" else contextlib.nullcontext()
        cs = {"s": list(state0)}
        t0 = time.perf_counter()
        with torch.inference_mode(), amp:
            outs = compiled(rgb[:, 0], rot[:, 0], trans[:, 0], intr, torch.tensor([True]), *cs["s"])
        compile_s = time.perf_counter() - t0
        n_out = len(outs) - len(state0)
        cs["s"] = [t.float() for t in outs[n_out:]]

        def comp(k):
            with amp:
                o = compiled(rgb[:, k % 4], rot[:, k % 4], trans[:, k % 4], intr, torch.tensor([False]), *cs["s"])
            cs["s"] = [t.float() for t in o[n_out:]]

        with torch.inference_mode():
            ts = timed(comp, 1, a.iters)
        report["rows"].append(
            {"precision": prec, "path": "torch.compile (Inductor, freezing)", "compile_s": round(compile_s, 1),
             "median_ms": statistics.median(ts), "ms": ts}
        )
        print(report["rows"][-1])
        model.set_numerics(static=False)
        torch._dynamo.reset()
    report["machine"]["loadavg_end"] = hardware_info("cpu")["loadavg_start"]
    atomic_write_text(a.out, json.dumps(report, indent=1) + "\n")
    print(f"wrote {a.out}")
    return 0


def refiner_probe(a) -> int:
    import torch._inductor.config as inductor_config

    from cosemdepth.inference.engine import _Refiner
    from cosemdepth.models.layers import Refiner

    inductor_config.freezing = True
    if a.threads:
        torch.set_num_threads(a.threads)
    h, w = ((s + 1) // 2 for s in a.size)
    torch.manual_seed(0)
    ref = Refiner(64, 5).eval()
    x = torch.randn(1, 64, h, w).contiguous(memory_format=torch.channels_last)
    report = {"scope": "refiner", "input": [1, 64, h, w], "machine": hardware_info("cpu"), "rows": []}
    for prec in a.precisions:
        dtype = torch.bfloat16 if prec == "bf16" else torch.float32
        packed = _Refiner(ref, dtype, torch.device("cpu"), None)
        amp = torch.autocast("cpu", dtype=torch.bfloat16) if prec == "bf16" else contextlib.nullcontext()
        compiled = torch.compile(ref.to(memory_format=torch.channels_last))
        with torch.inference_mode():
            t0 = time.perf_counter()
            with amp:
                y = compiled(x)
            compile_s = time.perf_counter() - t0
            eager_ms = timed(lambda k: packed(x), 1, a.iters)
            with amp:
                comp_ms = timed(lambda k: compiled(x), 1, a.iters)
            diff = float((y.float() - packed(x).float()).abs().max())
        row = {
            "precision": prec,
            "packed_eager_median_ms": statistics.median(eager_ms),
            "compiled_median_ms": statistics.median(comp_ms),
            "compile_s": round(compile_s, 1),
            "max_abs_diff": diff,
            "packed_eager_ms": eager_ms,
            "compiled_ms": comp_ms,
        }
        report["rows"].append(row)
        print({k: v for k, v in row.items() if not k.endswith("_ms") or "median" in k})
        torch._dynamo.reset()
    atomic_write_text(a.out, json.dumps(report, indent=1) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
