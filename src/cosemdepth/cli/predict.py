"""``cosemdepth predict``: run a model on a dataset split or on your own flight and write its outputs.

    cosemdepth predict --model MODEL --dataset NAME --root ROOT [--split-dir D] [--split test] --out DIR
    cosemdepth predict --model MODEL --flight --images DIR --poses FILE (--intrinsics FX FY CX CY | --hfov DEG) --out DIR
    cosemdepth predict --model MODEL --bag PATH --image-topic T --pose-topic T (--camera-info-topic T | ...) --out DIR

Outputs (depth as float32 .npy and 16-bit PNG = round(depth_m * 256), labels, colourised labels, side-by-side
pictures, a video): see :mod:`cosemdepth.evaluation.predict`.

Without ``--size`` the input is read at the size where its camera (the dataset's, ``--intrinsics`` / ``--hfov`` at
the images' size, or the bag's camera_info) has the model's focal length in pixels, keeping its aspect ratio (the
operating point in the model's config.json); a model without one runs at the dataset table's size, or a flight's
image size. A ``--size`` far from the model's focal length gets a warning on stderr.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..data import open_dataset
from ..data.flight import DEFAULT_CONVENTION
from ..data.pose_matching import DEFAULT_MAX_GAP, MATCHES
from ..data.poses import CONVENTIONS
from ..data.stamps import UNITS, parse_stamp_unit
from ..decoders.depth.task import no_depth_warning
from ..errors import ConfigError
from ..evaluation.predict import DEFAULT_INVALID, INVALID_MODES, predict
from ..evaluation.visualize import DEFAULT_FPS, DEFAULT_VIDEO, VIDEO_FORMATS
from ..inference.policy import BASELINE, EVERY_FRAME
from ..models.outputs import ESTIMATED, HELD, RESET
from ..output_safety.outdir import Input, model_inputs
from ..output_safety.staging import StagedDir
from ..robotics.bag_flight import DEFAULT_BAG_CONVENTION, DEFAULT_MAX_POSE_GAP
from ..robotics.cli import add_robotics_args, bag_report, check_args, make_sinks, open_bag
from ..robotics.rerun_writer import check_rrd_path
from ..workers import check_workers
from ._shared import (
    add_model_args,
    add_policy_args,
    add_run_args,
    add_split_args,
    apply_threads,
    check_run_size,
    check_split_dir,
    frame_size,
    input_size,
    load,
    model_operating_point,
    parse_size,
    positive_int,
    size_help,
    stream_policy,
    warn_far_size,
)
from .flag_rules import explicit


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
    flight.add_argument("--flight", action="store_true", help="run on a folder of images with a pose file")
    flight.add_argument("--images", type=Path, metavar="DIR", help="folder of the flight's images")
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


def _validate(args: argparse.Namespace) -> None:
    """The argument checks that need no file."""
    check_workers(args.workers)
    if args.max_pose_gap is not None and not args.max_pose_gap >= 0:
        raise ConfigError(f"--max-pose-gap must be >= 0 seconds, got {args.max_pose_gap}")
    check_args(args)
    if args.backend == "onnxruntime":
        if args.reference or args.precision != "fp32":
            raise ConfigError(
                "--backend onnxruntime runs --onnx at the precision it was exported in: drop --reference / --precision"
            )
        if args.onnx is None:
            raise ConfigError("--backend onnxruntime needs --onnx FILE (a graph written by 'cosemdepth export --onnx')")
        if args.device not in ("auto", "cpu"):
            raise ConfigError(f"--backend onnxruntime runs on the CPU provider, not --device {args.device}")
    elif args.onnx is not None:
        raise ConfigError("--onnx is the graph of --backend onnxruntime: add --backend onnxruntime")
    if args.bag is not None:
        return
    if args.flight:
        if args.dataset or args.root:
            raise ConfigError("give either --flight (with --images, --poses) or --dataset/--root, not both")
        if args.images is None:
            raise ConfigError("--flight needs --images DIR")
        if args.poses is None:
            raise ConfigError("--flight needs --poses FILE")
        if sum(x is not None for x in (args.intrinsics, args.hfov, getattr(args, "calibration", None))) != 1:
            raise ConfigError(
                "--flight needs exactly one of --intrinsics FX FY CX CY, --hfov DEG and --calibration FILE"
            )
        if args.hfov is not None and not 0 < args.hfov < 180:
            raise ConfigError(f"--hfov must be in (0, 180) degrees, got {args.hfov}")
        parse_stamp_unit(args.stamp_unit)
        given = explicit(args)
        # flags of matching by stamp, given with a rule that reads no image stamps
        for flag, rules in (("--max-pose-gap", ("order", "index")), ("--skip-unposed", ("order",))):
            if flag in given and args.match in rules:
                raise ConfigError(
                    f"{flag} does not apply to --match {args.match} (every image takes a pose row as "
                    "it is; no interpolation between poses)"
                )
    elif not args.dataset or args.root is None:
        raise ConfigError("give --dataset NAME --root ROOT (a dataset split), or --flight --images DIR --poses FILE")


def _open(args: argparse.Namespace):
    """The input of predict / view, at ``--size`` or else at the model's focal length (``cli._shared.input_size``);
    a ``--size`` far from the model's focal length gets a warning."""
    op = model_operating_point(args.model)
    size = input_size(args.size, op)
    if args.bag is not None:
        dataset = open_bag(args, size)
    elif args.flight:
        dataset = open_dataset(
            "flight",
            args.images,
            poses=args.poses,
            intrinsics=args.intrinsics,
            fov=args.hfov,
            convention=args.convention or DEFAULT_CONVENTION,
            frame_skip=args.frame_skip,
            seq_len=1,
            size=size,
            jpeg_idct=args.jpeg_idct,
            match=args.match,
            stamp_unit=args.stamp_unit,
            max_gap=DEFAULT_MAX_GAP if args.max_pose_gap is None else args.max_pose_gap,
            skip_unposed=args.skip_unposed,
            calibration=args.calibration,
        )
    else:
        check_split_dir(args)
        dataset = open_dataset(
            args.dataset,
            args.root,
            split_dir=args.split_dir,
            split=args.split,
            seq_len=1,
            size=size,
            jpeg_idct=args.jpeg_idct,
            **({"calibration": args.calibration} if args.calibration is not None else {}),
        )
    warn_far_size(op, args.size, dataset)
    note = ((getattr(dataset, "calibration", None) or {}).get("calibration") or {}).get("note")
    if note:
        print(f"cosemdepth: note: {note}", file=sys.stderr)
    return dataset


def command_inputs(args: argparse.Namespace) -> list:
    """The input paths of predict / view (for the output policy of :mod:`cosemdepth.output_safety.outdir`)."""
    return [
        *model_inputs(args.model),
        *(
            Input(label, p)
            for label, p in (
                ("--root", args.root),
                ("--split-dir", args.split_dir),
                ("--images", args.images),
                ("--poses", args.poses),
                ("--bag", args.bag),
                ("--calibration", args.calibration),
            )
            if p is not None
        ),
    ]


def flight_report(dataset) -> str:
    """``"; flight: 16 of 16 images matched to poses by stamp (...)"`` for a flight, else ``""``."""
    matching = getattr(dataset, "pose_matching", None)
    return f"; flight: {matching['describe']}" if matching else ""


def run_settings(args: argparse.Namespace, dataset, model=None) -> dict:
    """What determines predict's outputs besides the frames: ``predictions.json``'s ``run`` entry. ``input_size``
    ``[H, W]`` and ``intrinsics`` ``[fx, fy, cx, cy]`` (package convention: pixel centres at +0.5) are those the model
    was fed; the pose settings are null for dataset splits (whose readers fix them); ``precision`` is the graph's
    own (its metadata) with ``--backend onnxruntime``."""
    graph = getattr(model, "onnx", None) if getattr(args, "backend", "pytorch") == "onnxruntime" else None
    own = bool(args.flight or args.bag)
    convention = args.convention or (DEFAULT_BAG_CONVENTION if args.bag else DEFAULT_CONVENTION)
    size = frame_size(dataset)
    return {
        "model": str(args.model),
        "path": "onnxruntime"
        if getattr(args, "backend", "pytorch") == "onnxruntime"
        else "reference"
        if args.reference
        else "fast",
        "onnx": str(args.onnx) if getattr(args, "onnx", None) is not None else None,
        "precision": graph.precision if graph is not None else args.precision,
        "input_size": None if size is None else list(size),
        "intrinsics": [float(v) for v in dataset.intrinsics.tolist()],
        "intrinsics_given": None if args.intrinsics is None else [float(v) for v in args.intrinsics],
        "hfov_deg": args.hfov,
        "calibration": None if args.calibration is None else str(args.calibration),
        "camera_info_topic": args.camera_info_topic,
        "convention": convention if own else None,
        "frame_skip": args.frame_skip if own else None,
        "poses": str(args.poses) if args.flight and args.poses is not None else None,
        "pose_topic": args.pose_topic if args.bag else None,
        "match": args.match if args.flight else None,
        "stamp_unit": args.stamp_unit if args.flight else None,
        "max_pose_gap": args.max_pose_gap if own else None,
        "skip_unposed": args.skip_unposed if own else None,
        "jpeg_idct": args.jpeg_idct,
    }


def run(args: argparse.Namespace) -> int:
    apply_threads(args)
    _validate(args)
    policy, min_baseline = input_policy(args)
    inputs = command_inputs(args)
    StagedDir(args.out, "predict", overwrite=args.overwrite, what="--out folder", inputs=inputs).check()  # first
    check_rrd_path(args.rerun, inputs=[*inputs, Input("--out", args.out)]) if args.rerun is not None else None
    dataset = _open(args)
    if args.backend == "onnxruntime":
        model, device = _onnx_model(args, dataset)
    else:
        model, device = load(args.model, args.device, fast=not args.reference, precision=args.precision)
    check_run_size(model, dataset, device, args.lanes)
    info = {
        "model": {"path": str(args.model)},
        "dataset": {
            "root": str(args.bag if args.bag else args.images if args.flight else args.root),
            "split": None if args.flight else args.split,
            **({"pose_matching": dataset.pose_matching} if hasattr(dataset, "pose_matching") else {}),
            **({"undistortion": dataset.calibration} if getattr(dataset, "calibration", None) else {}),
        },
        "device": str(device),
        "run": run_settings(args, dataset, model),
    }
    manifest = predict(
        model,
        dataset,
        args.out,
        video=args.video,
        fps=args.fps,
        max_frames=args.max_frames,
        lanes=args.lanes,
        num_workers=args.workers,
        overwrite=args.overwrite,
        progress=not args.no_progress and sys.stderr.isatty(),
        dataset_name="flight" if args.flight or args.bag else args.dataset,
        info=info,
        sinks=make_sinks(args, dataset, model),
        inputs=inputs,
        policy=policy,
        min_baseline=min_baseline,
        invalid=args.invalid,
    )
    n = manifest["frames_written"]
    videos = [t["video"] for t in manifest["trajectories"] if "video" in t]
    nt = len(manifest["trajectories"])
    print(
        f"wrote {n} frame{'s' * (n != 1)} of {nt} trajector{'ies' if nt != 1 else 'y'} to {args.out}"
        + (f"; videos: {', '.join(str(args.out / v) for v in videos)}" if videos else "")
        + bag_report(dataset)
        + flight_report(dataset)
        + (f"; rerun recording: {args.rerun}" if args.rerun else "")
    )
    if manifest.get("frames_by_status") is not None:
        print(
            depth_report(
                manifest["frames_by_status"],
                manifest["policy"],
                [f.get("valid_fraction", 0.0) for f in manifest["frames"]],
            )
        )
        counts, fractions = manifest["frames_by_status"], [f.get("valid_fraction", 0.0) for f in manifest["frames"]]
        no_depth = no_depth_warning(
            sum(counts.values()),
            counts.get(ESTIMATED, 0),
            counts.get(HELD, 0),
            sum(fractions) / len(fractions) if fractions else None,
        )
        if no_depth:
            print(f"cosemdepth predict: warning: {no_depth}", file=sys.stderr)
    return 0


def _onnx_model(args: argparse.Namespace, dataset):
    """``(model, device)`` of ``--backend onnxruntime``: the graph ``--onnx`` behind the model's ``step``, checked
    against the input's frame size and ``--trajectories-per-batch`` before any frame is read."""
    import torch

    from ..export.runtime import OnnxModel, OnnxStep
    from ..optional import require

    require("onnxruntime", "predict --backend onnxruntime")
    if not args.onnx.is_file():
        raise ConfigError(f"--onnx {args.onnx}: no such file")
    model, device = load(args.model, "cpu", fast=False)
    step = OnnxStep(args.onnx, threads=args.threads)
    onnx_model = OnnxModel(model, step, model_name=f"--model {args.model}")  # refuses a graph of another model
    want = (None, 3, *frame_size(dataset)) if frame_size(dataset) is not None else None
    got = step.shape
    if want is not None and tuple(got[1:]) != tuple(want[1:]):
        raise ConfigError(
            f"--onnx {args.onnx}: the graph takes {got[2]}x{got[3]} images, the input is read at "
            f"{want[2]}x{want[3]} (export at this size with --size, or give --size)"
        )
    if got[0] is not None and (got[0] != 1 or args.lanes != 1):
        raise ConfigError(
            f"--onnx {args.onnx}: the graph has a fixed batch of {got[0]}; streaming needs batch 1 "
            "(and --trajectories-per-batch 1) or a graph exported with --dynamic-batch"
        )
    return onnx_model, torch.device("cpu")


def input_policy(args: argparse.Namespace) -> tuple[str | None, float | None]:
    """``(policy, min_baseline)`` of predict / view: ``--policy`` as given, else baseline for flights and bags
    (every-frame for a model that records no training motion) and every-frame for dataset splits."""
    return stream_policy(args, None if args.flight or args.bag is not None else EVERY_FRAME)


def depth_report(statuses: dict, policy: dict, valid_fractions) -> str:
    """The summary line of the depth's statuses, e.g. ``"depth (policy baseline): 137 frames estimated, 1 reset
    (no depth); 12 frames held: the camera moved less than 0.74 m from its reference frame; 91.3 % of the pixels
    valid"``."""
    est, held, reset = (int(statuses.get(k, 0)) for k in (ESTIMATED, HELD, RESET))
    parts = [f"{est} frame{'s' * (est != 1)} estimated, {reset} reset (no depth)"]
    if held:
        parts.append(
            f"{held} frame{'s' * (held != 1)} held: the camera moved less than "
            f"{policy['min_baseline_m']:.2f} m from its reference frame"
        )
    fractions = list(valid_fractions)
    if fractions:
        parts.append(f"{100.0 * sum(fractions) / len(fractions):.1f} % of the pixels valid")
    return f"depth (policy {policy['mode']}): " + "; ".join(parts)
