"""Adam update of ours (``train.optimizer`` adam_keras / adam_torch) against tf-keras' own Adam on the same gradients.

    PYTHONPATH=src python benchmarks/adam_vs_keras.py [--steps 20] [--out benchmarks/results/adam_vs_keras.json]

Needs ``TFREF_PY`` (a python with TensorFlow and tf-keras, ../shared/tools/tfref/README.md); without it, it says so
and exits 0. A fixed stream of gradients (seeded numpy; magnitudes from 1e-9 to 10, some exactly zero, signs mixed)
is applied for ``--steps`` steps to a float32 vector of zeros by ``tf.keras.optimizers.Adam(lr, epsilon=1e-7)`` (run in the
``TFREF_PY`` interpreter with ``TF_USE_LEGACY_KERAS=1``, the Keras 2 optimizer the original uses) and by both of our
optimizers. Reported: the largest difference of the parameters from Keras' after each step, absolute and relative
to the parameter's total movement, for each of ours.

With ``--data TREE`` (a Mid-Air-format tree with split CSVs in TREE/splits), also the gradient of one real training
batch (``--config midair`` at ``--size``, fresh weights, seed 0): the fraction of parameters whose first Adam step is
smaller in Keras' form than in PyTorch's (ratio ``(|g| + eps) / (|g| + eps / sqrt(1 - b2))`` at step 1), and the
parameter tensors most affected. This part needs no TensorFlow.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

KERAS_SIDE = r"""
import os, sys, numpy as np
os.environ.setdefault("TF_USE_LEGACY_KERAS", "1")
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
import tensorflow as tf
d = np.load(sys.argv[1])
var = tf.Variable(d["p0"])
opt = tf.keras.optimizers.Adam(learning_rate=float(d["lr"]), epsilon=float(d["eps"]))
out = []
for g in d["grads"]:
    opt.apply_gradients([(tf.constant(g), var)])
    out.append(var.numpy().copy())
np.savez(sys.argv[2], params=np.stack(out), keras=type(opt).__module__ + "." + type(opt).__name__,
         config=repr(opt.get_config()))
"""


def gradients(steps: int, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    scale = 10.0 ** rng.uniform(-9, 1, size=n)              # per coordinate, fixed over steps
    g = rng.standard_normal((steps, n)) * scale
    g[:, : n // 10] = 0.0                                    # never-used coordinates
    g[rng.random((steps, n)) < 0.1] = 0.0                    # occasional zero gradients
    return g.astype(np.float32)


def real_gradient_effect(data: str, size: int, eps: float) -> dict:
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from cosemdepth.models import build_model
    from cosemdepth.training.data import build_train_dataset, collate
    from cosemdepth.training.run_config import resolve_config
    from cosemdepth.training.trainer import compute_loss

    cfg = resolve_config("midair", values={"data.train.0.root": data, "data.train.0.split_dir": str(Path(data) / "splits"),
                                           "data.size": size, "train.seed": 0})
    ds = build_train_dataset(cfg.data, cfg.model, 0)
    torch.manual_seed(0)
    model = build_model(cfg.model)
    batch = collate([ds[i] for i in range(3)])
    out = model(batch["rgb"], batch["rot"], batch["trans"], batch["intrinsics"], batch.get("reset"))
    compute_loss(out, batch, cfg).total.backward()
    named = [(n, p.grad.detach().abs().double().flatten()) for n, p in model.named_parameters() if p.grad is not None]
    g = torch.cat([x for _, x in named])
    ratio = (g + eps) / (g + eps / math.sqrt(1 - 0.999))
    per_tensor = sorted(((float((x + eps).div(x + eps / math.sqrt(1 - 0.999)).mean()), n) for n, x in named))[:8]
    return {"parameters": int(g.numel()), "median_abs_grad": float(g.median()),
            "fraction_abs_grad_below": {f"{t:g}": float((g < t).double().mean()) for t in (3.2e-6, 1e-6, 3.2e-7)},
            "fraction_step1_keras_over_torch_below_0.9": float((ratio < 0.9).double().mean()),
            "fraction_step1_keras_over_torch_below_0.5": float((ratio < 0.5).double().mean()),
            "tensors_with_smallest_mean_ratio": [{"name": n, "mean_ratio": r} for r, n in per_tensor]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--eps", type=float, default=1e-7)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None)
    ap.add_argument("--data", default=None, help="tree for the real-gradient part")
    ap.add_argument("--size", type=int, default=128)
    a = ap.parse_args()
    tfpy = os.environ.get("TFREF_PY")
    real = real_gradient_effect(a.data, a.size, a.eps) if a.data else None
    if real:
        print("one real batch:", json.dumps(real))
    if not tfpy:
        print("TFREF_PY is not set: no TensorFlow to compare with (see ../shared/tools/tfref/README.md)")
        if a.out and real:
            Path(a.out).write_text(json.dumps({"benchmark": "adam_vs_keras", "real_gradient": real}, indent=1))
        return 0
    import torch

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from cosemdepth.training.optim import make_optimizer

    grads = gradients(a.steps, a.n, a.seed)
    # parameters start at 0 (the update does not depend on them): float32 then resolves each coordinate's movement
    p0 = np.zeros(a.n, np.float32)
    with tempfile.TemporaryDirectory() as tmp:
        inp, outp = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        np.savez(inp, p0=p0, grads=grads, lr=a.lr, eps=a.eps)
        r = subprocess.run([tfpy, "-c", KERAS_SIDE, inp, outp], capture_output=True, text=True)
        if r.returncode != 0:
            print(r.stderr[-2000:], file=sys.stderr)
            return 1
        k = np.load(outp)
        keras, kcls, kcfg = k["params"].astype(np.float64), str(k["keras"]), str(k["config"])
    res = {"benchmark": "adam_vs_keras", "keras_optimizer": kcls, "keras_config": kcfg, "steps": a.steps,
           "n": a.n, "lr": a.lr, "eps": a.eps, "ours": {}, "real_gradient": real}
    moved = np.abs(keras[-1] - p0.astype(np.float64)).max()
    for kind in ("adam_keras", "adam_torch"):
        p = torch.nn.Parameter(torch.from_numpy(p0.copy()))
        opt = make_optimizer(kind, [p], lr=a.lr, betas=(0.9, 0.999), eps=a.eps)
        worst, worst_rel = [], []
        for t in range(a.steps):
            p.grad = torch.from_numpy(grads[t])
            opt.step()
            diff = np.abs(p.detach().numpy().astype(np.float64) - keras[t])
            step_size = np.abs(keras[t] - p0) + 1e-12
            worst.append(float(diff.max()))
            # relative to each coordinate's movement, on coordinates that moved at least 1e-3 lr in Keras
            sel = step_size > 1e-3 * a.lr
            worst_rel.append(float((diff[sel] / step_size[sel]).max()) if sel.any() else 0.0)
        res["ours"][kind] = {"max_abs_diff_per_step": worst, "max_rel_diff_per_step_of_movement": worst_rel}
        print(f"{kind}: max |ours - keras| over {a.steps} steps {max(worst):.3g} (parameters moved up to "
              f"{moved:.3g}); worst relative to a coordinate's movement {max(worst_rel):.3g}")
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
