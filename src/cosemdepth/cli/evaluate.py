"""``cosemdepth evaluate``: the test protocol of the original (design 11.3) on a dataset split.

    cosemdepth evaluate --model MODEL --dataset NAME --root ROOT [--split-dir D] [--split test] [--size S]
                        [--out DIR] [--device cpu] [--max-frames N] [--trajectories-per-batch B]

Without ``--size`` the split is read at the size where its camera has the model's focal length in pixels (the
operating point in the model's config.json: 384x384 for the official Mid-Air checkpoints, 128x128 for the shipped
SynthAir weights); a ``--size`` far from it gets a warning on stderr.

Prints the results table; with ``--out DIR`` also writes ``DIR/metrics.json`` and ``DIR/metrics.md`` (both renamed
into place together at the end; nothing is written if the run fails).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..inference.policy import EVERY_FRAME
from ..jobs.evaluate import EvaluateOptions, run_evaluate
from ._options import model_options, run_options, split_options
from ._shared import add_model_args, add_policy_args, add_run_args, add_split_args, parse_size, size_help


def configure(parser: argparse.ArgumentParser) -> None:
    add_model_args(parser)
    add_split_args(parser)
    parser.add_argument("--size", type=parse_size, default=None, metavar="S", help=size_help())
    parser.add_argument(
        "--calibration",
        type=Path,
        default=None,
        metavar="FILE",
        help="the lens of a Mid-Air-format split's images (e.g. a SynthAir set rendered with --distortion: "
        "ROOT/calibration/camera_info.yaml): frames and ground truth undistorted to a pinhole (docs/data.md)",
    )
    parser.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="write metrics.json and metrics.md into DIR (created if needed; other files in DIR are "
        "left alone, and files cosemdepth did not write are never replaced)",
    )
    add_policy_args(parser, f"{EVERY_FRAME} (the paper's protocol)")
    add_run_args(parser)


def options(args: argparse.Namespace) -> EvaluateOptions:
    """The :class:`~cosemdepth.jobs.evaluate.EvaluateOptions` of the parsed arguments."""
    run = run_options(args)
    return EvaluateOptions(source=split_options(args), model=model_options(args), run=run, out=args.out)


def run(args: argparse.Namespace) -> int:
    result = run_evaluate(options(args))
    for line in result.lines:
        print(line)
    for line in result.warnings:
        print(line, file=sys.stderr)
    return 0
