"""``cosemdepth export --onnx OUT``: the streaming step as an ONNX graph with the state as inputs/outputs."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch

from ..data.registry import DATASETS, split_datasets
from ..errors import ConfigError
from ..export.check import CHECK_FRAMES, NOISE_MULTIPLE, compare_onnx
from ..export.onnx import DEFAULT_OPSET, MIN_OPSET, export_onnx, is_our_onnx
from ..export.quantize import CALIBRATION_FRAMES, int8_weights, quantize_onnx
from ..models.footprint import check_size
from ..optional import require
from ..output_safety.outdir import Input, check_output_file, model_inputs, record_output_file
from ._shared import (
    DEFAULT_SIZE_PAIR,
    add_model_or_arch_args,
    load_or_build,
    model_size_pair,
    parse_size_pair,
    positive_int,
)

#: the SynthAir world ``--int8`` calibrates on without ``--calibration-root`` (none the studies evaluate on)
CALIBRATION_WORLD = 7


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--onnx",
        metavar="OUT",
        required=True,
        help="output .onnx file (its folder must exist; an existing file is "
        "replaced only if cosemdepth export wrote it)",
    )
    add_model_or_arch_args(parser)
    parser.add_argument(
        "--size",
        nargs=2,
        type=int,
        metavar=("H", "W"),
        help="input size (default: the model's training size, from its operating point, with "
        "--model; else {} {})".format(*DEFAULT_SIZE_PAIR),
    )
    parser.add_argument("--batch", type=int, default=1, help="batch size (default 1)")
    parser.add_argument("--dynamic-batch", action="store_true", help="make the batch axis dynamic")
    parser.add_argument(
        "--opset", type=int, default=DEFAULT_OPSET, help=f"ONNX opset, >= {MIN_OPSET} (default {DEFAULT_OPSET})"
    )
    parser.add_argument(
        "--reset-float", action="store_true", help="take the reset mask as float32 (1 = reset) instead of bool"
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help=f"stream {CHECK_FRAMES} frames of a SynthAir flight through ONNX Runtime and PyTorch; exit "
        f"status 1 when ONNX Runtime is further from PyTorch than {NOISE_MULTIPLE:g}x the drift of two "
        "float32 PyTorch runs that differ only in rounding (docs/deploy.md); with --int8 it checks the "
        "float32 graph before quantisation",
    )
    parser.add_argument(
        "--int8",
        action="store_true",
        help="quantise the semantic refiners' hidden convolutions to int8 (static QDQ, calibrated on a stream of "
        "frames; the depth decoder, encoder, cost volumes and state stay float32): faster in ONNX Runtime on "
        "CPUs with VNNI; check its accuracy with 'cosemdepth fast-accuracy --modes onnx-int8' (docs/deploy.md)",
    )
    parser.add_argument(
        "--calibration-root",
        type=Path,
        default=None,
        metavar="ROOT",
        help="--int8: a dataset root whose split's first frames calibrate (default: a SynthAir flight rendered "
        "at --size); with --calibration-dataset, --calibration-split-dir and --calibration-split",
    )
    parser.add_argument(
        "--calibration-dataset",
        default=None,
        choices=split_datasets(),
        metavar="NAME",
        help=f"--int8: dataset of --calibration-root: {', '.join(split_datasets())} (default midair)",
    )
    parser.add_argument("--calibration-split-dir", type=Path, default=None, metavar="D", help="--int8: split files")
    parser.add_argument("--calibration-split", default=None, metavar="SPLIT", help="--int8: split (dataset default)")
    parser.add_argument(
        "--calibration-frames",
        type=positive_int,
        default=None,
        metavar="N",
        help=f"--int8: calibration frames (default {CALIBRATION_FRAMES})",
    )


def run(args: argparse.Namespace) -> int:
    parse_size_pair(args.size)  # (checked before anything is read)
    if args.batch < 1:
        raise ConfigError(f"--batch must be at least 1, got {args.batch}")
    if not args.int8:
        for flag in (
            "calibration_root",
            "calibration_dataset",
            "calibration_split_dir",
            "calibration_split",
            "calibration_frames",
        ):
            if getattr(args, flag) is not None:
                raise ConfigError(f"--{flag.replace('_', '-')} calibrates --int8, which is not given")
    args.calibration_dataset = args.calibration_dataset or "midair"
    args.calibration_frames = args.calibration_frames or CALIBRATION_FRAMES
    inputs = model_inputs(args.model)
    if args.calibration_root is not None:
        inputs = [*inputs, Input("--calibration-root", args.calibration_root)]
        _check_calibration_args(args)
    # the output policy: not a folder, under an existing folder, not an input; an existing file only if we wrote it
    check_output_file(args.onnx, what="--onnx file", inputs=inputs, recognize=is_our_onnx)
    require("onnx", "export")  # what the export and --check need, before anything is written
    if args.check or args.int8:
        require("onnxruntime", "export --check" if args.check else "export --int8")
    model = load_or_build(args)
    h, w = model_size_pair(args.size, model)
    check_size(model, h, w, batch=args.batch)  # the export traces a step in float32 on the CPU
    if args.int8 and not int8_weights(model):
        raise ConfigError(
            f"--int8: {model.config.arch} has no convolution the int8 policy quantises (it keeps the depth "
            "decoder float); export it without --int8"
        )
    calibration = _calibration(args, h, w) if args.int8 else None  # read before anything is written
    with tempfile.TemporaryDirectory(prefix="cosemdepth-export-") as work:
        graph = export_onnx(
            model,
            Path(work) / "float32.onnx" if args.int8 else args.onnx,
            h,
            w,
            batch=args.batch,
            opset=args.opset,
            dynamic_batch=args.dynamic_batch,
            reset_float=args.reset_float,
        )
        report = compare_onnx(model, graph) if args.check else None
        if args.int8:
            batch = 1 if args.dynamic_batch else args.batch
            frames = [tuple(t.expand(batch, *t.shape[1:]).contiguous() for t in f) for f in calibration]
            path = quantize_onnx(model, graph, args.onnx, frames)
        else:
            path = graph
    record_output_file(path, "export")  # replaced by a later export only while unchanged
    kind = f", int8 semantic refiners calibrated on {len(calibration)} frames" if args.int8 else ""
    print(f"wrote {path} ({model.config.arch}, {h}x{w}, batch {args.batch}, opset {args.opset}{kind})")
    if not args.model:
        print("note: no --model given, the graph holds freshly initialised weights")
    if report is not None:
        print(("the float32 graph before quantisation: " if args.int8 else "") + report.summary())
        if not report.ok:
            return 1
    return 0


def _check_calibration_args(args: argparse.Namespace) -> None:
    """The calibration folders exist, and the dataset's split files are found."""
    if not Path(args.calibration_root).is_dir():
        raise ConfigError(f"--calibration-root {args.calibration_root}: not a folder")
    if args.calibration_split_dir is not None and not Path(args.calibration_split_dir).is_dir():
        raise ConfigError(f"--calibration-split-dir {args.calibration_split_dir}: not a folder")
    spec = DATASETS[args.calibration_dataset]
    if args.calibration_split_dir is None and spec.needs_split_dir and spec.split_dir is None:
        raise ConfigError(
            f"--calibration-dataset {args.calibration_dataset} needs --calibration-split-dir D, the folder of its "
            f"split files (<split>_data/**/*.csv); write them with: cosemdepth splits {args.calibration_dataset} ROOT D"
        )


def _calibration(args: argparse.Namespace, h: int, w: int) -> list[tuple]:
    """The ``--int8`` calibration stream at ``h x w``: the first ``--calibration-frames`` frames of the calibration
    split, or of a SynthAir flight rendered on the fly, as ``(rgb, rot, trans, intrinsics, reset)`` of batch 1."""
    n = args.calibration_frames
    if args.calibration_root is None:
        from ..export.check import flight_sequence  # deferred: renders a SynthAir world

        rgb, rot, trans, k = flight_sequence(1, n, h, w, seed=CALIBRATION_WORLD)
        return [(rgb[:, t], rot[:, t], trans[:, t], k, torch.tensor([t == 0])) for t in range(n)]
    from ..bench.accuracy import calibration_frames
    from ..data import open_dataset

    ds = open_dataset(
        args.calibration_dataset,
        args.calibration_root,
        split_dir=args.calibration_split_dir,
        split=args.calibration_split,
        seq_len=1,
        size=(h, w),
    )
    return calibration_frames(ds, n)
