"""``cosemdepth predict``: run a model on a dataset split or on your own flight and write its outputs.

    cosemdepth predict --model MODEL --dataset NAME --root ROOT [--split-dir D] [--split test] --out DIR
    cosemdepth predict --model MODEL --flight --images DIR --poses FILE (--intrinsics FX FY CX CY | --hfov DEG) --out DIR

Outputs (depth as float32 .npy and 16-bit PNG = round(depth_m * 256), labels, colourised labels, side-by-side
pictures, a video): see :mod:`cosemdepth.evaluation.predict`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import ConfigError
from ._shared import add_model_args, apply_threads, add_run_args, add_split_args, load, parse_size


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
    flight.add_argument("--convention", default="opencv", choices=("opencv", "ned", "flu", "opengl"),
                        help="axes of the posed frame (default opencv: x right, y down, z forward)")
    flight.add_argument("--frame-skip", type=int, default=1, metavar="K", help="keep every K-th image (default 1)")
    parser.add_argument("--size", type=parse_size, default=None, metavar="S",
                        help="network input size, S or HxW (default 384 for datasets; the image size for flights)")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (new, empty, or the "
                        "output of a previous predict, which is replaced)")
    parser.add_argument("--video", default="mp4", choices=("mp4", "gif", "none"),
                        help="video of each trajectory: mp4 (default; GIF when no ffmpeg), gif or none")
    parser.add_argument("--fps", type=float, default=8.0, help="video frame rate (default 8)")
    parser.add_argument("--overwrite", action="store_true", help="replace a non-empty --out folder")
    add_run_args(parser)


def _open(args: argparse.Namespace):
    from ..data import open_dataset

    if args.workers < 0:
        raise ConfigError(f"--workers must be >= 0, got {args.workers}")
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
        return open_dataset("flight", args.images, poses=args.poses, intrinsics=args.intrinsics, fov=args.hfov,
                            convention=args.convention, frame_skip=args.frame_skip, seq_len=1, size=args.size,
                            jpeg_idct=args.jpeg_idct)
    if not args.dataset or args.root is None:
        raise ConfigError("give --dataset NAME --root ROOT (a dataset split), or --flight --images DIR --poses FILE")
    return open_dataset(args.dataset, args.root, split_dir=args.split_dir, split=args.split, seq_len=1,
                        size=args.size, jpeg_idct=args.jpeg_idct)


def run(args: argparse.Namespace) -> int:
    apply_threads(args)
    from ..evaluation.predict import predict
    from ..io.staging import StagedDir
    from ..evaluation.predict import MANIFEST

    StagedDir(args.out, MANIFEST, overwrite=args.overwrite, what="--out folder").check()  # fail before loading
    dataset = _open(args)
    model, device = load(args.model, args.device, fast=not args.reference)
    info = {
        "model": {"path": str(args.model)},
        "dataset": {"root": str(args.images if args.flight else args.root),
                    "split": None if args.flight else args.split},
        "device": str(device),
    }
    manifest = predict(model, dataset, args.out, video=args.video, fps=args.fps, max_frames=args.max_frames,
                       lanes=args.lanes, num_workers=args.workers, overwrite=args.overwrite,
                       progress=not args.no_progress and sys.stderr.isatty(),
                       dataset_name="flight" if args.flight else args.dataset, info=info)
    n = manifest["frames_written"]
    videos = [t["video"] for t in manifest["trajectories"] if "video" in t]
    print(f"wrote {n} frames of {len(manifest['trajectories'])} trajectories to {args.out}"
          + (f"; videos: {', '.join(str(args.out / v) for v in videos)}" if videos else ""))
    return 0
