"""``cosemdepth predict``: run a model on a dataset split or on your own flight and write its outputs.

    cosemdepth predict --model MODEL --dataset NAME --root ROOT [--split-dir D] [--split test] --out DIR
    cosemdepth predict --model MODEL --flight --images DIR --poses FILE (--intrinsics FX FY CX CY | --hfov DEG) --out DIR
    cosemdepth predict --model MODEL --bag PATH --image-topic T --pose-topic T (--camera-info-topic T | ...) --out DIR

Outputs (depth as float32 .npy and 16-bit PNG = round(depth_m * 256), labels, colourised labels, side-by-side
pictures, a video): see :mod:`cosemdepth.evaluation.predict`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..data import open_dataset
from ..data.flight import DEFAULT_CONVENTION
from ..data.poses import CONVENTIONS
from ..errors import ConfigError
from ..evaluation.predict import predict
from ..evaluation.visualize import DEFAULT_FPS, DEFAULT_VIDEO, VIDEO_FORMATS
from ..io.outdir import Input, model_inputs
from ..io.rerun_writer import check_rrd_path
from ..io.staging import StagedDir
from ..data.bag_flight import DEFAULT_BAG_CONVENTION
from ._robotics import add_robotics_args, bag_report, check_args, make_sinks, open_bag
from ._shared import (add_model_args, apply_threads, add_run_args, add_split_args, check_run_size, check_split_dir,
                      input_size, load, parse_size, size_help)


def configure(parser: argparse.ArgumentParser) -> None:
    add_model_args(parser)
    add_split_args(parser, required=False)
    flight = parser.add_argument_group("your own flight (instead of --dataset)")
    flight.add_argument("--flight", action="store_true", help="run on a folder of images with a pose file")
    flight.add_argument("--images", type=Path, metavar="DIR", help="folder of the flight's images")
    flight.add_argument("--poses", type=Path, metavar="FILE",
                        help="absolute camera poses: TUM (timestamp tx ty tz qx qy qz qw) or CSV with a header "
                        "(see docs/data.md)")
    flight.add_argument("--intrinsics", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"),
                        help="pinhole intrinsics in pixels of the original images")
    flight.add_argument("--hfov", type=float, metavar="DEG", help="horizontal field of view in degrees (instead of "
                        "--intrinsics; square pixels, centred principal point)")
    flight.add_argument("--convention", default=None, choices=tuple(CONVENTIONS),
                        help="axes of the posed frame (default opencv: x right, y down, z forward; flu for --bag)")
    flight.add_argument("--frame-skip", type=int, default=1, metavar="K", help="keep every K-th image (default 1)")
    parser.add_argument("--size", type=parse_size, default=None, metavar="S",
                        help=size_help()[:-1] + "; the image size for flights)")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (new, empty, or the "
                        "output of a previous predict, which is replaced; never an input, a folder holding one or a "
                        "folder inside one)")
    parser.add_argument("--video", default=DEFAULT_VIDEO, choices=(*VIDEO_FORMATS, "none"),
                        help=f"video of each trajectory (default {DEFAULT_VIDEO}; GIF when no ffmpeg), or none")
    parser.add_argument("--fps", type=float, default=DEFAULT_FPS, help=f"video frame rate (default {DEFAULT_FPS:g})")
    parser.add_argument("--overwrite", action="store_true", help="also replace the output of another cosemdepth "
                        "command (a folder cosemdepth did not write is never replaced)")
    add_run_args(parser)
    add_robotics_args(parser)


def _validate(args: argparse.Namespace) -> None:
    """The argument checks that need no file."""
    if args.workers < 0:
        raise ConfigError(f"--workers must be >= 0, got {args.workers}")
    check_args(args)
    if args.bag is not None:
        return
    if args.flight:
        if args.dataset or args.root:
            raise ConfigError("give either --flight (with --images, --poses) or --dataset/--root, not both")
        if args.images is None:
            raise ConfigError("--flight needs --images DIR")
        if args.poses is None:
            raise ConfigError("--flight needs --poses FILE")
        if (args.intrinsics is None) == (args.hfov is None):
            raise ConfigError("--flight needs exactly one of --intrinsics FX FY CX CY and --hfov DEG")
        if args.hfov is not None and not 0 < args.hfov < 180:
            raise ConfigError(f"--hfov must be in (0, 180) degrees, got {args.hfov}")
    elif not args.dataset or args.root is None:
        raise ConfigError("give --dataset NAME --root ROOT (a dataset split), or --flight --images DIR --poses FILE")


def _open(args: argparse.Namespace):
    if args.bag is not None:
        return open_bag(args)
    if args.flight:
        return open_dataset("flight", args.images, poses=args.poses, intrinsics=args.intrinsics, fov=args.hfov,
                            convention=args.convention or DEFAULT_CONVENTION, frame_skip=args.frame_skip, seq_len=1,
                            size=args.size, jpeg_idct=args.jpeg_idct)
    check_split_dir(args)
    return open_dataset(args.dataset, args.root, split_dir=args.split_dir, split=args.split, seq_len=1,
                        size=args.size, jpeg_idct=args.jpeg_idct)


def command_inputs(args: argparse.Namespace) -> list:
    """The input paths of predict / view (for the output policy of :mod:`cosemdepth.io.outdir`)."""
    return [*model_inputs(args.model), *(Input(label, p) for label, p in (
        ("--root", args.root), ("--split-dir", args.split_dir), ("--images", args.images), ("--poses", args.poses),
        ("--bag", args.bag)) if p is not None)]


def run_settings(args: argparse.Namespace, dataset) -> dict:
    """What determines predict's outputs besides the frames: ``predictions.json``'s ``run`` entry. ``input_size``
    ``[H, W]`` and ``intrinsics`` ``[fx, fy, cx, cy]`` (package convention: pixel centres at +0.5) are those the model
    was fed; the pose settings are null for dataset splits (whose readers fix them)."""
    own = bool(args.flight or args.bag)
    convention = args.convention or (DEFAULT_BAG_CONVENTION if args.bag else DEFAULT_CONVENTION)
    size = input_size(dataset)
    return {
        "model": str(args.model),
        "path": "reference" if args.reference else "fast",
        "precision": args.precision,
        "input_size": None if size is None else list(size),
        "intrinsics": [float(v) for v in dataset.intrinsics.tolist()],
        "intrinsics_given": None if args.intrinsics is None else [float(v) for v in args.intrinsics],
        "hfov_deg": args.hfov,
        "camera_info_topic": args.camera_info_topic,
        "convention": convention if own else None,
        "frame_skip": args.frame_skip if own else None,
        "poses": str(args.poses) if args.flight and args.poses is not None else None,
        "pose_topic": args.pose_topic if args.bag else None,
        "jpeg_idct": args.jpeg_idct,
    }


def run(args: argparse.Namespace) -> int:
    apply_threads(args)
    _validate(args)
    inputs = command_inputs(args)
    StagedDir(args.out, "predict", overwrite=args.overwrite, what="--out folder", inputs=inputs).check()  # first
    check_rrd_path(args.rerun, inputs=[*inputs, Input("--out", args.out)]) if args.rerun is not None else None
    dataset = _open(args)
    model, device = load(args.model, args.device, fast=not args.reference, precision=args.precision)
    check_run_size(model, dataset, device, args.lanes)
    info = {
        "model": {"path": str(args.model)},
        "dataset": {"root": str(args.bag if args.bag else args.images if args.flight else args.root),
                    "split": None if args.flight else args.split},
        "device": str(device),
        "run": run_settings(args, dataset),
    }
    manifest = predict(model, dataset, args.out, video=args.video, fps=args.fps, max_frames=args.max_frames,
                       lanes=args.lanes, num_workers=args.workers, overwrite=args.overwrite,
                       progress=not args.no_progress and sys.stderr.isatty(),
                       dataset_name="flight" if args.flight or args.bag else args.dataset, info=info,
                       sinks=make_sinks(args, dataset, model), inputs=inputs)
    n = manifest["frames_written"]
    videos = [t["video"] for t in manifest["trajectories"] if "video" in t]
    print(f"wrote {n} frames of {len(manifest['trajectories'])} trajectories to {args.out}"
          + (f"; videos: {', '.join(str(args.out / v) for v in videos)}" if videos else "") + bag_report(dataset)
          + (f"; rerun recording: {args.rerun}" if args.rerun else ""))
    return 0
