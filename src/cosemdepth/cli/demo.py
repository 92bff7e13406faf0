"""``cosemdepth demo --out DIR``: the shipped Co-SemDepth on a held-out SynthAir flight, against two baselines.

Writes ``DIR/metrics.json``, ``DIR/report.md``, ``DIR/iou.png``, ``DIR/qualitative.png`` and ``DIR/flight.mp4`` and
prints where the report is. See :mod:`cosemdepth.demo`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..demo import (
    DEFAULT_CLIMATE,
    DEFAULT_FRAMES,
    DEFAULT_MODEL,
    DEFAULT_SEED,
    DEFAULT_SIZE,
    DEFAULT_SUPERSAMPLE,
    run_demo,
)
from ..errors import ConfigError
from ..inference.policy import BASELINE, EVERY_FRAME
from ..jobs.options import RunOptions
from ..render.visualize import DEFAULT_VIDEO, VIDEO_FORMATS
from ..synthair.writer import SUPERSAMPLES
from ._shared import (
    add_device_args,
    add_jpeg_idct_arg,
    add_policy_args,
    add_reference_arg,
    apply_threads,
    positive_int,
)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        required=True,
        type=Path,
        metavar="DIR",
        help="report folder (new, empty, or a previous demo report, which is replaced)",
    )
    parser.add_argument(
        "--model",
        default=None,
        metavar="DIR",
        help=f"model folder (default: the shipped weights, {DEFAULT_MODEL}/ in the repository)",
    )
    parser.add_argument(
        "--size",
        type=positive_int,
        default=None,
        metavar="S",
        help="side of the generated flight in pixels (default: the size at which its 90-degree "
        "camera has the model's focal length in pixels, from the model's operating point: its "
        f"training size for SynthAir-trained weights; {DEFAULT_SIZE} for a model without one; with "
        "--data-root, that rule applied to the dataset's camera)",
    )
    parser.add_argument(
        "--frames",
        type=positive_int,
        default=DEFAULT_FRAMES,
        metavar="F",
        help=f"frames in the held-out flight (default {DEFAULT_FRAMES})",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=DEFAULT_SEED,
        metavar="K",
        help=f"world seed of the held-out flight (default {DEFAULT_SEED})",
    )
    parser.add_argument("--climate", default=DEFAULT_CLIMATE, help=f"SynthAir climate (default {DEFAULT_CLIMATE})")
    parser.add_argument(
        "--supersample",
        type=int,
        default=DEFAULT_SUPERSAMPLE,
        choices=SUPERSAMPLES,
        help=f"colour rays per pixel of the generated flight (default {DEFAULT_SUPERSAMPLE}, as the "
        "shipped weights' training data)",
    )
    parser.add_argument(
        "--data-dir",
        type=Path,
        default=None,
        metavar="DIR",
        help="generate the flight here and keep it (a re-run with the same arguments reuses it); "
        "default: a temporary folder",
    )
    parser.add_argument(
        "--data-root",
        type=Path,
        default=None,
        metavar="ROOT",
        help="evaluate on this existing Mid-Air-format dataset (split CSVs in ROOT/splits) instead "
        "of generating a flight",
    )
    add_device_args(parser)
    parser.add_argument(
        "--video",
        default=DEFAULT_VIDEO,
        choices=(*VIDEO_FORMATS, "none"),
        help=f"flight video format (default {DEFAULT_VIDEO}; GIF when no ffmpeg)",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="also replace the output of another cosemdepth "
        "command (a folder cosemdepth did not write is never replaced)",
    )
    add_reference_arg(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_jpeg_idct_arg(parser)
    add_policy_args(parser, f"{BASELINE} (when the model records its training motion, else {EVERY_FRAME})")


def run(args: argparse.Namespace) -> int:
    apply_threads(args)
    if args.data_root is not None and args.data_dir is not None:
        raise ConfigError("give at most one of --data-root (use an existing dataset) and --data-dir (generate here)")
    policy, min_baseline = RunOptions(policy=args.policy, min_baseline=args.min_baseline).stream_policy(None)
    run_demo(
        args.out,
        model=args.model,
        size=args.size,
        frames=args.frames,
        seed=args.seed,
        climate=args.climate,
        supersample=args.supersample,
        data_root=args.data_root,
        data_dir=args.data_dir,
        device=args.device,
        video=None if args.video == "none" else args.video,
        overwrite=args.overwrite,
        fast=not args.reference,
        jpeg_idct=args.jpeg_idct,
        progress=not args.no_progress and sys.stderr.isatty(),
        policy=policy,
        min_baseline=min_baseline,
    )
    return 0
