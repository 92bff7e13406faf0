"""``cosemdepth fast-accuracy``: are the fast inference modes as accurate as the fp32 reference on these weights?

    cosemdepth fast-accuracy --model MODEL --dataset NAME --root ROOT [--split-dir D] [--split test] [--size S]
        [--modes fast-fp32 fast-bf16 fast-int8] [--max-frames N] [--device cpu] [--threads N]
        [--calibration-root ROOT2 [--calibration-split SPLIT] --calibration-frames 16] [--out fast_accuracy.json]

Streams the split frame by frame (the test protocol: reset frames count in no metric) through the reference path
and through each fast mode, and checks each mode against the reference: mIoU within 0.5 points and AbsRel within 1 %
(relative). ``onnx-fp32`` and ``onnx-int8`` run the graph ``cosemdepth export --onnx`` (``--int8``) writes at the
split's size in ONNX Runtime. ``fast-int8`` and ``onnx-int8`` calibrate on the first ``--calibration-frames`` frames of ``--calibration-root`` (another
flight; by default the evaluated split itself, which the report then says). Writes the report (the benchmark JSON
shape of :mod:`cosemdepth.bench.harness`) to ``--out``. Exit status 0 when every mode is within the tolerances, 1
when one is not, 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..bench.accuracy import (
    ABSREL_TOL_REL,
    CALIBRATED,
    CALIBRATION_FRAMES,
    DEFAULT_MODES,
    MIOU_TOL_POINTS,
    MODES,
    all_ok,
    calibration_frames,
    compare_modes,
)
from ..bench.harness import command_line, make_report, run_meta, write_report
from ..checkpoints.model_io import load_model
from ..data import open_dataset
from ..data.registry import dataset_spec
from ..devices import resolve_device
from ..jobs.model import input_size, model_operating_point
from ..optional import require
from ..output_safety.outdir import Input, check_output_file, model_inputs, record_output_file
from ._options import split_options
from ._shared import (
    add_device_args,
    add_split_args,
    apply_threads,
    parse_size,
    positive_int,
    size_help,
)

#: the report's ``tool``
TOOL = "cosemdepth fast-accuracy"
DEFAULT_OUT = "fast_accuracy.json"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model",
        required=True,
        metavar="MODEL",
        help="a model folder (config.json + model.safetensors) or an official TensorFlow checkpoint",
    )
    add_split_args(parser)
    parser.add_argument("--size", type=parse_size, default=None, metavar="S", help=size_help())
    parser.add_argument(
        "--modes",
        nargs="+",
        choices=[m for m in MODES if m != "reference"],
        default=list(DEFAULT_MODES),
        help=f"the fast modes compared with the reference (default {' '.join(DEFAULT_MODES)})",
    )
    parser.add_argument(
        "--max-frames",
        type=positive_int,
        default=None,
        metavar="N",
        help="only the first N frames of the split (in order)",
    )
    add_device_args(parser)
    parser.add_argument(
        "--calibration-root",
        type=Path,
        default=None,
        metavar="ROOT",
        help="fast-int8, onnx-int8: dataset root whose first frames calibrate (default: --root)",
    )
    parser.add_argument(
        "--calibration-split",
        default=None,
        metavar="SPLIT",
        help="fast-int8, onnx-int8: split of --calibration-root (default: --split)",
    )
    parser.add_argument(
        "--calibration-frames",
        type=positive_int,
        default=CALIBRATION_FRAMES,
        metavar="N",
        help=f"fast-int8, onnx-int8: calibration frames (default {CALIBRATION_FRAMES})",
    )
    parser.add_argument(
        "--out",
        default=DEFAULT_OUT,
        metavar="FILE",
        help=f"the JSON report (default {DEFAULT_OUT}; an existing file is replaced only if "
        "cosemdepth fast-accuracy wrote it and it is unchanged since)",
    )


def _is_ours(path: Path) -> bool:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(data, dict) and data.get("tool") == TOOL


def run(args: argparse.Namespace) -> int:
    apply_threads(args)
    inputs = [
        *model_inputs(args.model),
        Input("--root", args.root),
        Input("--split-dir", args.split_dir) if args.split_dir is not None else None,
        Input("--calibration-root", args.calibration_root) if args.calibration_root is not None else None,
    ]
    check_output_file(args.out, what="--out file", inputs=inputs, recognize=_is_ours)
    split_options(args).check_split_dir()
    if any(MODES[m][0] == "onnx" for m in args.modes):
        require("onnx", "fast-accuracy --modes onnx-*")
        require("onnxruntime", "fast-accuracy --modes onnx-*")
    device = resolve_device(args.device)
    size = input_size(args.size, model_operating_point(args.model))
    dataset = open_dataset(args.dataset, args.root, split_dir=args.split_dir, split=args.split, seq_len=1, size=size)
    size = list(dataset[0]["rgb"].shape[-2:])  # what it runs at (recorded in the report)
    calib_root = args.calibration_root or args.root
    calibration = None
    if any(m in CALIBRATED for m in args.modes):
        cal = open_dataset(
            args.dataset,
            calib_root,
            split_dir=args.split_dir if args.calibration_root is None else None,
            split=args.calibration_split or args.split,
            seq_len=1,
            size=size,
        )
        calibration = calibration_frames(cal, args.calibration_frames)
    compared = compare_modes(
        lambda: load_model(args.model, device=device, mode="reference").eval(),
        dataset,
        args.modes,
        device,
        args.max_frames,
        calibration,
    )
    params = {
        "model": str(args.model),
        "dataset": args.dataset,
        "root": str(args.root),
        "split_dir": None if args.split_dir is None else str(args.split_dir),
        "split": args.split or dataset_spec(args.dataset).split,
        "size": size,
        "modes": list(args.modes),
        "max_frames": args.max_frames,
        "device": str(device),
        "int8_calibration": None
        if calibration is None
        else {"root": str(calib_root), "frames": len(calibration), "same_as_evaluated": calib_root == args.root},
        "tolerances": {"miou_points": MIOU_TOL_POINTS, "abs_rel_relative": ABSREL_TOL_REL},
    }
    report = make_report(
        TOOL,
        params,
        compared,
        meta=run_meta(str(device), command=command_line(["cosemdepth", "fast-accuracy", *sys.argv[2:]])),
    )
    write_report(args.out, report)
    record_output_file(args.out, "fast-accuracy")  # replaced by a later run only while unchanged
    ok = all_ok(compared["verdicts"].values())
    print(f"wrote {args.out}: {'every mode within' if ok else 'a mode outside'} the tolerances")
    return 0 if ok else 1
