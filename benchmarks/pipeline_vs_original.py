"""Training batches of ours against the original's data pipeline, statistically, on the same tree and split CSVs.

    TFREF_PY=... COSEM_AUTHORS=... PYTHONPATH=src python benchmarks/pipeline_vs_original.py \
        --data TREE --split-dir TREE/splits --prep PREP [--size 128] [--epochs 20] [--out out.json]

Our side: the training dataset of ``cosemdepth train --config midair`` (``build_train_dataset``, the trainer's
``ResumableSampler`` order) at ``--size``. The original's side: the authors' midair dataloader, ``get_dataset("train")``
with their augmentation (imported unmodified from ``COSEM_AUTHORS`` by the project's tfref harness,
``train_reference.setup_tensorflow``; nothing of it is copied here), run in ``TFREF_PY`` on the tfref-prepared
``--prep`` (made by ``tfref_prep.py`` when missing: the harness' prepare stage; SynthAir's disparities are
Mid-Air's ``512 / z`` at every size, so both sides read the same depths). ``--epochs`` passes over the training
chunks on each side.

Per sequence, both sides record: pixel statistics of the colour frames after augmentation (mean, std, min, max,
fraction below 0 and above 1), a 16x16 grey thumbnail of frame 0, depth statistics (median, fraction at or beyond the
loss clip of 200 m), the class histogram, the motion (rot, trans) and the reset flags. The analysis then finds, for
every sequence, the CSV chunk and the flips/transposition that map the CSV motion onto it (all 8 combinations tried),
and whether the colours were inverted (sign of the correlation of the thumbnail with the source frame's, after the
same geometric operation). Reported per side: the fractions of flips, transpositions and inversions, chunk coverage
per epoch, the distributions of the pixel statistics (quantiles, and the two-sample Kolmogorov-Smirnov distance
between the sides), depth and class statistics, and motion component statistics.

Also: ``tf.image.adjust_brightness/contrast/saturation/hue`` against ours on one fixed input (largest difference).

Without ``TFREF_PY``/``COSEM_AUTHORS`` it says so and reports our side only.
"""

from __future__ import annotations

import argparse
import csv
import glob
import json
import os
import subprocess
import sys
import tempfile
import types
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
TFREF_TOOLS = Path(os.environ.get("TFREF_TOOLS", HERE.parents[2] / "shared" / "tools" / "tfref"))
THUMB = 16


# ---------------------------------------------------------------------------------------------------- records
def colour_op_inputs() -> np.ndarray:
    """A fixed [2, 4, 32, 32, 3] float32 input for the colour-op check: values in [-0.3, 1.3] (what brightness and
    contrast can produce), a patch in [0, 1], a grey patch and an all-negative patch."""
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.3, 1.3, size=(2, 4, 32, 32, 3)).astype(np.float32)
    x[0, 0, :8] = rng.uniform(0, 1, size=(8, 32, 3))
    x[0, 1, :4] = 0.5
    x[1, 0, :4] = -0.1
    return x


COLOUR_OPS = [("brightness", 0.15), ("brightness", -0.2), ("contrast", 1.2), ("contrast", 0.75),
              ("saturation", 1.2), ("saturation", 0.8), ("hue", 0.3), ("hue", -0.37)]


def record(rgb, depth, sem, rot, trans, reset, num_classes=7) -> dict:
    """One sequence, channels last: rgb [T,H,W,3] float, depth [T,H,W], sem [T,H,W] int."""
    rgb = np.asarray(rgb, np.float64)
    t, h, w, _ = rgb.shape
    g = rgb[0].mean(-1)
    thumb = g.reshape(THUMB, h // THUMB, THUMB, w // THUMB).mean((1, 3))
    d = np.asarray(depth, np.float64)
    return {
        "mean": rgb.mean(), "std": rgb.std(), "min": rgb.min(), "max": rgb.max(),
        "lt0": float((rgb < 0).mean()), "gt1": float((rgb > 1).mean()),
        "all_le0": float((rgb.max(-1) <= 0).mean()),
        "chan_mean": rgb.mean((0, 1, 2)), "thumb": thumb,
        "depth_median": float(np.median(d)), "depth_ge200": float((d >= 200).mean()),
        "logdepth_mean": float(np.log(np.clip(d, 0.01, 200)).mean()),
        "sem_hist": np.bincount(np.asarray(sem, np.int64).ravel(), minlength=num_classes)[:num_classes] / d.size,
        "rot": np.asarray(rot, np.float64), "trans": np.asarray(trans, np.float64),
        "reset": np.asarray(reset, bool),
    }


def stack(records: list[dict]) -> dict:
    return {k: np.stack([np.asarray(r[k]) for r in records]) for k in records[0]}


# ---------------------------------------------------------------------------------------------------- original side
def original_side(a) -> None:
    """Runs in TFREF_PY: the authors' train dataset through the tfref harness; writes an npz of records."""
    sys.path.insert(0, str(TFREF_TOOLS))
    import train_reference as tr  # the project's harness (it imports the authors' code unmodified)

    ns = types.SimpleNamespace(xla_auto_jit=False, intra_threads=1, inter_threads=1, deterministic=False,
                               keras_init="tf27", repo=a.authors)
    tf, common, csd, dl, cbk, env = tr.setup_tensorflow(ns)
    prep_info = json.load(open(os.path.join(a.prep, "prepare.json")))
    settings = tr.dataloader_settings(dl, prep_info, "train", a.db_seq_len, a.seq_len, True)
    tf.random.set_seed(a.seed)
    loader = dl.get_loader("midair")
    loader.get_dataset("train", settings, batch_size=a.batch, out_size=[a.size, a.size])
    per_epoch = int(loader.length)
    recs, epochs = [], []
    for e, batch in enumerate(loader.dataset.repeat(a.epochs)):
        b = {k: (v.numpy() if hasattr(v, "numpy") else v) for k, v in batch.items() if k != "camera"}
        for i in range(b["RGB_im"].shape[0]):
            recs.append(record(b["RGB_im"][i], b["depth"][i][..., 0], b["semantic"][i][..., 0], b["rot"][i],
                               b["trans"][i], b["new_traj"][i]))
            epochs.append(e // per_epoch)
    out = stack(recs)
    out["epoch"] = np.asarray(epochs)
    x = colour_op_inputs()
    fns = {"brightness": tf.image.adjust_brightness, "contrast": tf.image.adjust_contrast,
           "saturation": tf.image.adjust_saturation, "hue": tf.image.adjust_hue}
    out["colour_ops"] = np.stack([np.stack([fns[op](im, v).numpy() for im in x]) for op, v in COLOUR_OPS])
    np.savez(a.dump, **out)


# ---------------------------------------------------------------------------------------------------- our side
def our_side(a) -> dict:
    import torch

    sys.path.insert(0, str(HERE.parents[1] / "src"))
    from cosemdepth.training.data import ResumableSampler, build_train_dataset, steps_per_epoch
    from cosemdepth.training.run_config import resolve_config

    cfg = resolve_config("midair", values={"data.train.0.root": a.data, "data.train.0.split_dir": a.split_dir,
                                           "data.size": a.size, "data.seq_len": a.seq_len,
                                           "data.db_seq_len": a.db_seq_len, "train.seed": a.seed})
    ds = build_train_dataset(cfg.data, cfg.model, cfg.train.seed)
    sampler = ResumableSampler(ds, shuffle=True, seed=cfg.train.seed)
    n = steps_per_epoch(ds, a.batch, 1) * a.batch
    recs, epochs = [], []
    torch.set_num_threads(1)
    for e in range(a.epochs):
        sampler.set_position(e)
        ds.set_epoch(e)
        for idx in list(sampler)[:n]:
            it = ds[idx]
            recs.append(record(it["rgb"].permute(0, 2, 3, 1).numpy(), it["depth"][:, 0].numpy(),
                               it["semantic"].numpy(), it["rot"].numpy(), it["trans"].numpy(), it["reset"].numpy()))
            epochs.append(e)
    out = stack(recs)
    out["epoch"] = np.asarray(epochs)
    return out


# ---------------------------------------------------------------------------------------------------- analysis
def read_chunks(split_dir: str, db_seq_len: int) -> list[dict]:
    chunks = []
    for f in sorted(glob.glob(os.path.join(split_dir, "train_data", "**", "*.csv"), recursive=True)):
        with open(f, newline="") as fh:
            rows = list(csv.DictReader(fh, delimiter="\t"))
        for s in range(0, len(rows) - db_seq_len + 1, db_seq_len):
            part = rows[s:s + db_seq_len]
            chunks.append({"csv": f, "start": s, "rgb": [r["camera_l"] for r in part],
                           "rot": np.array([[float(r[k]) for k in ("qw", "qx", "qy", "qz")] for r in part]),
                           "trans": np.array([[float(r[k]) for k in ("tx", "ty", "tz")] for r in part])})
    return chunks


def geometric(rot, trans, v, h, tr):
    """The motion after vertical flip, horizontal flip, transposition (in this order), as design 9.3 / the original."""
    rot, trans = rot.copy(), trans.copy()
    if v:
        rot *= [1, -1, 1, -1]
        trans *= [1, -1, 1]
    if h:
        rot *= [1, 1, -1, -1]
        trans *= [-1, 1, 1]
    if tr:
        rot = np.stack([rot[:, 0], -rot[:, 2], -rot[:, 1], -rot[:, 3]], 1)
        trans = np.stack([trans[:, 1], trans[:, 0], trans[:, 2]], 1)
    return rot, trans


def thumb_of(path: str, size: int, v, h, tr) -> np.ndarray:
    from PIL import Image

    im = Image.open(path).convert("RGB").resize((size, size), Image.BILINEAR)
    g = np.asarray(im, np.float64).mean(-1) / 255.0
    if v:
        g = g[::-1]
    if h:
        g = g[:, ::-1]
    if tr:
        g = g.T
    return g.reshape(THUMB, size // THUMB, THUMB, size // THUMB).mean((1, 3))


def match(recs: dict, chunks: list[dict], root: str, size: int, seq_len: int) -> dict:
    combos = [(v, h, t) for v in (0, 1) for h in (0, 1) for t in (0, 1)]
    n = len(recs["mean"])
    flags = np.zeros((n, 3), bool)
    inverted = np.zeros(n, bool)
    chunk_id = np.full(n, -1)
    offset = np.full(n, -1)
    ambiguous = 0
    cache = {}
    for i in range(n):
        best = []
        for ci, c in enumerate(chunks):
            for off in range(len(c["rot"]) - seq_len + 1):
                for cb in combos:
                    r, t = geometric(c["rot"][off:off + seq_len], c["trans"][off:off + seq_len], *cb)
                    err = np.abs(r - recs["rot"][i]).max() + np.abs(t - recs["trans"][i]).max()
                    best.append((err, ci, off, cb))
        best.sort(key=lambda x: x[0])
        err, ci, off, cb = best[0]
        if len(best) > 1 and best[1][0] < 1e-5:
            ambiguous += 1
        flags[i], chunk_id[i], offset[i] = cb, ci, off
        key = (ci, off, cb)
        if key not in cache:
            cache[key] = thumb_of(os.path.join(root, chunks[ci]["rgb"][off]), size, *cb)
        src = cache[key].ravel()
        got = recs["thumb"][i].ravel()
        inverted[i] = np.corrcoef(src, got)[0, 1] < 0
    return {"flags": flags, "inverted": inverted, "chunk": chunk_id, "offset": offset, "ambiguous": ambiguous}


def ks(x, y) -> float:
    x, y = np.sort(np.asarray(x, float)), np.sort(np.asarray(y, float))
    z = np.concatenate([x, y])
    return float(np.abs(np.searchsorted(x, z, "right") / len(x) - np.searchsorted(y, z, "right") / len(y)).max())


def quant(x) -> list:
    return [float(v) for v in np.quantile(np.asarray(x, float), [0, 0.05, 0.25, 0.5, 0.75, 0.95, 1])]


def summarize(recs: dict, m: dict, n_chunks: int) -> dict:
    n = len(recs["mean"])
    cover = []
    for e in np.unique(recs["epoch"]):
        sel = m["chunk"][recs["epoch"] == e]
        cover.append({"sequences": int(sel.size), "distinct_chunks": int(np.unique(sel).size),
                      "max_repeats": int(np.bincount(sel, minlength=n_chunks).max())})
    return {
        "sequences": n,
        "fraction_vflip": float(m["flags"][:, 0].mean()), "fraction_hflip": float(m["flags"][:, 1].mean()),
        "fraction_transpose": float(m["flags"][:, 2].mean()), "fraction_inverted": float(m["inverted"].mean()),
        "ambiguous_motion_matches": m["ambiguous"],
        "window_offsets": np.bincount(m["offset"]).tolist(),
        "coverage_per_epoch": cover[:3], "chunks": n_chunks,
        "reset_patterns": {str(k.astype(int).tolist()): int(v) for k, v in
                           zip(*np.unique(recs["reset"], axis=0, return_counts=True))},
        "pixel": {k: quant(recs[k]) for k in ("mean", "std", "min", "max", "lt0", "gt1", "all_le0")},
        "mean_fraction_of_pixels_all_channels_le0": float(recs["all_le0"].mean()),
        "fraction_of_sequences_with_values_outside_0_1": float(((recs["lt0"] > 0) | (recs["gt1"] > 0)).mean()),
        "depth_median": quant(recs["depth_median"]), "depth_ge200": quant(recs["depth_ge200"]),
        "logdepth_mean": quant(recs["logdepth_mean"]),
        "class_fraction_mean": recs["sem_hist"].mean(0).tolist(),
        "trans_mean": recs["trans"].reshape(-1, 3).mean(0).tolist(), "trans_std": recs["trans"].reshape(-1, 3).std(0).tolist(),
        "rot_mean": recs["rot"].reshape(-1, 4).mean(0).tolist(), "rot_std": recs["rot"].reshape(-1, 4).std(0).tolist(),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True)
    ap.add_argument("--split-dir", required=True)
    ap.add_argument("--prep", default=None, help="tfref prepare folder (made here when missing)")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--batch", type=int, default=3)
    ap.add_argument("--seq-len", type=int, default=4)
    ap.add_argument("--db-seq-len", type=int, default=4)
    ap.add_argument("--epochs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None)
    ap.add_argument("--side", choices=["both", "original"], default="both", help=argparse.SUPPRESS)
    ap.add_argument("--dump", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--authors", default=os.environ.get("COSEM_AUTHORS"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.side == "original":
        original_side(a)
        return 0
    tfpy, authors = os.environ.get("TFREF_PY"), os.environ.get("COSEM_AUTHORS")
    chunks = read_chunks(a.split_dir, a.db_seq_len)
    res = {"benchmark": "pipeline_vs_original", "data": os.path.abspath(a.data), "size": a.size,
           "batch": a.batch, "seq_len": a.seq_len, "db_seq_len": a.db_seq_len, "epochs": a.epochs, "seed": a.seed}
    sides = {"ours": our_side(a)}
    if tfpy and authors:
        sys.path.insert(0, str(HERE.parent))
        from tfref_prep import prepare_for_original

        prep = a.prep or tempfile.mkdtemp(prefix="tfref_prep_")
        res["original_prep"] = prepare_for_original(tfpy, authors, a.data, a.split_dir, prep)
        with tempfile.TemporaryDirectory() as tmp:
            dump = os.path.join(tmp, "orig.npz")
            subprocess.run([tfpy, str(HERE), "--side", "original", "--data", a.data, "--split-dir", a.split_dir,
                            "--prep", prep, "--size", str(a.size), "--batch", str(a.batch), "--seq-len",
                            str(a.seq_len), "--db-seq-len", str(a.db_seq_len), "--epochs", str(a.epochs),
                            "--seed", str(a.seed), "--dump", dump, "--authors", authors], check=True,
                           env={**os.environ, "TF_USE_LEGACY_KERAS": "1", "TF_CPP_MIN_LOG_LEVEL": "2"})
            sides["original"] = dict(np.load(dump))
    else:
        print("TFREF_PY and COSEM_AUTHORS are not set: our pipeline only (see ../shared/tools/tfref/README.md)")
    for name, recs in sides.items():
        res[name] = summarize(recs, match(recs, chunks, a.data, a.size, a.seq_len), len(chunks))
    if "original" in sides:
        import torch

        from cosemdepth.data import augment as A

        ours_fns = {"brightness": A.adjust_brightness, "contrast": A.adjust_contrast,
                    "saturation": A.adjust_saturation, "hue": A.adjust_hue}
        x = torch.from_numpy(colour_op_inputs()).permute(0, 1, 4, 2, 3)
        tf_out = sides["original"].pop("colour_ops")
        res["colour_ops_vs_tf"] = {
            f"{op} {v}": float(np.abs(ours_fns[op](x, v).permute(0, 1, 3, 4, 2).numpy() - tf_out[k]).max())
            for k, (op, v) in enumerate(COLOUR_OPS)}
        res["colour_ops_note"] = ("largest |ours - tf.image.adjust_*| on a fixed input with values in [-0.3, 1.3] "
                                  "(incl. grey and all-negative pixels)")
        o, u = sides["original"], sides["ours"]
        res["ks_distance_ours_vs_original"] = {k: ks(u[k], o[k]) for k in (
            "mean", "std", "min", "max", "lt0", "gt1", "all_le0", "depth_median", "depth_ge200", "logdepth_mean")}
        res["ks_note"] = ("two-sample Kolmogorov-Smirnov distance of the per-sequence statistics; with n1, n2 sequences "
                          "a distance above 1.36 * sqrt((n1 + n2) / (n1 n2)) rejects equal distributions at 5%")
        n1, n2 = len(u["mean"]), len(o["mean"])
        res["ks_5pct_threshold"] = 1.36 * np.sqrt((n1 + n2) / (n1 * n2))
    text = json.dumps(res, indent=1)
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
