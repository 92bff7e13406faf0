"""``cosemdepth export --onnx OUT``: the streaming step as an ONNX graph with the state as inputs/outputs."""

from __future__ import annotations

import argparse

from ..errors import ConfigError
from ..export.check import CHECK_FRAMES, NOISE_MULTIPLE, compare_onnx
from ..export.onnx import DEFAULT_OPSET, MIN_OPSET, export_onnx, is_our_onnx
from ..models.footprint import check_size
from ..optional import require
from ..output_safety.outdir import check_output_file, model_inputs, record_output_file
from ._shared import DEFAULT_SIZE_PAIR, add_model_or_arch_args, load_or_build, model_size_pair, parse_size_pair


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
        "float32 PyTorch runs that differ only in rounding (docs/deploy.md)",
    )


def run(args: argparse.Namespace) -> int:
    parse_size_pair(args.size)  # (checked before anything is read)
    if args.batch < 1:
        raise ConfigError(f"--batch must be at least 1, got {args.batch}")
    # the output policy: not a folder, under an existing folder, not an input; an existing file only if we wrote it
    check_output_file(args.onnx, what="--onnx file", inputs=model_inputs(args.model), recognize=is_our_onnx)
    require("onnx", "export")  # what the export and --check need, before anything is written
    if args.check:
        require("onnxruntime", "export --check")
    model = load_or_build(args)
    h, w = model_size_pair(args.size, model)
    check_size(model, h, w, batch=args.batch)  # the export traces a step in float32 on the CPU
    path = export_onnx(
        model,
        args.onnx,
        h,
        w,
        batch=args.batch,
        opset=args.opset,
        dynamic_batch=args.dynamic_batch,
        reset_float=args.reset_float,
    )
    record_output_file(path, "export")  # replaced by a later export only while unchanged
    print(f"wrote {path} ({model.config.arch}, {h}x{w}, batch {args.batch}, opset {args.opset})")
    if not args.model:
        print("note: no --model given, the graph holds freshly initialised weights")
    if args.check:
        report = compare_onnx(model, path)
        print(report.summary())
        if not report.ok:
            return 1
    return 0
