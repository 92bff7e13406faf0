"""The operating point of the shipped demo weights, recomputed from their recipe without rendering an image.

    python scripts/demo_motion_stats.py [--write weights/synthair-cosemdepth]

The recipe (``scripts/make_demo_weights.sh``) trains on six SynthAir worlds (seeds 11-16; 3 trajectories per
climate, sunny and cloudy, 400 frames at 128x128, every trajectory in the train split: ``cosemdepth splits --rule
train``) with ``src/cosemdepth/configs/synthair-demo.yaml`` (size, seq_len, db_seq_len). SynthAir is deterministic
from its seed, so the training windows' motion follows from the flight planner alone: for each world this script
plans the flights as ``cosemdepth synth`` does (:func:`cosemdepth.synthair.writer.plan_flights`), turns their
100 Hz ground truth into split-CSV rows with the split generator's code (:func:`cosemdepth.data.midair.splits.
trajectory_rows`, written with :func:`~cosemdepth.data.midair.splits.write_csv` into a temporary folder), opens those
CSVs as the trainer does (train windows of the config) and takes the statistics of
:meth:`~cosemdepth.data.sequence.SequenceDataset.step_translations`, as ``cosemdepth train`` records them.

Prints the operating point as JSON; ``--write DIR`` puts it into ``DIR/config.json`` as ``"operating_point"``
(atomically; ``model.safetensors`` and its checksum are left as they are).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from cosemdepth.checkpoints.model_io import CONFIG_FILE, OPERATING_POINT, read_config_file
from cosemdepth.data import open_dataset
from cosemdepth.data.frames import midair_intrinsics
from cosemdepth.data.midair.splits import Trajectory, trajectory_rows, write_csv
from cosemdepth.operating_point import MotionStats, OperatingPoint
from cosemdepth.output_safety.atomic import atomic_write_text
from cosemdepth.synthair.world import get_world
from cosemdepth.synthair.writer import ENVIRONMENT, SynthConfig, plan_flights
from cosemdepth.training.config import resolve_config

#: The training worlds of scripts/make_demo_weights.sh and their `cosemdepth synth` arguments.
SEEDS = (11, 12, 13, 14, 15, 16)
TRAJECTORIES = 3
FRAMES = 400
CLIMATES = ("sunny", "cloudy")
CONFIG = "synthair-demo"


def world_trajectories(
    seed: int,
    split_root: Path,
    *,
    trajectories: int = TRAJECTORIES,
    frames: int = FRAMES,
    climates: tuple[str, ...] = CLIMATES,
) -> None:
    """Write the split CSVs that ``cosemdepth synth --seed SEED --trajectories T --frames F --climates ...`` followed
    by ``cosemdepth splits synthair ... --rule train`` would write, under ``split_root/train_data``, without
    rendering an image (the flights do not depend on the image size)."""
    cfg = SynthConfig(out=split_root, trajectories=trajectories, frames=frames, seed=seed, climates=climates)
    flights = plan_flights(cfg, get_world(seed))
    for climate, planned in flights.items():
        # the split generator numbers a climate's trajectories in the sorted order of their folders
        for index, number in enumerate(sorted(planned)):
            traj = Trajectory(ENVIRONMENT, climate, number, index)
            f = planned[number].flight
            rows = trajectory_rows(traj, np.asarray(f.attitude, np.float64), np.asarray(f.position, np.float64))
            write_csv(split_root / "train_data" / ENVIRONMENT / climate / f"traj_{index:04d}.csv", rows)


def demo_operating_point(log=print) -> OperatingPoint:
    run = resolve_config(CONFIG, [], {})
    size = tuple(run.data.size)
    norms = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in SEEDS:
            log(f"world {seed}: planning {TRAJECTORIES} x {len(CLIMATES)} flights ...")
            split_dir = Path(tmp) / f"s{seed}"
            world_trajectories(seed, split_dir)
            ds = open_dataset(
                "synthair",
                tmp,
                split_dir=split_dir,
                split="train",
                seq_len=run.data.seq_len,
                size=size,
                mode="train",
                db_seq_len=run.data.db_seq_len,
            )
            norms.append(ds.step_translations())
    fx, fy = (float(v) for v in midair_intrinsics(size)[:2])
    motion = MotionStats.from_samples(np.concatenate(norms))
    return OperatingPoint(
        size,
        (fx, fy),
        motion,
        f"cosemdepth train: SynthAir worlds {SEEDS[0]}-{SEEDS[-1]} at {size[0]}x{size[1]} "
        f"(scripts/make_demo_weights.sh), {motion.count} window steps; recomputed by "
        "scripts/demo_motion_stats.py",
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--write", type=Path, metavar="DIR", help="record it in DIR/config.json (the shipped weights)")
    args = p.parse_args(argv)
    op = demo_operating_point(log=lambda m: print(m, file=sys.stderr))
    print(json.dumps(op.to_dict(), indent=2))
    if args.write is not None:
        read_config_file(args.write)  # a model folder of ours
        path = args.write / CONFIG_FILE
        meta = json.loads(path.read_text(encoding="utf-8"))
        meta[OPERATING_POINT] = op.to_dict()
        if "weights_sha256" in meta:  # keep the checksum last, where save_weights writes it
            meta["weights_sha256"] = meta.pop("weights_sha256")
        atomic_write_text(path, json.dumps(meta, indent=2) + "\n")
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
