"""Interleaved A/B timing of whole training steps in one process (for a loaded machine).

    PYTHONPATH=src python benchmarks/train_ab.py VARIANT VARIANT... [--size 128] [--batch 3] [--seq-len 4]
        [--threads 2] [--repeats 8] [--out benchmarks/results/NAME.json]

A variant is a comma-separated list of switches: ``fp32`` or ``bf16`` (autocast of the forward), ``cl``
(channels-last model and input, as the trainer's ``train.channels_last``), ``loop`` (Keras Adam parameter by
parameter instead of the multi-tensor update). Every variant gets its own copy of the same initial weights and its
own optimizer; the variants' steps alternate (A B C A B C ..., the order rotated every round), so that a changing
machine load hits all of them alike. Prints the median seconds per step of each and its ratio to the first, in
wall time and in the process's CPU time (user + system of all its threads: less sensitive to other processes
taking the cores, though not immune to them: shared caches, OpenMP threads spinning while descheduled).
"""

from __future__ import annotations

import argparse
import copy
import json
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cosemdepth.bench.runner import hardware_info  # noqa: E402
from cosemdepth.config import RunConfig  # noqa: E402
from cosemdepth.devices import retain_freed_host_memory  # noqa: E402
from cosemdepth.io.atomic import atomic_write_text  # noqa: E402
from cosemdepth.models import build_model  # noqa: E402
from cosemdepth.training.data import collate, to_device  # noqa: E402
from cosemdepth.training.optim import KerasAdam  # noqa: E402
from cosemdepth.training.toy import ToyDataset  # noqa: E402
from cosemdepth.training.trainer import bf16_autocast, compute_loss, forward_batch, prepare_for_training  # noqa: E402

SWITCHES = {"fp32", "bf16", "cl", "loop"}


def make_variant(spec: str, base: torch.nn.Module, cfg: RunConfig) -> dict:
    sw = set(spec.split(","))
    if sw - SWITCHES:
        raise SystemExit(f"unknown switch(es) {sorted(sw - SWITCHES)} in {spec!r}; known: {sorted(SWITCHES)}")
    model = prepare_for_training(copy.deepcopy(base), torch.device("cpu"), channels_last="cl" in sw)
    opt = KerasAdam(model.parameters(), lr=1e-4, eps=1e-7, foreach="loop" not in sw)
    return {"spec": spec, "model": model, "opt": opt, "bf16": "bf16" in sw, "times": [], "cpu": []}


def step(v: dict, batch: dict, cfg: RunConfig) -> float:
    model, opt = v["model"], v["opt"]
    t, c = time.perf_counter(), time.process_time()
    with bf16_autocast(torch.device("cpu"), v["bf16"]):
        out = forward_batch(model, batch)
    loss = compute_loss(out, batch, cfg).total
    opt.zero_grad(set_to_none=True)
    loss.backward()
    norm = torch.linalg.vector_norm(torch.stack(torch._foreach_norm([p.grad for p in model.parameters()])))
    if bool(torch.isfinite(loss)) and bool(torch.isfinite(norm)):
        opt.step()
    v["cpu"].append(time.process_time() - c)
    return time.perf_counter() - t


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("variants", nargs="+")
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--batch", type=int, default=3)
    p.add_argument("--seq-len", type=int, default=4)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=8)
    p.add_argument("--out", type=Path)
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    retain_freed_host_memory()  # as the CPU trainer does (train.retain_host_memory)
    torch.manual_seed(0)
    cfg = RunConfig.from_dict({"data": {"train": [{"name": "toy"}], "size": a.size, "seq_len": a.seq_len}})
    base = build_model(cfg.model).train()
    toy = ToyDataset(length=a.batch, size=(a.size, a.size), seq_len=a.seq_len)
    batch = to_device(collate([toy[i] for i in range(a.batch)]), torch.device("cpu"))
    variants = [make_variant(s, base, cfg) for s in a.variants]
    for v in variants:  # warm-up: oneDNN primitives, allocator
        step(v, batch, cfg)
    for r in range(a.repeats):
        k = r % len(variants)
        for v in variants[k:] + variants[:k]:
            v["times"].append(step(v, batch, cfg))
        print(f"round {r + 1}: " + "  ".join(f"{v['spec']} {v['times'][-1]:.2f}s (cpu {v['cpu'][-1]:.2f}s)"
                                             for v in variants), flush=True)
    ref = statistics.median(variants[0]["times"])
    ref_cpu = statistics.median(variants[0]["cpu"])
    rows = []
    for v in variants:
        med, cpu = statistics.median(v["times"]), statistics.median(v["cpu"])
        # paired ratio: each round's time over the first variant's time of the same round
        paired = statistics.median(t / t0 for t, t0 in zip(v["times"], variants[0]["times"]))
        rows.append({"variant": v["spec"], "median_s": med, "min_s": min(v["times"]), "speedup_vs_first": ref / med,
                     "paired_speedup_vs_first": 1.0 / paired, "median_cpu_s": cpu,
                     "cpu_speedup_vs_first": ref_cpu / cpu, "times_s": v["times"], "cpu_s": v["cpu"]})
        print(f"{v['spec']:>16}: median {med:.3f} s/step (min {min(v['times']):.3f}), x{ref / med:.2f} vs "
              f"{variants[0]['spec']} (paired x{1.0 / paired:.2f}); CPU time median {cpu:.3f} s, x{ref_cpu / cpu:.2f}")
    if a.out:
        atomic_write_text(a.out, json.dumps({"config": vars(a) | {"out": str(a.out)}, "rows": rows,
                                             "machine": hardware_info("cpu")}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
