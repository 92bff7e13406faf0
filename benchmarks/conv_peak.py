"""How fast can this machine convolve? The floor under any direct-convolution frame time.

    python benchmarks/conv_peak.py [--threads 1 2] [--out FILE]

Times the largest convolution of the model (3x3, 128 -> 128 channels at 192x192, 10.9 GFLOP, channels-last, fused
LeakyReLU, the fast path's kernel) in fp32 and bf16, and as the int8 path runs it (uint8 activations, oneDNN
quantized convolution, then the LeakyReLU requantisation) at each thread count, reports GFLOP/s and the time the model's
81 GFLOP per 384x384 frame (design 12.2) would need at that rate. Also records whether NNPACK's Winograd convolution
runs here. Writes JSON.
"""

from __future__ import annotations

import argparse
import statistics
import sys

import torch

from cosemdepth.bench.harness import make_report, time_calls, write_report
from cosemdepth.devices import bf16_convolutions
from cosemdepth.inference.convs import PackedConv
from cosemdepth.inference.int8 import QuantConv, Range, has_int8, quantize
from cosemdepth.ops.padding import Conv2dSame

FRAME_GFLOP = 81.0


def timed_row(run, dtype: str, threads: int, iters: int, gflop: float) -> dict:
    """Time ``run()`` (one warm-up call, then ``iters`` calls) on ``threads`` threads: one row of the table."""
    torch.set_num_threads(threads)
    ts = [t * 1e3 for t in time_calls(run, warmup=1, iters=iters)]
    best = min(ts)
    row = {
        "dtype": dtype,
        "threads": threads,
        "min_ms": round(best, 2),
        "median_ms": round(statistics.median(ts), 2),
        "gflops_at_min": round(gflop / best * 1e3, 1),
        "frame_conv_floor_ms": round(FRAME_GFLOP / (gflop / best * 1e3) * 1e3, 1),
    }
    print(row)
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    p.add_argument("--iters", type=int, default=10)
    p.add_argument("--out", default="benchmarks/results/conv_peak.json")
    a = p.parse_args(argv)
    conv = Conv2dSame(128, 128, 3)
    x = torch.randn(1, 128, 192, 192)
    gflop = 2 * 128 * 128 * 9 * 192 * 192 / 1e9
    rows = []
    with torch.inference_mode():
        # bf16 only where oneDNN has bf16 convolutions (not on an AVX2-only CPU)
        for dtype in (torch.float32, torch.bfloat16) if bf16_convolutions("cpu") else (torch.float32,):
            packed = PackedConv(conv, dtype, torch.device("cpu"), act=True)
            xin = x.to(dtype).contiguous(memory_format=torch.channels_last)
            for th in a.threads:
                rows.append(timed_row(lambda: packed(xin), str(dtype).replace("torch.", ""), th, a.iters, gflop))
    if has_int8():
        with torch.inference_mode():
            xr, yr = Range(), Range()
            xr.update(x)
            yr.update(conv(x))
            q = QuantConv(conv, xr, yr)
            qx = quantize(x.clone(), q.x_scale, q.x_zp)
            for th in a.threads:
                rows.append(timed_row(lambda: q(qx), "int8", th, a.iters, gflop))
    nnpack = {"available": torch.backends.nnpack.is_available(), "shapes": {}}
    for cin, cout, hw, bias in [
        (64, 64, 32, False),
        (64, 128, 192, False),
        (64, 128, 192, True),
        (128, 128, 192, True),
    ]:
        key = f"{cin}->{cout} at {hw}x{hw}{' +bias' if bias else ''}"
        try:
            torch._nnpack_spatial_convolution(
                torch.randn(1, cin, hw, hw), torch.randn(cout, cin, 3, 3), torch.randn(cout) if bias else None, [1, 1]
            )
            nnpack["shapes"][key] = "runs"
        except RuntimeError as e:
            nnpack["shapes"][key] = str(e).splitlines()[0]
    print("nnpack", nnpack)
    results = {
        "conv": "3x3 128->128 at 192x192, batch 1",
        "gflop": round(gflop, 2),
        "rows": rows,
        "nnpack": nnpack,
        "bf16": "measured" if bf16_convolutions("cpu") else "left out: this CPU has no bf16 convolutions",
    }
    write_report(a.out, make_report("conv_peak", {"threads": a.threads, "iters": a.iters}, results))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
