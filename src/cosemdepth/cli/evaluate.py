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
import contextlib
import sys
from pathlib import Path

from ..data.registry import dataset_spec
from ..evaluation.evaluator import evaluate
from ..inference.policy import EVERY_FRAME
from ..output_safety.outdir import Input, model_inputs
from ..output_safety.staging import OutputFiles
from ._shared import (
    add_model_args,
    add_policy_args,
    add_run_args,
    add_split_args,
    apply_threads,
    check_run_size,
    input_size,
    load,
    model_operating_point,
    open_split,
    parse_size,
    size_help,
    stream_policy,
    warn_far_size,
)


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


def run(args: argparse.Namespace) -> int:
    apply_threads(args)
    policy, min_baseline = stream_policy(args, EVERY_FRAME)
    inputs = [
        *model_inputs(args.model),
        Input("--root", args.root),
        Input("--split-dir", args.split_dir) if args.split_dir is not None else None,
        Input("--calibration", args.calibration) if args.calibration is not None else None,
    ]
    files_ctx = (
        OutputFiles(args.out, "--out folder", command="evaluate", names=("metrics.json", "metrics.md"), inputs=inputs)
        if args.out
        else contextlib.nullcontext()
    )
    with files_ctx as files:
        op = model_operating_point(args.model)
        dataset = open_split(args, input_size(args.size, op), calibration=args.calibration)
        warn_far_size(op, args.size, dataset)
        model, device = load(args.model, args.device, fast=not args.reference, precision=args.precision)
        check_run_size(model, dataset, device, args.lanes)
        result = evaluate(
            model,
            dataset,
            lanes=args.lanes,
            max_frames=args.max_frames,
            num_workers=args.workers,
            progress=not args.no_progress and sys.stderr.isatty(),
            dataset_name=args.dataset,
            policy=policy,
            min_baseline=min_baseline,
        )
        result.info["model"].update(path=str(args.model), name=Path(str(args.model)).name)
        result.info["dataset"].update(
            root=str(args.root),
            split=args.split or dataset_spec(args.dataset).split,
            split_dir=None if args.split_dir is None else str(args.split_dir),
        )
        if getattr(dataset, "calibration", None):
            result.info["dataset"]["undistortion"] = dataset.calibration
        text = result.to_markdown()
        print(text)
        no_depth = result.depth_warning()
        if no_depth:
            print(f"cosemdepth evaluate: warning: {no_depth}", file=sys.stderr)
        if files is not None:
            files.add_text("metrics.json", result.to_json())
            files.add_text("metrics.md", text)
    if args.out:
        print(f"wrote {Path(args.out) / 'metrics.json'} and {Path(args.out) / 'metrics.md'}")
    return 0
