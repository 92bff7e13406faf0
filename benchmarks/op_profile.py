"""Where the time goes, by op (torch.profiler): a streamed inference frame, or a training step by part of the model.

    python benchmarks/op_profile.py infer [--size 384] [--threads 2] [--precision bf16 int8] [--frames 3]
        [--model weights/synthair-cosemdepth] [--out benchmarks/results/op_profile_infer]
    python benchmarks/op_profile.py train [--size 128] [--batch 3] [--seq-len 4] [--threads 2] [--bf16]
        [--channels-last] [--steps 3] [--data ROOT --split-dir DIR] [--out benchmarks/results/op_profile_train]

``infer``: see :data:`INFER_DOC`; ``train``: see :data:`TRAIN_DOC`. Each writes ``OUT.json`` (the benchmark report
shape, ``params.mode`` the mode) and ``OUT.md`` when ``--out`` is given, else prints only. Timings on a shared
machine are indicative: the shares are what matters.
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import time
from collections import defaultdict
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile, record_function

from cosemdepth import load_model
from cosemdepth.bench.harness import make_report, write_report
from cosemdepth.data.toy import ToyDataset
from cosemdepth.devices import retain_freed_host_memory
from cosemdepth.export.check import synthetic_sequence
from cosemdepth.inference import FastModel
from cosemdepth.models import build_model
from cosemdepth.output_safety.atomic import atomic_write_text
from cosemdepth.training.config import RunConfig
from cosemdepth.training.data import collate, to_device
from cosemdepth.training.optim import make_optimizer
from cosemdepth.training.trainer import bf16_autocast, compute_loss, forward_batch, prepare_for_training

INFER_DOC = """Where a streamed frame's time goes on the fast path: torch.profiler by op, convolutions against everything else.

For each precision: the model on the fast path (int8: calibrated on 4 synthetic frames first), 3 warm-up frames,
then ``--frames`` profiled frames of one trajectory (batch 1). Self CPU time per op (the time of an op minus the ops
it calls), per frame; ops are grouped as convolutions (oneDNN fp32/bf16 and int8 convolution kernels) or other.
Wall time per frame is measured in a separate unprofiled pass (the profiler adds overhead per op). Timings are indicative on a shared machine.
"""
TRAIN_DOC = """Where a training step's time goes: torch.profiler by op and by part of the model (forward and backward).

Profiles ``--steps`` whole training steps (after one warm-up step) of the trainer's step function
(:meth:`cosemdepth.training.trainer.Trainer._train_step`'s work: forward, the fp32 loss, backward, the gradient
norm, Adam) on the toy batch, or on batches of a Mid-Air-format tree when ``--data`` is given (then the time of
fetching each batch from the DataLoader is measured too).

The parts of the model are marked without touching its code: forward hooks on the encoder, the refiners and the
decoders, and wrappers around the cost volumes, the warps and the normalisation where the decoders call them. The
backward is attributed to the same parts through the autograd sequence numbers (each backward node carries the
number of the forward op that created it).
"""

# --- infer: a streamed frame on the fast path ---

CONV_OPS = (
    "mkldnn::_convolution_pointwise",
    "onednn::qconv2d_pointwise",
    "aten::mkldnn_convolution",
    "aten::_convolution",
    "aten::convolution",
    "aten::conv2d",
    "quantized::conv2d",
)
PRECISION_DTYPES = {"fp32": "float32", "bf16": "bfloat16", "int8": "int8"}


def frames_for(size: int, n: int, seed: int):
    rgb, rot, trans, intr = synthetic_sequence(1, n, size, size, seed=seed)
    return [(rgb[:, k], rot[:, k], trans[:, k], intr, torch.tensor([k == 0])) for k in range(n)]


def prepare(model_path: str, precision: str, size: int):
    model = load_model(model_path, mode="reference")
    options = {"calibration": frames_for(size, 4, seed=2)} if precision == "int8" else {}
    return FastModel(model, PRECISION_DTYPES[precision], **options)


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
    ops = sorted(
        ({"op": k, "calls_per_frame": c / n, "self_ms_per_frame": ms / n} for k, (c, ms) in by_op.items()),
        key=lambda r: -r["self_ms_per_frame"],
    )
    total = sum(r["self_ms_per_frame"] for r in ops)
    conv = sum(r["self_ms_per_frame"] for r in ops if r["op"] in CONV_OPS)
    return {
        "precision": precision,
        "wall_ms_per_frame": [round(w * 1e3, 1) for w in walls],
        "wall_median_ms": round(statistics.median(walls) * 1e3, 1),
        "profiled_self_ms_per_frame": round(total, 1),
        "conv_ms_per_frame": round(conv, 1),
        "other_ms_per_frame": round(total - conv, 1),
        "conv_share": round(conv / total, 3),
        "ops": [
            {**r, "self_ms_per_frame": round(r["self_ms_per_frame"], 2)} for r in ops if r["self_ms_per_frame"] >= 0.05
        ],
    }


def infer_markdown(report: dict, top: int = 15) -> str:
    m = report["meta"]
    lines = [
        f"# Fast-path frame profile ({report['params']['size']} px, batch 1, {report['params']['threads']} threads) — indicative",
        "",
        f"Machine: {m.get('cpu_model')}, load average at start {m.get('loadavg')}; {m['date_utc']}.",
        "",
        "| precision | wall ms/frame (median, unprofiled) | profiled self ms/frame | convolutions | other | "
        "conv share |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in report["results"]["runs"]:
        lines.append(
            f"| {r['precision']} | {r['wall_median_ms']} | {r['profiled_self_ms_per_frame']} | "
            f"{r['conv_ms_per_frame']} | {r['other_ms_per_frame']} | {r['conv_share']:.0%} |"
        )
    for r in report["results"]["runs"]:
        lines += [
            "",
            f"## {r['precision']}: top ops by self time",
            "",
            "| op | calls/frame | self ms/frame |",
            "|---|---:|---:|",
        ]
        lines += [f"| `{o['op']}` | {o['calls_per_frame']:g} | {o['self_ms_per_frame']} |" for o in r["ops"][:top]]
    return "\n".join(lines) + "\n"


def infer_main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="op_profile.py infer", description=INFER_DOC.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=384)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--precision", nargs="+", choices=list(PRECISION_DTYPES), default=["bf16", "int8"])
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--model", default=str(Path(__file__).resolve().parents[1] / "weights" / "synthair-cosemdepth"))
    ap.add_argument("--out", default=None, help="output prefix: OUT.json, OUT.md (default: print only)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    runs = []
    for p in args.precision:
        r = profile_one(args.model, p, args.size, args.frames)
        runs.append(r)
        print(
            f"{p}: wall {r['wall_median_ms']} ms/frame; profiled {r['profiled_self_ms_per_frame']} ms = conv "
            f"{r['conv_ms_per_frame']} + other {r['other_ms_per_frame']}",
            flush=True,
        )
        for o in r["ops"][:12]:
            print(f"    {o['op']:<45} {o['calls_per_frame']:>6g} {o['self_ms_per_frame']:>8.2f}", flush=True)
    params = {
        "mode": "infer",
        "size": args.size,
        "threads": args.threads,
        "precision": args.precision,
        "frames": args.frames,
        "model": args.model,
        "batch": 1,
    }
    report = make_report("op_profile", params, {"runs": runs})
    if args.out:
        write_report(Path(args.out + ".json"), report)
        atomic_write_text(Path(args.out + ".md"), infer_markdown(report))
    return 0


# --- train: a training step by part of the model ---

#: Functions the decoders call, wrapped in a profiler range of this name (module, attribute, part).
WRAPPED = [
    ("cosemdepth.decoders.depth.decoder", "grouped_l2_normalize", "normalisation: grouped L2"),
    ("cosemdepth.decoders.semantic.decoder", "grouped_l2_normalize", "normalisation: grouped L2"),
    ("cosemdepth.decoders.depth.decoder", "resize_bl1", "resize"),
    ("cosemdepth.decoders.semantic.decoder", "resize_nn1", "resize"),
    ("cosemdepth.decoders.depth.decoder", "epipolar_geometry", "geometry (epipolar, parallax)"),
    ("cosemdepth.decoders.depth.decoder", "candidate_sample_points", "geometry (epipolar, parallax)"),
    ("cosemdepth.decoders.depth.decoder", "prev_depth_to_parallax", "geometry (epipolar, parallax)"),
    ("cosemdepth.decoders.depth.decoder", "parallax_to_depth", "geometry (epipolar, parallax)"),
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
            ref,
            pscv=_wrap(ref.pscv, "cost volume: parallax sweep (incl. warp)"),
            sncv=_wrap(ref.sncv, "cost volume: spatial (SNCV)"),
            concat=_wrap(ref.concat, "concatenation"),
        )

    def hook_pair(part):
        state = {}

        def pre(_m, _i):
            rf = record_function(PART_PREFIX + part)
            rf.__enter__()
            state.setdefault("stack", []).append(rf)

        def post(_m, _i, _o):
            state["stack"].pop().__exit__(None, None, None)

        return pre, post

    from cosemdepth.decoders.semantic import SemanticDecoder
    from cosemdepth.models.encoder import DINL, Encoder
    from cosemdepth.models.layers import Refiner

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
            part = r.name[len(PART_PREFIX) :] if r is not None else "model, other"
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


def train_main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="op_profile.py train", description=TRAIN_DOC.splitlines()[0])
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
    p.add_argument("--out", default=None, help="output prefix: OUT.json, OUT.md (default: print only)")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    retain_freed_host_memory()  # as the CPU trainer does (train.retain_host_memory)
    torch.manual_seed(0)
    cfg = RunConfig.from_dict(
        {"data": {"train": [{"name": "toy"}], "size": a.size, "seq_len": a.seq_len}, "train": {"bf16": a.bf16}}
    )
    device = torch.device("cpu")
    model = build_model(cfg.model).train()
    model = prepare_for_training(model, device, a.channels_last)
    opt = make_optimizer("adam_keras", model.parameters(), lr=1e-4, betas=(0.9, 0.999), eps=1e-7)  # the trainer's

    if a.data:
        from cosemdepth.training.data import build_train_dataset, make_loader

        d = {
            "data": {
                "train": [{"name": "midair", "root": a.data, **({"split_dir": a.split_dir} if a.split_dir else {})}],
                "size": a.size,
                "seq_len": a.seq_len,
                "num_workers": a.workers,
            }
        }
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
            norm = torch.linalg.vector_norm(
                torch.stack(torch._foreach_norm([q.grad for q in model.parameters() if q.grad is not None]))
            )
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
    rows = sorted(
        (
            {
                "part": k,
                "forward_ms": v["forward_ms"] / n,
                "backward_ms": v["backward_ms"] / n,
                "total_ms": (v["forward_ms"] + v["backward_ms"]) / n,
            }
            for k, v in parts.items()
        ),
        key=lambda r: -r["total_ms"],
    )
    if fetch_s:
        rows.append(
            {
                "part": "data loading (DataLoader fetch, %d workers)" % a.workers,
                "forward_ms": 1e3 * sum(fetch_s) / len(fetch_s),
                "backward_ms": 0.0,
                "total_ms": 1e3 * sum(fetch_s) / len(fetch_s),
            }
        )
    total_self = sum(r["total_ms"] for r in rows)
    by_op = sorted(prof.key_averages(), key=lambda k: -k.self_cpu_time_total)
    ops = [
        {"op": k.key, "calls_per_step": k.count / n, "self_ms": k.self_cpu_time_total / 1e3 / n}
        for k in by_op
        if not k.key.startswith(PART_PREFIX)
    ][:25]
    params = {
        "mode": "train",
        "size": a.size,
        "batch": a.batch,
        "seq_len": a.seq_len,
        "threads": a.threads,
        "bf16": a.bf16,
        "channels_last": a.channels_last,
        "steps": a.steps,
        "data": a.data or "toy batch",
        "workers": a.workers,
    }
    results = {
        "step_wall_s": walls,
        "step_wall_s_min": min(walls),
        "note": "profiled steps run slower than unprofiled ones (a few %); shares are what matters",
        "parts": rows,
        "parts_total_self_ms": total_self,
        "top_ops": ops,
    }
    report = make_report("op_profile", params, results)
    md = [
        f"# Training step profile ({a.size} px, batch {a.batch}, seq {a.seq_len}, {a.threads} threads, "
        f"{'bf16 autocast' if a.bf16 else 'fp32'}{', channels-last' if a.channels_last else ''})",
        "",
        f"Machine: {report['meta'].get('cpu_model')}, load average at start {report['meta'].get('loadavg')}; "
        f"steps (profiled) {', '.join(f'{w:.2f}' for w in walls)} s.",
        "",
        "| part | forward ms | backward ms | total ms | share |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        if r["total_ms"] < 0.5:
            continue
        md.append(
            f"| {r['part']} | {r['forward_ms']:.0f} | {r['backward_ms']:.0f} | {r['total_ms']:.0f} | "
            f"{100 * r['total_ms'] / total_self:.1f}% |"
        )
    md += ["", "| op | calls/step | self ms/step |", "|---|---:|---:|"]
    md += [f"| `{o['op']}` | {o['calls_per_step']:.0f} | {o['self_ms']:.1f} |" for o in ops]
    if a.out:
        out = Path(a.out)
        write_report(out.with_suffix(".json"), report)
        atomic_write_text(out.with_suffix(".md"), "\n".join(md) + "\n")
    print("\n".join(md))
    return 0


MODES = {"infer": infer_main, "train": train_main}


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] not in MODES:
        print(
            f"usage: python benchmarks/op_profile.py {{{','.join(MODES)}}} [options]  (-h after the mode for them)",
            file=sys.stderr,
        )
        return 2
    return MODES[argv[0]](argv[1:])


if __name__ == "__main__":
    sys.exit(main())
