"""Parsed arguments -> the frozen options of the streaming commands (:mod:`cosemdepth.jobs`): the one place where
an ``argparse.Namespace`` becomes a library value. The values are checked by the options themselves."""

from __future__ import annotations

import argparse
import sys

from ..data.video import is_video
from ..errors import ConfigError
from ..jobs.model import ModelOptions
from ..jobs.options import RunOptions
from ..streaming.sources.bag import BagOptions
from ..streaming.sources.dataset import DatasetOptions
from ..streaming.sources.flight import FlightOptions
from ..streaming.sources.video_log import AUTO, VideoLogOptions
from .flag_rules import explicit


def run_options(args: argparse.Namespace) -> RunOptions:
    """``--size``, ``--policy``, ``--min-baseline``, ``--max-frames``, ``--trajectories-per-batch``, ``--workers``,
    and the progress bar (unless ``--no-progress``, when stderr is a terminal)."""
    return RunOptions(
        size=getattr(args, "size", None),
        policy=getattr(args, "policy", None),
        min_baseline=getattr(args, "min_baseline", None),
        max_frames=getattr(args, "max_frames", None),
        lanes=getattr(args, "lanes", 1),
        workers=getattr(args, "workers", 0),
        progress=not getattr(args, "no_progress", False) and sys.stderr.isatty(),
    )


def model_options(args: argparse.Namespace) -> ModelOptions:
    """``--model``, ``--reference``, ``--precision``, ``--device``, ``--threads``, ``--backend``, ``--onnx``."""
    return ModelOptions(
        path=args.model,
        reference=args.reference,
        precision=args.precision,
        device=args.device,
        threads=args.threads,
        backend=getattr(args, "backend", "pytorch"),
        onnx=getattr(args, "onnx", None),
    )


def split_options(args: argparse.Namespace) -> DatasetOptions:
    """``--dataset``, ``--root``, ``--split-dir``, ``--split``, ``--jpeg-idct``."""
    idct = getattr(args, "jpeg_idct", None)
    return DatasetOptions(
        args.dataset,
        args.root,
        args.split_dir,
        args.split,
        **({"jpeg_idct": idct} if idct else {}),
        calibration=getattr(args, "calibration", None),
    )


#: predict's / view's flags of a video with a log, and of a folder of images with a pose file (``--flight``)
_VIDEO_FLAGS = ("--log", "--log-format", "--time-offset", "--camera-mount", "--lever-arm")
_IMAGE_FLAGS = ("--poses", "--convention", "--match", "--stamp-unit", "--skip-unposed")


def video_options(args: argparse.Namespace) -> VideoLogOptions:
    """``--flight --images VIDEO --log FILE``: :class:`~cosemdepth.streaming.sources.video_log.VideoLogOptions`;
    the flags of a folder of images (``--poses``, ``--match``...) are refused."""
    for flag in _IMAGE_FLAGS:
        if flag in explicit(args):
            raise ConfigError(
                f"{flag} applies to a folder of images with a pose file, not to a video (--images {args.images}: "
                "its poses come from --log)"
            )
    if "--jpeg-idct" in explicit(args):
        raise ConfigError(f"--jpeg-idct applies to JPEG images, not to a video (--images {args.images})")
    if args.log is None:
        raise ConfigError(f"--images {args.images} is a video: give the flight controller's log with --log FILE")
    return VideoLogOptions(
        video=args.images,
        log=args.log,
        log_format=args.log_format,
        time_offset=AUTO if args.time_offset is None else args.time_offset,
        camera_mount=args.camera_mount or "forward",
        lever_arm=None if args.lever_arm is None else tuple(args.lever_arm),
        intrinsics=None if args.intrinsics is None else tuple(args.intrinsics),
        hfov=args.hfov,
        calibration=getattr(args, "calibration", None),
        frame_skip=args.frame_skip,
        max_pose_gap=args.max_pose_gap,
    )


def source_options(args: argparse.Namespace):
    """The input of predict / view: ``--bag``, ``--flight`` or a dataset split (only one of them)."""
    if args.bag is not None:
        if args.flight or args.dataset or args.root:
            raise ConfigError("give one of --bag, --flight and --dataset/--root")
        return BagOptions(
            args.bag,
            args.image_topic,
            args.pose_topic,
            camera_info_topic=args.camera_info_topic,
            intrinsics=None if args.intrinsics is None else tuple(args.intrinsics),
            hfov=args.hfov,
            convention=args.convention,
            frame_skip=args.frame_skip,
            max_pose_gap=args.max_pose_gap,
            skip_unposed=args.skip_unposed,
            ignore_distortion=args.ignore_distortion,
            jpeg_idct=args.jpeg_idct,
            calibration=args.calibration,
        )
    if args.flight:
        if args.dataset or args.root:
            raise ConfigError("give either --flight (with --images, --poses) or --dataset/--root, not both")
        if args.images is not None and is_video(args.images):
            return video_options(args)
        for flag in _VIDEO_FLAGS:
            if flag in explicit(args):
                raise ConfigError(f"{flag} applies to a video (--images VIDEO with --log), not to a folder of images")
        return FlightOptions(
            args.images,
            args.poses,
            intrinsics=None if args.intrinsics is None else tuple(args.intrinsics),
            hfov=args.hfov,
            convention=args.convention,
            frame_skip=args.frame_skip,
            match=args.match,
            stamp_unit=args.stamp_unit,
            max_pose_gap=args.max_pose_gap,
            skip_unposed=args.skip_unposed,
            jpeg_idct=args.jpeg_idct,
            calibration=args.calibration,
        )
    return split_options(args)


__all__ = ["model_options", "run_options", "source_options", "split_options", "video_options"]
