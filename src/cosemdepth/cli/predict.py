"""``cosemdepth predict``: run a model on a dataset split or on your own flight and write its outputs.

    cosemdepth predict --model MODEL --dataset NAME --root ROOT [--split-dir D] [--split test] --out DIR
    cosemdepth predict --model MODEL --flight --images DIR --poses FILE (--intrinsics FX FY CX CY | --hfov DEG) --out DIR
    cosemdepth predict --model MODEL --flight --images VIDEO --log FILE [--time-offset S|auto] [--camera-mount SPEC]
        (--intrinsics FX FY CX CY | --hfov DEG) --out DIR
    cosemdepth predict --model MODEL --bag PATH --image-topic T --pose-topic T (--camera-info-topic T | ...) --out DIR

Outputs (depth as float32 .npy and 16-bit PNG = round(depth_m * 256), labels, colourised labels, side-by-side
pictures, a video): see :mod:`cosemdepth.streaming.sinks.files`; the output bag and the rerun recording:
:mod:`cosemdepth.streaming.sinks.bag`, :mod:`cosemdepth.streaming.sinks.rerun`. The arguments become a
:class:`~cosemdepth.jobs.predict.PredictOptions`, run by :func:`cosemdepth.jobs.predict.run_predict`.

Without ``--size`` the input is read at the size where its camera (the dataset's, ``--intrinsics`` / ``--hfov`` at
the images' size, or the bag's camera_info) has the model's focal length in pixels, keeping its aspect ratio (the
operating point in the model's config.json); a model without one runs at the dataset table's size, or a flight's
image size. A ``--size`` far from the model's focal length gets a warning on stderr.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..data.pose_matching import DEFAULT_MAX_GAP, MATCHES
from ..data.poses import CONVENTIONS
from ..data.stamps import UNITS
from ..flightlogs import LOG_FORMATS
from ..inference.policy import BASELINE, EVERY_FRAME
from ..jobs.predict import PredictOptions, run_predict
from ..render.visualize import DEFAULT_FPS, DEFAULT_VIDEO, VIDEO_FORMATS
from ..robotics.bag_flight import DEFAULT_MAX_POSE_GAP
from ..streaming.sinks.bag import DEFAULT_NAMESPACE
from ..streaming.sinks.files import DEFAULT_INVALID, INVALID_MODES, FileOptions
from ._options import model_options, run_options, source_options
from ._shared import (
    add_model_args,
    add_policy_args,
    add_run_args,
    add_split_args,
    parse_size,
    positive_int,
    size_help,
)


def configure(parser: argparse.ArgumentParser) -> None:
    add_model_args(parser)
    parser.add_argument(
        "--backend",
        choices=["pytorch", "onnxruntime"],
        default="pytorch",
        help="pytorch (default; the fast path, or --reference) or onnxruntime: the graph --onnx "
        "(written by 'cosemdepth export --onnx' from --model at the input size) run by ONNX Runtime's "
        "CPU provider with the state fed back (fp32; --threads intra-op threads)",
    )
    parser.add_argument("--onnx", type=Path, metavar="FILE", help="the exported graph of --backend onnxruntime")
    add_split_args(parser, required=False)
    flight = parser.add_argument_group("your own flight (instead of --dataset)")
    flight.add_argument(
        "--flight", action="store_true", help="run on a folder of images with a pose file, or a video with a log"
    )
    flight.add_argument(
        "--images",
        type=Path,
        metavar="DIR|VIDEO",
        help="folder of the flight's images, or a video file (.mp4, .mov, .mkv...; with --log)",
    )
    flight.add_argument(
        "--poses",
        type=Path,
        metavar="FILE",
        help="absolute camera poses: TUM (timestamp tx ty tz qx qy qz qw) or CSV with a header (see docs/data.md)",
    )
    flight.add_argument(
        "--intrinsics",
        type=float,
        nargs=4,
        metavar=("FX", "FY", "CX", "CY"),
        help="pinhole intrinsics in pixels of the original images",
    )
    flight.add_argument(
        "--calibration",
        type=Path,
        metavar="FILE",
        help="the camera's calibration (ROS camera_info YAML, OpenCV FileStorage YAML, Kalibr camchain, COLMAP "
        "cameras.txt; instead of --intrinsics / --hfov / --camera-info-topic): images undistorted to a pinhole at "
        "the model's focal length (docs/data.md)",
    )
    flight.add_argument(
        "--hfov",
        type=float,
        metavar="DEG",
        help="horizontal field of view in degrees (instead of --intrinsics; square pixels, centred principal point)",
    )
    flight.add_argument(
        "--convention",
        default=None,
        choices=tuple(CONVENTIONS),
        help="axes of the posed frame (default opencv: x right, y down, z forward; flu for --bag)",
    )
    flight.add_argument(
        "--frame-skip", type=positive_int, default=1, metavar="K", help="keep every K-th image (default 1)"
    )
    flight.add_argument(
        "--match",
        choices=MATCHES,
        default="auto",
        help="which pose goes with which image (default auto): stamp (image names are stamps), "
        "order (the n-th pose row for the n-th image), index (image names are frame numbers "
        "indexing the pose rows from 0), auto (stamp if every name is a stamp within the poses' "
        "time range, else order if there is one pose per image; docs/data.md)",
    )
    flight.add_argument(
        "--stamp-unit",
        default="auto",
        metavar="U",
        help=f"unit of the stamps: {', '.join(UNITS)} for image names and pose stamps, or "
        "IMAGES,POSES (e.g. ns,s); default auto: the unit in which they are dates since 1970, else s",
    )
    flight.add_argument(
        "--max-pose-gap",
        type=float,
        default=None,
        metavar="S",
        help="interpolate an image's pose only between poses at most S seconds apart (default: "
        f"{DEFAULT_MAX_GAP:g} for --flight, {DEFAULT_MAX_POSE_GAP:g} for --bag)",
    )
    flight.add_argument(
        "--skip-unposed",
        action="store_true",
        help="leave out images without a pose (counted in the summary) instead of failing",
    )
    video = parser.add_argument_group("a video with the flight controller's log (--flight --images VIDEO)")
    video.add_argument(
        "--log",
        type=Path,
        metavar="FILE",
        help="the flight log giving the video's poses: PX4 .ulg, ArduPilot .bin, MAVLink .tlog or DJI .SRT "
        "(the format from the content; docs/own-flight.md)",
    )
    video.add_argument("--log-format", choices=LOG_FORMATS, default=None, help="insist on this log format")
    video.add_argument(
        "--time-offset",
        default=None,
        metavar="S|auto",
        help="the log time (seconds) of the video's first frame, or auto (default): estimated from the camera's "
        "rotation (a DJI .SRT is on the video's own clock)",
    )
    video.add_argument(
        "--camera-mount",
        default=None,
        metavar="SPEC",
        help="the camera on the vehicle: forward (default), down, R,P,Y (degrees of the camera's FRD frame "
        "relative to the body's, e.g. 0,-30,0 pitched down 30), or a Kalibr camchain / T_body_cam YAML",
    )
    video.add_argument(
        "--lever-arm",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="the camera's position on the vehicle, metres in body FRD (x forward, y right, z down)",
    )
    parser.add_argument(
        "--size",
        type=parse_size,
        default=None,
        metavar="S",
        help=size_help()[:-1] + "; the image size for flights and bags)",
    )
    parser.add_argument(
        "--out",
        required=True,
        type=Path,
        metavar="DIR",
        help="output folder (new, empty, or the "
        "output of a previous predict, which is replaced; never an input, a folder holding one or a "
        "folder inside one)",
    )
    parser.add_argument(
        "--video",
        default=DEFAULT_VIDEO,
        choices=(*VIDEO_FORMATS, "none"),
        help=f"video of each trajectory (default {DEFAULT_VIDEO}; GIF when no ffmpeg), or none",
    )
    parser.add_argument("--fps", type=float, default=DEFAULT_FPS, help=f"video frame rate (default {DEFAULT_FPS:g})")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="also replace the output of another cosemdepth "
        "command (a folder cosemdepth did not write is never replaced)",
    )
    parser.add_argument(
        "--invalid",
        choices=INVALID_MODES,
        default=DEFAULT_INVALID,
        help="what the depth .npy holds where depth_valid is 0: keep (the model's values; default) or "
        "nan (the PNG holds 0 there and the bag NaN either way)",
    )
    add_policy_args(
        parser,
        f"{BASELINE} for --flight and --bag (when the model records its training motion, else "
        f"{EVERY_FRAME}), {EVERY_FRAME} for --dataset",
    )
    add_run_args(parser)
    add_robotics_args(parser)


def add_robotics_args(parser: argparse.ArgumentParser) -> None:
    """Add the ROS bag input, bag output and rerun options to a command's ``parser``."""
    bag = parser.add_argument_group("a ROS bag as the flight (instead of --dataset or --flight; docs/robotics.md)")
    bag.add_argument("--bag", type=Path, metavar="PATH", help="ROS 2 bag folder (sqlite3 or MCAP) or ROS 1 .bag")
    bag.add_argument("--image-topic", metavar="T", help="sensor_msgs/Image or CompressedImage topic")
    bag.add_argument(
        "--pose-topic",
        metavar="T",
        help="geometry_msgs/PoseStamped, PoseWithCovarianceStamped or nav_msgs/Odometry topic: absolute "
        "poses of the body (axes: --convention, default flu = REP 103) or of the camera",
    )
    bag.add_argument(
        "--camera-info-topic",
        metavar="T",
        help="sensor_msgs/CameraInfo topic for the intrinsics (instead of --intrinsics / --hfov)",
    )
    bag.add_argument(
        "--ignore-distortion",
        action="store_true",
        help="use camera_info's K as if the images were undistorted (default: a distorting lens is undistorted on "
        "the fly)",
    )
    bag.add_argument(
        "--out-namespace",
        default=DEFAULT_NAMESPACE,
        metavar="NS",
        help=f"topic prefix of the output bag DIR/bag/ (default {DEFAULT_NAMESPACE})",
    )
    parser.add_argument(
        "--rerun",
        type=Path,
        default=None,
        metavar="FILE.rrd",
        help="also write a rerun recording (open it with: rerun FILE.rrd; needs cosemdepth[viz])",
    )


def options(args: argparse.Namespace) -> PredictOptions:
    """The :class:`~cosemdepth.jobs.predict.PredictOptions` of the parsed arguments."""
    run = run_options(args)
    model = model_options(args)
    return PredictOptions(
        source=source_options(args),
        model=model,
        out=args.out,
        run=run,
        files=FileOptions(video=args.video, fps=args.fps, invalid=args.invalid),
        overwrite=args.overwrite,
        out_namespace=args.out_namespace,
        rerun=args.rerun,
    )


def run(args: argparse.Namespace) -> int:
    result = run_predict(options(args))
    for line in result.lines:
        print(line)
    for line in result.warnings:
        print(line, file=sys.stderr)
    return 0
