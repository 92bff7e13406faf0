"""Speed of reading Mid-Air-format frames (1024x1024 JPEG + float16 disparity PNG + label PNG -> 384x384 tensors).

    PYTHONPATH=src python benchmarks/data_loading.py [--frames 8] [--native 1024] [--size 384] [--out result.json]

Writes a small Mid-Air-format dataset into a temporary folder, then times ``open_dataset("midair", ...)[i]`` per
frame (best of ``--repeat`` passes), with and without the training augmentation, and the decoding steps alone.
Prints a JSON object (seconds per frame) and writes it to ``--out`` if given.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np
import torch
from PIL import Image

from cosemdepth.bench.report import print_json
from cosemdepth.data import open_dataset
from cosemdepth.data.decode import read_rgb
from cosemdepth.data.midair.dataset import read_depth, read_labels
from cosemdepth.data.midair.splits import generate_splits


def write_dataset(root: Path, frames: int, native: int) -> None:
    base = root / "Bench" / "sunny"
    traj = "trajectory_0000"
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:native, 0:native].astype(np.float32)
    for sensor in ("color_left", "stereo_disparity", "segmentation"):
        (base / sensor / traj).mkdir(parents=True, exist_ok=True)
    for i in range(frames):
        rgb = np.stack([128 + 100 * np.sin(xx / 37 + i), 128 + 100 * np.cos(yy / 23), 128 + 60 * np.sin((xx + yy) / 50)],
                       axis=-1).astype(np.uint8)
        Image.fromarray(rgb).save(base / "color_left" / traj / f"{i:06d}.JPEG", quality=95)
        disp = (1.0 + 40 * (yy / native) + rng.uniform(0, 0.1, yy.shape)).astype(np.float16)
        Image.fromarray(disp.view(np.uint16)).save(base / "stereo_disparity" / traj / f"{i:06d}.PNG")
        ids = ((xx // 64 + yy // 64) % 14).astype(np.uint8)
        Image.fromarray(ids).save(base / "segmentation" / traj / f"{i:06d}.PNG")
    n_gt = 4 * frames
    att = np.tile([1.0, 0.0, 0.0, 0.0], (n_gt, 1))
    pos = np.stack([np.arange(n_gt) * 0.1, np.zeros(n_gt), np.full(n_gt, -20.0)], axis=-1)
    with h5py.File(base / "sensor_records.hdf5", "w") as h5:
        h5.create_dataset(f"{traj}/groundtruth/attitude", data=att)
        h5.create_dataset(f"{traj}/groundtruth/position", data=pos)


def per_frame(fn, n: int, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        for i in range(n):
            fn(i)
        best = min(best, (time.perf_counter() - t) / n)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=8, help="camera frames written (rows = frames/4 - 1, at least 1)")
    ap.add_argument("--native", type=int, default=1024)
    ap.add_argument("--size", type=int, default=384)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "root"
        write_dataset(root, max(a.frames, 8), a.native)
        generate_splits(root, Path(tmp) / "splits", rule=lambda t: "test")
        ds = open_dataset("midair", root, split_dir=Path(tmp) / "splits", split="test", size=a.size)
        aug = open_dataset("midair", root, split_dir=Path(tmp) / "splits", split="test", size=a.size, augment=True)
        rec = ds.trajectories[0].frames
        n = len(ds)
        result = {
            "what": f"seconds per frame, Mid-Air format {a.native}px -> {a.size}px, one process, 1 torch thread",
            "frames": n,
            "item": per_frame(lambda i: ds[i], n, a.repeat),
            "item_augmented": per_frame(lambda i: aug[i], n, a.repeat),
            "decode_jpeg": per_frame(lambda i: read_rgb(rec[i].rgb), n, a.repeat),
            "decode_disparity_to_depth": per_frame(lambda i: read_depth(rec[i].depth), n, a.repeat),
            "decode_labels": per_frame(lambda i: read_labels(rec[i].semantic), n, a.repeat),
            "machine": platform.processor() or platform.machine(),
            "torch": torch.__version__,
        }
    print_json(result, a.out)


if __name__ == "__main__":
    main()
