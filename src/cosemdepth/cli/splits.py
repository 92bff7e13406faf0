"""``cosemdepth splits``: write the train/val/test split CSVs of a dataset.

    cosemdepth splits midair ROOT OUT_DIR      # Mid-Air: the paper's rule (design 10.4)
    cosemdepth splits synthair ROOT [OUT_DIR]  # SynthAir / any Mid-Air-format root: generic rule; default ROOT/splits
    cosemdepth splits topair ROOT OUT_DIR      # TopAir, from each environment's airsim_rec.txt

Mid-Air-format output: ``OUT_DIR/{train,val,test}_data/<env>/<climate>/traj_XXXX.csv`` in the authors' tab-separated
format, trajectories numbered in sorted order of their folders. OUT_DIR holds this output only: a previous
``splits`` output there is replaced as a whole (the CSVs of another rule do not stay), a folder holding anything
else is refused (:mod:`cosemdepth.output_safety.outdir`). Nothing is written into ROOT (except for SynthAir when OUT_DIR is
left out: ROOT/splits is where ``open_dataset("synthair", ROOT)`` looks).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..data.midair.splits import SPLITS
from ..data.registry import DATASETS, dataset_spec
from ..errors import ConfigError
from ..output_safety.outdir import Input
from ..output_safety.staging import StagedDir


def configure(parser: argparse.ArgumentParser) -> None:
    names = tuple(n for n, spec in DATASETS.items() if spec.split_generator is not None)
    parser.add_argument("dataset", choices=names, help="dataset format")
    parser.add_argument("root", type=Path, help="dataset root")
    parser.add_argument("out_dir", type=Path, nargs="?", help="output folder (default for synthair: ROOT/splits)")
    parser.add_argument(
        "--rule",
        choices=("auto", "midair", "generic", *SPLITS),
        default=None,
        help="split rule for Mid-Air-format roots: midair = the paper's (index %% 3 == 0 test, 8 fixed "
        "validation trajectories), generic = index %% 3 == 0 test with the last test trajectory of each climate "
        "(when it has two or more) as validation; train, val or test = every trajectory in that split (a world "
        "used only for training, or only for testing); default midair for midair, generic for synthair",
    )


def run(args: argparse.Namespace) -> int:
    spec = dataset_spec(args.dataset)
    out_dir = args.out_dir
    if out_dir is None:
        if not spec.splits_into_root:
            raise ConfigError(f"cosemdepth splits {args.dataset} needs OUT_DIR (nothing is written into the dataset)")
        out_dir = args.root / spec.split_dir
    # ROOT/<split_dir> is where the reader looks for a root's split CSVs
    carve = (spec.split_dir,) if spec.split_dir else ()
    # the whole folder is this run's output: a previous `splits` output there is replaced (nothing of another rule
    # is left over), anything else refused
    StagedDir(out_dir, "splits", overwrite=None, what="OUT_DIR", inputs=[Input("ROOT", args.root, carve)]).check()
    written = spec.split_generator(args.root, out_dir, rule=args.rule)
    args.out_dir = out_dir
    for split, paths in written.items():
        rows = sum(_count_rows(p) for p in paths)
        print(f"{split}: {len(paths)} trajectories, {rows} rows")
    print(f"wrote {sum(len(p) for p in written.values())} CSV files under {args.out_dir}")
    return 0


def _count_rows(path: Path) -> int:
    with open(path) as f:
        return max(sum(1 for _ in f) - 1, 0)
