"""Compare every inference path with the authors' TensorFlow outputs of the fixture ``tfref-s128``.

    PYTHONPATH=src python benchmarks/tf_fixture_fast.py [--fixture ../shared/fixtures/tfref-s128] [--out FILE]

Loads the fixture's TF checkpoint (``cosemdepth.io.model_io.load_model``, which converts official checkpoints),
streams its 4 frames through the reference path, the fast fp32 path and the fast bf16 path, and reports per frame the
largest relative parallax difference, the depth difference (absolute and relative to |depth| + 1 m, since random
weights give depths near zero) and the largest semantic-probability difference against the TF outputs. Writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from cosemdepth.io.atomic import atomic_write_text  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    fixtures = Path(os.environ.get("COSEMDEPTH_FIXTURES", ROOT.parent / "shared" / "fixtures"))
    p.add_argument("--fixture", default=str(fixtures / "tfref-s128"), help="default: $COSEMDEPTH_FIXTURES/tfref-s128")
    p.add_argument("--out", default="benchmarks/results/tf_fixture_fast.json")
    a = p.parse_args(argv)
    from cosemdepth.io.model_io import load_model

    fx = Path(a.fixture)
    ref = np.load(fx / "reference.npz")
    nchw = lambda x: torch.from_numpy(np.ascontiguousarray(x)).permute(0, 3, 1, 2)  # noqa: E731
    t = ref["rgb"].shape[0]
    h, w = ref["rgb"].shape[2:4]
    f, c = ref["camera_f"][0], ref["camera_c"][0]
    K = torch.tensor([[f[0], f[1], c[0], c[1]]], dtype=torch.float32)
    modes = {"reference": None, "fast-fp32": "float32", "fast-bf16": "bfloat16"}
    report = {"fixture": str(fx), "size": [int(h), int(w)], "frames": int(t), "modes": {}}
    for name, dtype in modes.items():
        model = load_model(fx / "ckpt", mode="reference").eval()
        if dtype:
            model.optimize("fast", dtype=dtype)
        state, rows = None, []
        with torch.no_grad():
            for k in range(t):
                out, state = model.step(
                    nchw(ref["rgb"][k]),
                    torch.from_numpy(ref["rot"][k]),
                    torch.from_numpy(ref["trans"][k]),
                    K,
                    torch.from_numpy(ref["new_traj"][k]),
                    state,
                )
                tf_depth = nchw(ref["infer_depth"][k])
                tf_sem = nchw(ref["infer_semantic"][k])
                row = {"frame": k}
                para = [
                    float(((out.levels["parallax"][j] - nchw(ref[f"infer_lvl{j + 1}_parallax"][k])).abs()
                           / nchw(ref[f"infer_lvl{j + 1}_parallax"][k]).abs()).max())
                    for j in range(len(out.levels["parallax"]))
                ]
                row["parallax_max_rel"] = max(para)
                d = (out.depth - tf_depth).abs()
                row["depth_max_abs_m"] = float(d.max())
                row["depth_max_rel_to_abs_depth_plus_1m"] = float((d / (tf_depth.abs() + 1)).max())
                row["depth_median_rel"] = float((d / tf_depth.abs().clamp_min(1e-6)).median())
                row["semantic_max_abs"] = float((out.semantic - tf_sem).abs().max())
                row["labels_agree"] = float((out.semantic.argmax(1) == tf_sem.argmax(1)).float().mean())
                rows.append(row)
        report["modes"][name] = rows
        worst = {k: max(r[k] for r in rows) for k in rows[0] if k not in ("frame", "labels_agree")}
        agree = min(r["labels_agree"] for r in rows)
        print(name, {k: f"{v:.2e}" for k, v in worst.items()}, f"labels agree >= {agree:.4f}")
    atomic_write_text(a.out, json.dumps(report, indent=1) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
