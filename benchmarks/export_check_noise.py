"""Which float32 rounding differences move the outputs as far as ONNX Runtime does: the figures behind the noise run
of ``cosemdepth export --check`` (docs/deploy.md, "What --check compares").

    python benchmarks/export_check_noise.py [--size 384] [--frames 6]
        [--model weights/synthair-cosemdepth] [--out benchmarks/results/export_check_noise]

Exports the model at ``--size`` (batch 1), then streams the check's SynthAir flight (resets at frame 0 and in the
middle) through ONNX Runtime and, on the same inputs and ONNX Runtime's incoming state, through the PyTorch reference
path and these float32 variants that differ from it only in the order of the floating-point operations:

* ``fast``: the fast engine (``FastModel(model)``: pre-packed channels-last convolutions, other cost-volume sums);
* ``onednn_off``: the reference modules with oneDNN switched off (PyTorch's own im2col + GEMM convolutions);
* ``channels_last``: the reference modules on channels-last tensors (oneDNN's NHWC kernels);
* ``chains_L``: DINL's two means over H x W summed in L sequential float32 chains (L = 4, 8, 16);
* ``noise_run``: what the check uses (:func:`cosemdepth.export.check.noise_model`).

Per frame and variant: the normalised RMS distance to the reference of depth, semantic probabilities and the worst
state tensor, and the 99th percentile of the per-pixel relative depth difference (the check's metrics). Writes
``OUT.json`` and ``OUT.md``.
"""

from __future__ import annotations

import argparse
import copy
import tempfile
from pathlib import Path

import numpy as np
import torch

from cosemdepth import load_model
from cosemdepth.bench.harness import make_report, write_report
from cosemdepth.export.check import (
    CHECK_FRAMES,
    flight_sequence,
    noise_model,
    nrms,
    relative_percentile,
    run_onnx_stream,
    sequential_spatial_mean,
    valid_depth,
)
from cosemdepth.export.onnx import export_onnx
from cosemdepth.inference import FastModel
from cosemdepth.models.outputs import StreamState
from cosemdepth.output_safety.atomic import atomic_write_text


def _cl(x):
    return x.contiguous(memory_format=torch.channels_last) if x.dim() == 4 else x


def variants(model):
    """``name -> step(args, state)`` for every variant (the model on its reference path)."""
    fast = FastModel(copy.deepcopy(model))
    cl = copy.deepcopy(model).to(memory_format=torch.channels_last)
    chains = {}
    for lanes in (4, 8, 16):
        m = copy.deepcopy(model)
        m.encoder.dinl.spatial_mean = lambda x, lanes=lanes: sequential_spatial_mean(x, lanes)
        chains[lanes] = m
    noisy = noise_model(model)

    def onednn_off(args, st):
        with torch.backends.mkldnn.flags(enabled=False):
            return model.step(*args, st)

    def on_cl(m):
        return lambda args, st: m.step(
            *map(_cl, args), None if st is None else StreamState.unflatten([_cl(t) for t in st.flatten()])
        )

    out = {"fast": lambda args, st: fast.step(*args, st), "onednn_off": onednn_off, "channels_last": on_cl(cl)}
    out.update({f"chains_{n}": (lambda args, st, m=m: m.step(*args, st)) for n, m in chains.items()})
    out["noise_run"] = on_cl(noisy)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=384)
    ap.add_argument("--frames", type=int, default=CHECK_FRAMES)
    ap.add_argument("--model", default="weights/synthair-cosemdepth")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    import onnxruntime as ort

    out = Path(args.out or "benchmarks/results/export_check_noise")
    model = load_model(args.model, mode="reference")
    with tempfile.TemporaryDirectory() as tmp:
        path = export_onnx(model, Path(tmp) / "step.onnx", args.size, args.size)
        sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    steps = variants(model)
    rgb, rot, trans, intr = flight_sequence(1, args.frames, args.size, args.size)
    reset = torch.zeros(1, args.frames, dtype=torch.bool)
    reset[:, 0] = reset[:, args.frames // 2] = True
    state = [np.zeros(i.shape, np.float32) for i in sess.get_inputs() if i.name.startswith("state_")]
    rows = []
    with torch.no_grad():
        for k in range(args.frames):
            feeds = {
                "rgb": rgb[:, k].numpy(),
                "rot": rot[:, k].numpy(),
                "trans": trans[:, k].numpy(),
                "intrinsics": intr.numpy(),
                "reset": reset[:, k].numpy(),
            }
            st = StreamState.unflatten([torch.from_numpy(s) for s in state]) if k > 0 else None
            res, state = run_onnx_stream(sess, feeds, state)
            a = (rgb[:, k], rot[:, k], trans[:, k], intr, reset[:, k])
            ref, ref_state = model.step(*a, st)
            d, s = ref.depth.numpy(), ref.semantic.numpy()
            ref_st = [t.numpy() for t in ref_state.flatten()]
            ok = valid_depth(d, reset[:, k].numpy())
            results = {"onnxruntime": (res["depth"], res["semantic"], state)}
            for name, step in steps.items():
                o, n = step(a, st)
                results[name] = (o.depth.numpy(), o.semantic.numpy(), [t.numpy() for t in n.flatten()])
            for name, (od, osem, ost) in results.items():
                p99 = relative_percentile(od, d, ok)
                rows.append(
                    {
                        "frame": k,
                        "reset": bool(reset[0, k]),
                        "run": name,
                        "depth_nrms": nrms(od, d),
                        "depth_p99": p99,
                        "semantic_nrms": nrms(osem, s),
                        "state_nrms": max(nrms(x, y) for x, y in zip(ost, ref_st)),
                    }
                )
            print(f"frame {k} done", flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    params = {"size": args.size, "frames": args.frames, "model": args.model}
    write_report(out.with_suffix(".json"), make_report("export_check_noise", params, rows))
    md = [
        f"# Distance to the PyTorch float32 reference, {args.size} px, {args.model}",
        "",
        "| frame | run | depth nRMS | depth p99 rel. | semantic nRMS | state nRMS |",
        "|---|---|---|---|---|---|",
    ]
    fmt = lambda x: "-" if x is None else f"{x:.2e}"  # noqa: E731
    for r in rows:
        md.append(
            f"| {r['frame']}{' (reset)' if r['reset'] else ''} | {r['run']} | {fmt(r['depth_nrms'])} | "
            f"{fmt(r['depth_p99'])} | {fmt(r['semantic_nrms'])} | {fmt(r['state_nrms'])} |"
        )
    atomic_write_text(out.with_suffix(".md"), "\n".join(md) + "\n")
    print(f"wrote {out.with_suffix('.json')} and {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
