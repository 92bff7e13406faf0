"""How much the float16 cost volume the original trains with changes one training step's gradients (vs float32).

    PYTHONPATH=src python benchmarks/pscv_precision_grad.py --data TREE [--split-dir TREE/splits] [--size 128]
        [--batches 3] [--out benchmarks/results/pscv_precision_grad.json]

For a few training batches of ``cosemdepth train --config midair`` (augmented, seed 0) and the same freshly
initialised weights, computes the loss and gradients with ``model.pscv_dtype`` float32 and float16 and reports the
loss difference, the cosine between the two gradients and the relative norm of their difference. For scale, the
same numbers between the gradients of two different batches (float32) are given: a precision effect far below that
batch-to-batch difference is noise for Adam.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from cosemdepth.models import build_model  # noqa: E402
from cosemdepth.training.data import build_train_dataset, collate  # noqa: E402
from cosemdepth.training.run_config import resolve_config  # noqa: E402
from cosemdepth.training.trainer import compute_loss  # noqa: E402


def grads(model, batch, cfg):
    model.zero_grad(set_to_none=True)
    out = model(batch["rgb"], batch["rot"], batch["trans"], batch["intrinsics"], batch.get("reset"))
    loss = compute_loss(out, batch, cfg).total
    loss.backward()
    return float(loss), torch.cat([p.grad.flatten() for p in model.parameters() if p.grad is not None])


def compare(a, b) -> dict:
    a, b = a.double(), b.double()
    return {"cosine": float(torch.nn.functional.cosine_similarity(a, b, dim=0)),
            "rel_diff_norm": float((a - b).norm() / a.norm())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True)
    ap.add_argument("--split-dir", default=None)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--batches", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    cfg = resolve_config("midair", values={"data.train.0.root": a.data,
                                           "data.train.0.split_dir": a.split_dir or str(Path(a.data) / "splits"),
                                           "data.size": a.size, "train.seed": 0})
    ds = build_train_dataset(cfg.data, cfg.model, 0)
    torch.manual_seed(0)
    m32 = build_model(cfg.model)
    m16 = build_model(replace(cfg.model, pscv_dtype="float16"))
    m16.load_state_dict(m32.state_dict())
    rows, prev = [], None
    for k in range(a.batches):
        batch = collate([ds[3 * k + i] for i in range(3)])
        l32, g32 = grads(m32, batch, cfg)
        l16, g16 = grads(m16, batch, cfg)
        row = {"batch": k, "loss_fp32": l32, "loss_fp16": l16, "fp16_vs_fp32": compare(g32, g16)}
        if prev is not None:
            row["previous_batch_vs_this_fp32"] = compare(prev, g32)
        prev = g32
        rows.append(row)
        print(json.dumps(row))
    res = {"benchmark": "pscv_precision_grad", "size": a.size, "rows": rows}
    if a.out:
        Path(a.out).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
