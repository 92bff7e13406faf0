"""``cosemdepth node``: join the ROS 2 graph and publish depth, validity and labels for a live camera.

    cosemdepth node --model MODEL --image-topic T --pose-topic T
                    (--camera-info-topic T | --calibration FILE | --hfov DEG | --intrinsics ...)
                    [--convention C] [--out-namespace NS] [--points] [--backend onnxruntime --onnx FILE]

No ROS installation: the node is a Cyclone DDS participant (``pip install cosemdepth[live]``) in the domain
``ROS_DOMAIN_ID``, configured by ``CYCLONEDDS_URI``. It runs until SIGINT / SIGTERM (or ``--max-frames``). Topics,
QoS and behaviour: docs/robotics.md, :mod:`cosemdepth.ros2`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..data.frames import as_size
from ..data.poses import CONVENTIONS
from ..errors import ConfigError
from ..inference.policy import BASELINE, Streamer, policy_info
from ..jobs.model import input_size, load_for
from ..jobs.options import RunOptions
from ..measures.classes import class_info
from ..ros2.node import REPORT_EVERY
from ..ros2.source import DEFAULT_MAX_FRAME_GAP, DEFAULT_MAX_POSE_GAP, DEFAULT_POSE_TIMEOUT
from ..streaming.sinks.bag import DEFAULT_NAMESPACE, check_namespace
from ..tasks import class_count
from ._options import model_options
from ._shared import add_jpeg_idct_arg, add_model_args, add_policy_args, parse_size, positive_int


def configure(parser: argparse.ArgumentParser) -> None:
    add_model_args(parser)
    parser.add_argument(
        "--backend",
        choices=["pytorch", "onnxruntime"],
        default="pytorch",
        help="pytorch (default; the fast path, or --reference) or onnxruntime: the graph --onnx (written by "
        "'cosemdepth export --onnx', fp32 or --int8) at the size it was exported at",
    )
    parser.add_argument("--onnx", type=Path, metavar="FILE", help="the exported graph of --backend onnxruntime")
    inp = parser.add_argument_group("inputs (topics of the ROS 2 graph; their types are discovered from it)")
    inp.add_argument("--image-topic", required=True, metavar="T", help="sensor_msgs/Image or CompressedImage topic")
    inp.add_argument(
        "--pose-topic",
        required=True,
        metavar="T",
        help="geometry_msgs/PoseStamped, PoseWithCovarianceStamped, nav_msgs/Odometry, px4_msgs/VehicleOdometry, "
        "or /tf (tf2_msgs/TFMessage; see --world-frame, --body-frame)",
    )
    inp.add_argument("--camera-info-topic", metavar="T", help="sensor_msgs/CameraInfo topic for the intrinsics")
    inp.add_argument(
        "--calibration",
        type=Path,
        metavar="FILE",
        help="the camera's calibration file (ROS or OpenCV YAML, Kalibr, COLMAP cameras.txt; instead of "
        "--camera-info-topic): the images are undistorted to a pinhole, its intrinsics published on camera_info",
    )
    inp.add_argument(
        "--intrinsics",
        type=float,
        nargs=4,
        metavar=("FX", "FY", "CX", "CY"),
        help="pinhole intrinsics in pixels of the images (instead of --camera-info-topic)",
    )
    inp.add_argument("--hfov", type=float, metavar="DEG", help="horizontal field of view (instead of the above)")
    inp.add_argument(
        "--convention",
        choices=tuple(CONVENTIONS),
        default=None,
        help="axes of the posed frame (default ned for px4_msgs/VehicleOdometry, flu otherwise: REP 103 base_link "
        "with a forward-looking camera; opencv for poses of the camera's optical frame)",
    )
    inp.add_argument(
        "--world-frame", metavar="F", help="/tf pose topic: the fixed frame (default: the root above the body frame)"
    )
    inp.add_argument(
        "--body-frame",
        metavar="F",
        help="/tf pose topic: the posed frame (default: base_link when /tf names it, else the one frame /tf moves)",
    )
    inp.add_argument(
        "--ignore-distortion",
        action="store_true",
        help="use camera_info's K as if the images were undistorted (default: a distorting lens is undistorted to "
        "a pinhole, as predict --bag does)",
    )
    timing = parser.add_argument_group("timing")
    timing.add_argument(
        "--max-pose-gap",
        type=float,
        default=DEFAULT_MAX_POSE_GAP,
        metavar="S",
        help=f"interpolate an image's pose only between poses at most S seconds apart (default {DEFAULT_MAX_POSE_GAP:g})",
    )
    timing.add_argument(
        "--pose-timeout",
        type=float,
        default=DEFAULT_POSE_TIMEOUT,
        metavar="S",
        help="an image whose pose has not arrived S seconds after it is processed without depth "
        f"(default {DEFAULT_POSE_TIMEOUT:g})",
    )
    timing.add_argument(
        "--max-frame-gap",
        type=float,
        default=DEFAULT_MAX_FRAME_GAP,
        metavar="S",
        help="an image more than S seconds after the previous processed one starts afresh "
        f"(default {DEFAULT_MAX_FRAME_GAP:g})",
    )
    out = parser.add_argument_group("outputs")
    out.add_argument(
        "--out-namespace",
        default=DEFAULT_NAMESPACE,
        metavar="NS",
        help=f"prefix of the output topics (default {DEFAULT_NAMESPACE}: {DEFAULT_NAMESPACE}/depth, ...)",
    )
    out.add_argument(
        "--remap",
        action="append",
        default=[],
        metavar="NAME:=TOPIC",
        help="publish output NAME (depth, depth_valid, depth_status, labels, labels_color, camera_info, points) on "
        "TOPIC instead (repeatable)",
    )
    out.add_argument("--points", action="store_true", help="also publish the valid depth as a PointCloud2 (points)")
    out.add_argument(
        "--input-qos",
        choices=("sensor", "reliable"),
        default="sensor",
        help="sensor (the default; best effort, volatile, keep last 5; takes best-effort and reliable publishers) or "
        "reliable (keep last 10; takes reliable publishers only)",
    )
    out.add_argument(
        "--output-qos",
        choices=("sensor", "reliable"),
        default="sensor",
        help="sensor (the default; best effort, volatile, keep last 5) or reliable (volatile, keep last 10: for "
        "subscribers that ask for reliable, e.g. rviz2's default)",
    )
    parser.add_argument(
        "--size",
        type=parse_size,
        default=None,
        metavar="S",
        help="network input size, S or HxW (default: the size where the camera has the model's focal length, "
        "keeping the images' aspect ratio; the images' size for a model without one; the graph's with --onnx)",
    )
    add_policy_args(parser, f"{BASELINE} (every-frame for a model that records no training motion)")
    run_ = parser.add_argument_group("running")
    run_.add_argument("--max-frames", type=positive_int, default=None, metavar="N", help="stop after N frames")
    run_.add_argument(
        "--discovery-timeout",
        type=float,
        default=None,
        metavar="S",
        help="give up (exit 2) when the input topics have no publisher after S seconds (default: wait)",
    )
    run_.add_argument(
        "--report-every",
        type=float,
        default=REPORT_EVERY,
        metavar="S",
        help=f"seconds between two progress lines on stderr (default {REPORT_EVERY:g}; 0: none)",
    )
    run_.add_argument("--summary", metavar="FILE.json", help="write the run's summary (counters, latency) to FILE")
    add_jpeg_idct_arg(parser)


def _model(args: argparse.Namespace, run: RunOptions):
    """``(model, size)``: the model of ``--model`` / ``--backend`` and the input size to open the camera at (the
    graph's with ``--backend onnxruntime``)."""
    options = model_options(args)
    options.apply_threads()
    model, _ = load_for(options)
    if options.backend != "onnxruntime":
        return model, input_size(run.size, options.operating_point())
    graph_size = tuple(int(v) for v in model.onnx.shape[2:])
    if model.onnx.shape[0] not in (None, 1):
        raise ConfigError(f"--onnx {args.onnx}: the graph has a fixed batch of {model.onnx.shape[0]}; the node needs 1")
    if run.size is not None and as_size(run.size, "--size") != graph_size:
        raise ConfigError(
            f"--onnx {args.onnx}: the graph takes {graph_size[0]}x{graph_size[1]} images, not --size {args.size}"
        )
    return model, graph_size


def run(args: argparse.Namespace) -> int:
    from ..ros2.dds import Graph
    from ..ros2.node import run_node
    from ..ros2.sink import TopicSink, output_names, parse_remaps
    from ..ros2.source import LiveOptions, LiveSource, log_stderr

    run_opts = RunOptions(
        size=args.size, policy=args.policy, min_baseline=args.min_baseline, max_frames=args.max_frames
    )
    options = LiveOptions(
        image_topic=args.image_topic,
        pose_topic=args.pose_topic,
        camera_info_topic=args.camera_info_topic,
        calibration=args.calibration,
        intrinsics=None if args.intrinsics is None else tuple(args.intrinsics),
        hfov=args.hfov,
        convention=args.convention,
        world_frame=args.world_frame,
        body_frame=args.body_frame,
        max_pose_gap=args.max_pose_gap,
        pose_timeout=args.pose_timeout,
        max_frame_gap=args.max_frame_gap,
        input_qos=args.input_qos,
        ignore_distortion=args.ignore_distortion,
        jpeg_idct=args.jpeg_idct,
        discovery_timeout=args.discovery_timeout,
    )
    check_namespace(args.out_namespace)
    remaps = parse_remaps(args.remap)
    if args.discovery_timeout is not None and not args.discovery_timeout >= 0:
        raise ConfigError(f"--discovery-timeout must be >= 0 seconds, got {args.discovery_timeout}")
    policy, min_baseline = run_opts.stream_policy(None)
    model, size = _model(args, run_opts)
    streamer = Streamer(model, policy, min_baseline=min_baseline)
    cfg = model.config
    classes = class_count(cfg)
    _, palette = class_info(classes, "flight") if classes else ((), None)
    outputs = output_names(streamer.has_depth, "semantic" in streamer.decoders, palette is not None, args.points)
    with Graph() as graph:
        source = LiveSource(graph, options, size)
        sink = TopicSink(
            graph,
            outputs,
            namespace=args.out_namespace,
            remaps=remaps,
            palette=palette,
            profile=args.output_qos,
            stats=source.stats,
        )
        log_stderr(
            f"model {args.model} ({args.backend}{'' if args.backend != 'pytorch' else ', reference' if args.reference else ', fast ' + args.precision}), "
            f"policy {policy_info(streamer)['mode']}; publishing {', '.join(sink.topics.values())} "
            f"({args.output_qos} QoS)"
        )
        summary = run_node(source, streamer, sink, max_frames=args.max_frames, report_every=args.report_every)
    summary["policy"] = policy_info(streamer)
    if args.summary:
        from ..output_safety.atomic import atomic_write_text

        atomic_write_text(args.summary, json.dumps(summary, indent=2, default=str) + "\n")
    if (
        summary["frames_processed"] == 0
        and args.discovery_timeout is not None
        and summary["input"]["pose_type"] is None
    ):
        raise ConfigError(
            f"no publisher on {options.image_topic if summary['input']['image_type'] is None else options.pose_topic}"
            f" within --discovery-timeout {args.discovery_timeout:g} s (domain {summary['input']['domain']})"
        )
    print(f"cosemdepth node: stopped; {summary['report']}", file=sys.stderr)
    return 0
