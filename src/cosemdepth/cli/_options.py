"""Parsed arguments -> the frozen options of the streaming commands (:mod:`cosemdepth.jobs`): the one place where
an ``argparse.Namespace`` becomes a library value. The values are checked by the options themselves."""

from __future__ import annotations

import argparse
import sys

from ..errors import ConfigError
from ..jobs.model import ModelOptions
from ..jobs.options import RunOptions
from ..streaming.sources.bag import BagOptions
from ..streaming.sources.dataset import DatasetOptions
from ..streaming.sources.flight import FlightOptions


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


__all__ = ["model_options", "run_options", "source_options", "split_options"]
