"""Where a training step's time goes: torch.profiler by op and by part of the model (forward and backward).

    PYTHONPATH=src python benchmarks/train_profile.py [--size 128] [--batch 3] [--seq-len 4] [--threads 2]
        [--bf16] [--channels-last] [--steps 3] [--data ROOT --split-dir DIR] [--out benchmarks/results/NAME]

Profiles ``--steps`` whole training steps (after one warm-up step) of the trainer's step function
(:meth:`cosemdepth.training.trainer.Trainer._train_step`'s work: forward, the fp32 loss, backward, the gradient
norm, Adam) on the toy batch, or on batches of a Mid-Air-format tree when ``--data`` is given (then the time of
fetching each batch from the DataLoader is measured too).

The parts of the model are marked without touching its code: forward hooks on the encoder, the refiners and the
decoders, and wrappers around the cost volumes, the warps and the normalisation where the decoders call them. The
backward is attributed to the same parts through the autograd sequence numbers (each backward node carries the
number of the forward op that created it). Writes ``NAME.json`` and ``NAME.md`` (a table by part and the top ops).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile, record_function

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cosemdepth.bench.runner import hardware_info  # noqa: E402
from cosemdepth.config import RunConfig  # noqa: E402
from cosemdepth.devices import retain_freed_host_memory  # noqa: E402
from cosemdepth.io.atomic import atomic_write_text  # noqa: E402
from cosemdepth.models import build_model  # noqa: E402
from cosemdepth.training.data import collate, to_device  # noqa: E402
from cosemdepth.training.toy import ToyDataset  # noqa: E402
from cosemdepth.training.optim import make_optimizer  # noqa: E402
from cosemdepth.training.trainer import bf16_autocast, compute_loss, forward_batch, prepare_for_training  # noqa: E402

#: Functions the decoders call, wrapped in a profiler range of this name (module, attribute, part).
WRAPPED = [
    ("cosemdepth.models.depth_decoder", "grouped_l2_normalize", "normalisation: grouped L2"),
    ("cosemdepth.models.semantic_decoder", "grouped_l2_normalize", "normalisation: grouped L2"),
    ("cosemdepth.models.depth_decoder", "resize_bl1", "resize"),
    ("cosemdepth.models.semantic_decoder", "resize_nn1", "resize"),
    ("cosemdepth.models.depth_decoder", "epipolar_geometry", "geometry (epipolar, parallax)"),
    ("cosemdepth.models.depth_decoder", "candidate_sample_points", "geometry (epipolar, parallax)"),
    ("cosemdepth.models.depth_decoder", "prev_depth_to_parallax", "geometry (epipolar, parallax)"),
    ("cosemdepth.models.depth_decoder", "parallax_to_depth", "geometry (epipolar, parallax)"),
]
PART_PREFIX = "part: "
EVAL = "autograd::engine::evaluate_function"


def _wrap(fn, name):
    def inner(*args, **kwargs):
        with record_function(PART_PREFIX + name):
            return fn(*args, **kwargs)
    return inner


@contextlib.contextmanager
def marked(model):
    """Profiler ranges around the model's parts (hooks and wrapped functions), removed on exit."""
    import importlib

    saved, handles = [], []
    for mod_name, attr, part in WRAPPED:
        mod = importlib.import_module(mod_name)
        if hasattr(mod, attr):
            saved.append((mod, attr, getattr(mod, attr)))
            setattr(mod, attr, _wrap(getattr(mod, attr), part))

    pyr = importlib.import_module("cosemdepth.models.pyramid")
    if hasattr(pyr, "REFERENCE_OPS"):  # the levels' cost volumes and concatenations (the training forward's ops)
        import dataclasses

        ref = pyr.REFERENCE_OPS
        saved.append((pyr, "REFERENCE_OPS", ref))
        pyr.REFERENCE_OPS = dataclasses.replace(
            ref, pscv=_wrap(ref.pscv, "cost volume: parallax sweep (incl. warp)"),
            sncv=_wrap(ref.sncv, "cost volume: spatial (SNCV)"), concat=_wrap(ref.concat, "concatenation"))

    def hook_pair(part):
        state = {}

        def pre(_m, _i):
            rf = record_function(PART_PREFIX + part)
            rf.__enter__()
            state.setdefault("stack", []).append(rf)

        def post(_m, _i, _o):
            state["stack"].pop().__exit__(None, None, None)
        return pre, post

    from cosemdepth.models.encoder import DINL, Encoder
    from cosemdepth.models.layers import Refiner
    from cosemdepth.models.semantic_decoder import SemanticDecoder

    for m in model.modules():
        part = None
        if isinstance(m, DINL):
            part = "normalisation: DINL (encoder)"
        elif isinstance(m, Encoder):
            part = "encoder convolutions"
        elif isinstance(m, Refiner):
            part = "refiner convolutions (" + ("semantic" if "semantic" in _path(model, m) else "depth") + ")"
        elif isinstance(m, SemanticDecoder):
            part = "semantic decoder, other"
        elif type(m).__name__ == "DepthDecoder":
            part = "depth decoder, other (geometry, parallax)"
        if part:
            pre, post = hook_pair(part)
            handles += [m.register_forward_pre_hook(pre), m.register_forward_hook(post)]
    try:
        yield
    finally:
        for h in handles:
            h.remove()
        for mod, attr, fn in saved:
            setattr(mod, attr, fn)


def _path(model, module) -> str:
    for name, m in model.named_modules():
        if m is module:
            return name
    return ""


def _ancestor(ev, pred):
    e = ev.cpu_parent
    while e is not None and not pred(e):
        e = e.cpu_parent
    return e


def attribute(events) -> dict[str, dict[str, float]]:
    """Self CPU time (ms) per part, forward and backward. An op belongs to the innermost part range around it; an
    op of the backward belongs to the part of the forward op that created its autograd node (same sequence
    number)."""
    fixed = ("loss (fp32)", "optimizer (Adam)", "grad norm + finite check", "data loading")
    tops = set(fixed) | {"forward", "backward"}
    out: dict[str, dict[str, float]] = defaultdict(lambda: {"forward_ms": 0.0, "backward_ms": 0.0})
    seq_part: dict[int, str] = {}
    backward_ops = []
    for e in events:  # forward first: it fills seq_part
        if e.name.startswith(PART_PREFIX) or e.name in tops:
            continue
        if e.name.startswith(EVAL) or _ancestor(e, lambda x: x.name.startswith(EVAL)) is not None:
            backward_ops.append(e)
            continue
        top = _ancestor(e, lambda x: x.name in tops)
        where = top.name if top is not None else "other"
        if where == "forward":
            r = _ancestor(e, lambda x: x.name.startswith(PART_PREFIX))
            part = r.name[len(PART_PREFIX):] if r is not None else "model, other"
            if e.sequence_nr >= 0:
                seq_part.setdefault(e.sequence_nr, part)
            out[part]["forward_ms"] += e.self_cpu_time_total / 1e3
        else:
            out[where]["forward_ms"] += e.self_cpu_time_total / 1e3
    for e in backward_ops:
        node = e if e.name.startswith(EVAL) else _ancestor(e, lambda x: x.name.startswith(EVAL))
        part = None
        for cand in (node, e):
            if cand is not None and cand.sequence_nr >= 0 and part is None:
                part = seq_part.get(cand.sequence_nr)
        if part is None and node is not None:  # the node's own op events carry the number
            for c in node.cpu_children:
                if c.sequence_nr >= 0 and c.sequence_nr in seq_part:
                    part = seq_part[c.sequence_nr]
                    break
        if part is None and node is not None and "AccumulateGrad" in node.name:
            part = "gradient accumulation"
        out[part or "backward, unattributed"]["backward_ms"] += e.self_cpu_time_total / 1e3
    return dict(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--batch", type=int, default=3)
    p.add_argument("--seq-len", type=int, default=4)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--steps", type=int, default=3)
    p.add_argument("--bf16", action="store_true", help="bfloat16 autocast of the forward (train.bf16)")
    p.add_argument("--channels-last", action="store_true", help="model and input in channels-last")
    p.add_argument("--data", help="a Mid-Air-format tree (SynthAir) to read batches from (default: toy batch)")
    p.add_argument("--split-dir", help="split CSVs of --data (default: its own)")
    p.add_argument("--workers", type=int, default=0, help="DataLoader workers with --data")
    p.add_argument("--out", default="benchmarks/results/train_profile")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    retain_freed_host_memory()  # as the CPU trainer does (train.retain_host_memory)
    torch.manual_seed(0)
    cfg = RunConfig.from_dict({"data": {"train": [{"name": "toy"}], "size": a.size, "seq_len": a.seq_len},
                               "train": {"bf16": a.bf16}})
    device = torch.device("cpu")
    model = build_model(cfg.model).train()
    model = prepare_for_training(model, device, a.channels_last)
    opt = make_optimizer("adam_keras", model.parameters(), lr=1e-4, betas=(0.9, 0.999), eps=1e-7)  # the trainer's

    if a.data:
        from cosemdepth.training.data import build_train_dataset, make_loader

        d = {"data": {"train": [{"name": "midair", "root": a.data, **({"split_dir": a.split_dir} if a.split_dir
                                                                          else {})}],
                      "size": a.size, "seq_len": a.seq_len, "num_workers": a.workers}}
        dcfg = RunConfig.from_dict(d)
        dataset = build_train_dataset(dcfg.data, dcfg.model, 0)
        loader_iter = iter(make_loader(dataset, a.batch, a.workers, seed=0))
    else:
        toy = ToyDataset(length=a.batch, size=(a.size, a.size), seq_len=a.seq_len)
        fixed_batch = collate([toy[i] for i in range(a.batch)])
        loader_iter = None

    fetch_s = []

    def next_batch():
        if loader_iter is None:
            return fixed_batch
        t = time.perf_counter()
        with record_function("data loading"):
            b = next(loader_iter)
        fetch_s.append(time.perf_counter() - t)
        return b

    def step():
        batch = to_device(next_batch(), device)
        with record_function("forward"):
            with bf16_autocast(device, a.bf16):
                out = forward_batch(model, batch)
        with record_function("loss (fp32)"):
            loss = compute_loss(out, batch, cfg).total
        opt.zero_grad(set_to_none=True)
        with record_function("backward"):
            loss.backward()
        with record_function("grad norm + finite check"):
            norm = torch.linalg.vector_norm(torch.stack(torch._foreach_norm([q.grad for q in model.parameters()
                                                                            if q.grad is not None])))
            ok = bool(torch.isfinite(loss)) and bool(torch.isfinite(norm))
        with record_function("optimizer (Adam)"):
            if ok:
                opt.step()
        return float(loss.detach())

    step()  # warm-up (oneDNN primitive creation, allocator)
    walls = []
    with marked(model):
        with profile(activities=[ProfilerActivity.CPU], record_shapes=False) as prof:
            for _ in range(a.steps):
                t = time.perf_counter()
                step()
                walls.append(time.perf_counter() - t)
    events = prof.events()
    parts = attribute(events)
    n = a.steps
    rows = sorted(({"part": k, "forward_ms": v["forward_ms"] / n, "backward_ms": v["backward_ms"] / n,
                    "total_ms": (v["forward_ms"] + v["backward_ms"]) / n} for k, v in parts.items()),
                  key=lambda r: -r["total_ms"])
    if fetch_s:
        rows.append({"part": "data loading (DataLoader fetch, %d workers)" % a.workers,
                     "forward_ms": 1e3 * sum(fetch_s) / len(fetch_s), "backward_ms": 0.0,
                     "total_ms": 1e3 * sum(fetch_s) / len(fetch_s)})
    total_self = sum(r["total_ms"] for r in rows)
    by_op = sorted(prof.key_averages(), key=lambda k: -k.self_cpu_time_total)
    ops = [{"op": k.key, "calls_per_step": k.count / n, "self_ms": k.self_cpu_time_total / 1e3 / n}
           for k in by_op if not k.key.startswith(PART_PREFIX)][:25]
    report = {
        "config": {"size": a.size, "batch": a.batch, "seq_len": a.seq_len, "threads": a.threads, "bf16": a.bf16,
                   "channels_last": a.channels_last, "steps": a.steps, "data": a.data or "toy batch",
                   "workers": a.workers},
        "step_wall_s": walls, "step_wall_s_min": min(walls),
        "note": "profiled steps run slower than unprofiled ones (a few %); shares are what matters",
        "parts": rows, "parts_total_self_ms": total_self, "top_ops": ops, "machine": hardware_info("cpu"),
    }
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out.with_suffix(".json"), json.dumps(report, indent=1) + "\n")
    md = [f"# Training step profile ({a.size} px, batch {a.batch}, seq {a.seq_len}, {a.threads} threads, "
          f"{'bf16 autocast' if a.bf16 else 'fp32'}{', channels-last' if a.channels_last else ''})", "",
          f"Machine: {report['machine'].get('cpu')}, load average at start {report['machine'].get('loadavg_start')}; "
          f"steps (profiled) {', '.join(f'{w:.2f}' for w in walls)} s.", "",
          "| part | forward ms | backward ms | total ms | share |", "|---|---:|---:|---:|---:|"]
    for r in rows:
        if r["total_ms"] < 0.5:
            continue
        md.append(f"| {r['part']} | {r['forward_ms']:.0f} | {r['backward_ms']:.0f} | {r['total_ms']:.0f} | "
                  f"{100 * r['total_ms'] / total_self:.1f}% |")
    md += ["", "| op | calls/step | self ms/step |", "|---|---:|---:|"]
    md += [f"| `{o['op']}` | {o['calls_per_step']:.0f} | {o['self_ms']:.1f} |" for o in ops]
    atomic_write_text(out.with_suffix(".md"), "\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
