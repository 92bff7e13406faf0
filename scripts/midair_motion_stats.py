"""The per-step translation statistics of Mid-Air's training windows, from the authors' published split CSVs.

    python scripts/midair_motion_stats.py AUTHORS_DIR [--split train] [--seq-len 4] [--db-seq-len 4]

``AUTHORS_DIR`` is a checkout of the authors' repository (Malga-Vision/Co-SemDepth); its split CSVs
(``data/midair/<split>_data/**/*.csv``) carry the relative camera motion of every row (``tx ty tz``, metres). The
CSVs are read with our Mid-Air reader, in the paper's training windows (chunks of ``db_seq_len`` rows, windows of
``seq_len``; design 9.2), and the statistics are those of the translations the model is given inside a window (the
rows after each window's first: :meth:`cosemdepth.data.sequence.SequenceDataset.step_translations`), exactly as
``cosemdepth train`` computes them for its own data. No image is read (the Mid-Air images need not be present).

Prints the statistics as JSON (the ``step_translation_m`` block of a model folder's ``operating_point``) and a few
figures of the raw CSV rows to compare with design 2.2; ``src/cosemdepth/io/convert.py`` holds the result as
``MIDAIR_STEP_TRANSLATION``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from cosemdepth.data import open_dataset
from cosemdepth.operating_point import MotionStats


def midair_motion(split_dir: Path, split: str = "train", seq_len: int = 4, db_seq_len: int = 4):
    """``(MotionStats of the windows, every row's translation [N, 3])`` of the Mid-Air split CSVs in ``split_dir``
    (the folder holding ``<split>_data/``)."""
    with tempfile.TemporaryDirectory() as root:  # the CSVs' image paths are not opened: any folder is a root
        ds = open_dataset(
            "midair",
            root,
            split_dir=split_dir,
            split=split,
            seq_len=seq_len,
            size=384,
            mode="train",
            db_seq_len=db_seq_len,
        )
        rows = np.concatenate([t.trans for t in ds.trajectories]).astype(np.float64)
        return MotionStats.from_samples(ds.step_translations()), rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("authors_dir", type=Path, help="checkout of Malga-Vision/Co-SemDepth")
    p.add_argument("--split", default="train")
    p.add_argument("--seq-len", type=int, default=4)
    p.add_argument("--db-seq-len", type=int, default=4)
    args = p.parse_args(argv)
    split_dir = args.authors_dir / "data" / "midair"
    stats, rows = midair_motion(split_dir, args.split, args.seq_len, args.db_seq_len)
    norms = np.linalg.norm(rows, axis=1)
    print(json.dumps(stats.to_dict(), indent=2))
    print(
        f"all {len(rows)} rows of the {args.split} CSVs: t_z median {np.median(rows[:, 2]):+.3f} m, "
        f"||t|| from {norms.min():.3f} to {norms.max():.3f} m",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
