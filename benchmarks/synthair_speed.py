"""SynthAir rendering speed: milliseconds per 384x384 frame on this machine, written as JSON.

    python benchmarks/synthair_speed.py [--size 384] [--frames-per-flight 3] [--threads 1]
                                                       [--out benchmarks/results/synthair_speed.json]

What is timed: the frames of the default set's flights (4 trajectories x 4 climates, seed 0), a few per flight,
rendered as ``cosemdepth synth`` renders them (one process, batches of ``batch_size(size)`` frames, torch on
``--threads`` threads), then encoded as the JPEG and the two PNGs that go to disk. The world is built once first
(timed separately). Reported: wall and CPU milliseconds per frame (mean, median, 90th percentile, max), with and
without the encoding, plus the machine, the load average and the date. The machine is shared: the load average
says how busy it was.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from cosemdepth.bench.harness import make_report, write_report
from cosemdepth.synthair.climate import get_climate
from cosemdepth.synthair.render import render_frames
from cosemdepth.synthair.world import build_world
from cosemdepth.synthair.writer import (
    SynthConfig,
    batch_size,
    depth_to_png_disparity,
    encode_jpeg,
    encode_png,
    plan_flights,
    rendered_frames,
)


def _stats(values_s: list[float]) -> dict:
    ms = sorted(v * 1e3 for v in values_s)
    return {
        "mean": round(statistics.fmean(ms), 1),
        "median": round(statistics.median(ms), 1),
        "p90": round(ms[min(len(ms) - 1, int(0.9 * len(ms)))], 1),
        "max": round(ms[-1], 1),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=384)
    p.add_argument("--frames-per-flight", type=int, default=3)
    p.add_argument("--threads", type=int, default=1, help="torch threads (the generator uses 1 per process)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="benchmarks/results/synthair_speed.json")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    load_before = os.getloadavg()

    t0 = time.perf_counter()
    world = build_world(a.seed)
    world_s = time.perf_counter() - t0

    cfg = SynthConfig(out=Path("unused"), size=a.size, seed=a.seed)  # the default set: 4 flights x 4 climates
    flights = plan_flights(cfg, world)
    frames = rendered_frames(cfg)
    picks = np.linspace(0, len(frames) - 1, a.frames_per_flight).round().astype(int)
    bs = batch_size(a.size)

    # warm-up (first-call allocations)
    first = next(iter(next(iter(flights.values())).values())).flight
    render_frames(world, get_climate("sunny"), first.attitude[:1], first.position[:1], a.size, a.size)

    render_wall, render_cpu, total_wall = [], [], []
    for climate, planned in flights.items():
        for pf in planned.values():
            ks = [frames[i] for i in picks]
            for c in range(0, len(ks), bs):
                sel = [4 * k for k in ks[c : c + bs]]
                w0, c0 = time.perf_counter(), time.process_time()
                out = render_frames(
                    world,
                    get_climate(climate).with_sun_azimuth(pf.sun_azimuth),
                    pf.flight.attitude[sel],
                    pf.flight.position[sel],
                    a.size,
                    a.size,
                )
                w1, c1 = time.perf_counter(), time.process_time()
                for f in out:
                    encode_jpeg(f.rgb, cfg.jpeg_quality)
                    encode_png(depth_to_png_disparity(f.depth))
                    encode_png(f.labels)
                w2 = time.perf_counter()
                n = len(out)
                render_wall += [(w1 - w0) / n] * n
                render_cpu += [(c1 - c0) / n] * n
                total_wall += [(w2 - w0) / n] * n

    result = {
        "frames": len(render_wall),
        "batch_size": bs,
        "ms_per_frame_render_wall": _stats(render_wall),
        "ms_per_frame_render_cpu": _stats(render_cpu),
        "ms_per_frame_with_encoding_wall": _stats(total_wall),
        "world_build_s": round(world_s, 2),
        "load_average_before": [round(v, 2) for v in load_before],
        "load_average_after": [round(v, 2) for v in os.getloadavg()],
    }
    params = {"size": a.size, "frames_per_flight": a.frames_per_flight, "threads": a.threads, "seed": a.seed}
    write_report(a.out, make_report("synthair_speed", params, result))
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
