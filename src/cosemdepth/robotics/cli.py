"""The robotics inputs and outputs of ``cosemdepth predict`` (and ``view``): ``--bag`` (a ROS bag as the flight),
its output bag, and ``--rerun FILE.rrd``. See ``docs/robotics.md``."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import ConfigError
from ..evaluation.evaluator import _model_config
from ..measures.classes import class_info
from ..tasks import class_count
from .bag_flight import DEFAULT_BAG_CONVENTION, DEFAULT_MAX_POSE_GAP, open_bag_flight
from .bag_writer import DEFAULT_NAMESPACE, BagWriter, check_namespace
from .rerun_writer import RerunWriter, require_rerun


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


def check_args(args: argparse.Namespace) -> None:
    """Argument checks that need no file (called before anything is read)."""
    if getattr(args, "bag", None) is not None:
        if getattr(args, "flight", False) or getattr(args, "dataset", None) or getattr(args, "root", None):
            raise ConfigError("give one of --bag, --flight and --dataset/--root")
        for opt in ("image_topic", "pose_topic"):
            if not getattr(args, opt):
                raise ConfigError(f"--bag needs --{opt.replace('_', '-')} T")
        calibration = getattr(args, "calibration", None)
        if sum(x is not None for x in (args.camera_info_topic, calibration, args.intrinsics, args.hfov)) > 1:
            raise ConfigError("give one of --camera-info-topic, --calibration, --intrinsics and --hfov")
        if args.camera_info_topic is None and calibration is None and (args.intrinsics is None) == (args.hfov is None):
            raise ConfigError(
                "--bag needs --camera-info-topic T, or exactly one of --calibration FILE, --intrinsics FX FY CX CY "
                "and --hfov DEG"
            )
        if args.hfov is not None and not 0 < args.hfov < 180:
            raise ConfigError(f"--hfov must be in (0, 180) degrees, got {args.hfov}")
        check_namespace(args.out_namespace)
    if getattr(args, "rerun", None) is not None:
        require_rerun()  # the file itself is checked with the command's inputs (cli.predict.inputs)


def open_bag(args: argparse.Namespace, size=None):
    """The stream-mode dataset of ``--bag`` at ``size`` (an int, ``(H, W)``, a
    :class:`~cosemdepth.data.frames.FocalSize` or None: the images' size); the
    :class:`~cosemdepth.robotics.bag_flight.BagFlight` is attached to it as ``dataset.bag_flight`` (stamps, frame_ids,
    absolute poses for the output bag and the recording)."""
    check_args(args)
    flight = open_bag_flight(
        args.bag,
        args.image_topic,
        args.pose_topic,
        camera_info_topic=args.camera_info_topic,
        intrinsics=args.intrinsics,
        fov=args.hfov,
        convention=args.convention or DEFAULT_BAG_CONVENTION,
        frame_skip=args.frame_skip,
        skip_unposed=args.skip_unposed,
        max_pose_gap=DEFAULT_MAX_POSE_GAP if args.max_pose_gap is None else args.max_pose_gap,
        ignore_distortion=args.ignore_distortion,
        calibration=getattr(args, "calibration", None),
        size=size,
        jpeg_idct=args.jpeg_idct,
    )
    dataset = flight.dataset
    dataset.bag_flight = flight
    return dataset


def make_sinks(args: argparse.Namespace, dataset, model, *, bag_output: bool = True) -> tuple:
    """The extra outputs of ``predict``: the output bag (``--bag``) and the rerun recording (``--rerun``)."""
    cfg = _model_config(model)
    classes = class_count(cfg)
    names, palette = class_info(classes, "flight") if classes else ((), None)
    flight = getattr(dataset, "bag_flight", None)
    sinks = []
    if flight is not None and bag_output:

        def header(index: int) -> tuple[int, str]:
            row = flight.row(index)
            return int(flight.index.stamps[row]), flight.index.frame_ids[row]

        sinks.append(BagWriter(header, flight.intrinsics.tolist(), palette, args.out_namespace))
    if getattr(args, "rerun", None) is not None:
        to_world = (lambda i: flight.camera_to_world(flight.row(i))) if flight is not None else None
        sinks.append(
            RerunWriter(
                args.rerun,
                dataset,
                class_names=names,
                palette=palette,
                camera_to_world=to_world,
                command=getattr(args, "command", None) or "view",
            )
        )
    return tuple(sinks)


def bag_report(dataset) -> str:
    """``"; N images skipped without a pose"`` for a bag run with --skip-unposed, else ``""``."""
    flight = getattr(dataset, "bag_flight", None)
    if flight is None:
        return ""
    text = f"; bag: {len(flight.index.stamps)} of {flight.index.total} images"
    if flight.index.skipped:
        text += f", {flight.index.skipped} skipped without a pose"
    return text


__all__ = ["add_robotics_args", "bag_report", "check_args", "make_sinks", "open_bag"]
