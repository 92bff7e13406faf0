"""``cosemdepth benchmark``: streaming speed and peak memory of Co-SemDepth, M4Depth and M4Semantic.

Default run (a few minutes on a 2-core CPU): the three models at 384x384 on the fast path in fp32, bf16 and int8
(int8: CPU only, calibrated on synthetic frames before timing; fp32, fp16 and bf16 on CUDA), batch 1 streaming
(10 timed frames after 2 warm-up frames) and batched 8 and 32 (fewer timed steps: ``--batched-iters``), the fp32
reference path at batch 1 for comparison, and the joint-vs-separate comparison at batch 1. On CUDA every fast row also gets a CUDA-graph row (``path = graph``: static shapes, state in
persistent buffers, one graph replay per step). Writes JSON and Markdown.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

import torch

from ..bench.harness import SCHEMA, command_line, run_meta
from ..bench.noise import format_busy, format_spread, spread
from ..bench.report import markdown, write_report
from ..bench.runner import (
    BenchCase,
    _loadavg,
    cpu_busy_fraction,
    joint_vs_separate,
    run_case,
    run_separate,
    wait_for_idle,
)
from ..defaults import DEFAULT_DEVICE
from ..devices import bf16_convolutions, no_bf16_reason, resolve_device
from ..errors import ConfigError
from ..models import build_model
from ..models.config import ARCHITECTURES, ModelConfig
from ..models.footprint import check_size
from ..output_safety.outdir import check_output_file, model_inputs, record_output_file
from ._shared import DEFAULT_SIZE_PAIR, load_or_build, model_size_pair, parse_size_pair, positive_int

#: The report's ``tool`` (and the start of its ``meta.command``).
TOOL = "cosemdepth benchmark"
#: The defaults of one measurement (size, levels, classes, warm-up and timed frames at batch 1).
CASE = BenchCase()


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--models", nargs="+", choices=ARCHITECTURES, default=list(ARCHITECTURES))
    parser.add_argument("--model", metavar="DIR", help="time these weights (its architecture) instead of --models")
    parser.add_argument(
        "--size",
        nargs=2,
        type=int,
        metavar=("H", "W"),
        help="input size (default: the training size of --model, from its operating point; else {} {})".format(
            *DEFAULT_SIZE_PAIR
        ),
    )
    parser.add_argument(
        "--levels", type=int, default=CASE.levels, help=f"pyramid levels of the --models (default {CASE.levels})"
    )
    parser.add_argument("--batch", nargs="+", type=int, default=[1, 8, 32], help="batch sizes (default 1 8 32)")
    parser.add_argument(
        "--precision",
        nargs="+",
        choices=["fp32", "bf16", "fp16", "int8"],
        help="fast-path precisions (default: fp32 bf16 int8 on CPU, without bf16 on a CPU that has no bf16 "
        "convolutions, such as an AVX2-only one; fp32 fp16 bf16 on CUDA); int8 is CPU only "
        "(calibrated on synthetic frames before timing)",
    )
    parser.add_argument(
        "--backend",
        choices=["pytorch", "onnxruntime"],
        default="pytorch",
        help="pytorch (default pytorch: the fast path and the rows above) or onnxruntime: the model exported "
        "as by 'cosemdepth export --onnx' at --size and each --batch, run by ONNX Runtime's CPU "
        "provider with the state fed back (fp32; --threads intra-op threads)",
    )
    parser.add_argument(
        "--device",
        default=DEFAULT_DEVICE,
        help=f"cpu, cuda, cuda:N or auto (default {DEFAULT_DEVICE}: CUDA when present)",
    )
    parser.add_argument("--no-reference", action="store_true", help="skip the reference-path (fp32, batch 1) rows")
    parser.add_argument("--no-joint", action="store_true", help="skip the joint-vs-separate comparison")
    parser.add_argument("--no-graph", action="store_true", help="on CUDA, skip the CUDA-graph rows")
    parser.add_argument(
        "--warmup", type=int, default=CASE.warmup, help=f"warm-up frames at batch 1 (default {CASE.warmup})"
    )
    parser.add_argument("--iters", type=int, default=CASE.iters, help=f"timed frames at batch 1 (default {CASE.iters})")
    parser.add_argument("--batched-warmup", type=int, default=1, help="warm-up steps at batch > 1 (default 1)")
    parser.add_argument("--batched-iters", type=int, default=2, help="timed steps at batch > 1 (default 2)")
    parser.add_argument("--threads", type=positive_int, help="torch CPU threads (default: PyTorch's choice)")
    parser.add_argument(
        "--wait-idle",
        type=float,
        metavar="FRACTION",
        help="before each case wait until the whole machine is at most this busy (e.g. 0.1), for shared machines",
    )
    parser.add_argument("--wait-timeout", type=float, default=600, help="longest wait per case in seconds (600)")
    parser.add_argument("--json", metavar="FILE", default="benchmark.json", help="JSON output (default benchmark.json)")
    parser.add_argument("--md", metavar="FILE", default="benchmark.md", help="Markdown output (default benchmark.md)")


def _is_our_json(path) -> bool:
    """A benchmark report written by ``cosemdepth benchmark`` (replaced by a new run; anything else is kept)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return (
        isinstance(data, dict)
        and isinstance(data.get("meta"), dict)
        and str(data["meta"].get("command", "")).startswith(TOOL)
    )


def _is_our_md(path) -> bool:
    try:
        with open(path, encoding="utf-8") as f:
            first = f.readline()
    except (OSError, UnicodeDecodeError):
        return False
    return first.startswith("Measured ") and ", PyTorch " in first


def _run_onnxruntime(args, models, weights, case, idle, record) -> None:
    """Every architecture and batch as an exported graph run by ONNX Runtime (fp32, CPU provider)."""
    import tempfile

    from ..bench.runner import BenchResult, make_frames, time_stream
    from ..export.onnx import export_onnx
    from ..export.runtime import OnnxStep
    from ..optional import require

    require("onnx", "benchmark --backend onnxruntime")
    require("onnxruntime", "benchmark --backend onnxruntime")
    if args.device != "auto" and not str(args.device).startswith("cpu"):
        raise ConfigError(f"--backend onnxruntime runs on the CPU provider, not --device {args.device}")
    with tempfile.TemporaryDirectory(prefix="cosemdepth-bench-") as tmp:
        for arch in models:
            model = weights if weights is not None else None
            if model is None:
                torch.manual_seed(0)
                model = build_model(ModelConfig(arch=arch, levels=args.levels))
            for batch in args.batch:
                c = case(arch, batch, "fp32", "onnxruntime")
                c.device = "cpu"
                graph = export_onnx(model, Path(tmp) / f"{arch}-b{batch}.onnx", c.height, c.width, batch=batch)
                step = OnnxStep(graph, threads=args.threads, model=model)
                busy = idle()
                load = _loadavg()
                wall, cpu, others = time_stream([step.step], c, make_frames(c))
                res = BenchResult(c, model.num_parameters(), wall, cpu, mem_method="not measured", loadavg=load)
                res.others = others
                record(res, busy)


def run(args: argparse.Namespace) -> int:
    h, w = parse_size_pair(args.size)
    device = str(resolve_device(args.device))
    cuda = device.startswith("cuda")
    if args.threads:
        torch.set_num_threads(args.threads)
    for name, v in (("--iters", args.iters), ("--batched-iters", args.batched_iters)):
        if v < 1:
            raise ConfigError(f"{name} must be at least 1, got {v}")
    if any(b < 1 for b in args.batch):
        raise ConfigError(f"--batch values must be at least 1, got {args.batch}")
    for flag, path, ours in (("--json", args.json, _is_our_json), ("--md", args.md, _is_our_md)):
        if path:
            check_output_file(path, what=f"{flag} file", inputs=model_inputs(args.model), recognize=ours)
    bf16 = bf16_convolutions(device)
    precisions = args.precision or (
        ["fp32", "fp16", "bf16"] if cuda else ["fp32", "bf16", "int8"] if bf16 else ["fp32", "int8"]
    )
    if "bf16" in precisions and not bf16:
        raise ConfigError(f"--precision bf16: {no_bf16_reason()}: use fp32 or int8")
    if "fp16" in precisions and not cuda:
        raise ConfigError("--precision fp16 is for CUDA; on CPU use bf16")
    if "int8" in precisions and cuda:
        raise ConfigError(f"--precision int8 is for the CPU (oneDNN int8 convolutions), not {device}: use fp16 or bf16")

    weights = None
    models = args.models
    if args.model:
        weights = load_or_build(argparse.Namespace(model=args.model))
        models = [weights.config.arch]
        h, w = model_size_pair(args.size, weights, warn=False)
    for arch in models:  # every case's size and largest batch against the memory, before any case runs
        if weights is not None:
            shapes = weights
        else:
            with torch.device("meta"):
                shapes = build_model(ModelConfig(arch=arch, levels=args.levels))
        check_size(
            shapes,
            h,
            w,
            device=device,
            batch=max(args.batch),
            what="--size" if max(args.batch) == 1 else "--size/--batch",
        )

    def case(arch, batch, precision, path="fast"):
        big = batch > 1
        cfg = weights.config if weights is not None else None
        return BenchCase(
            arch=arch,
            batch=batch,
            height=h,
            width=w,
            device=device,
            precision=precision,
            path=path,
            warmup=args.batched_warmup if big else args.warmup,
            iters=args.batched_iters if big else args.iters,
            levels=cfg.levels if cfg else args.levels,
            num_classes=cfg.num_classes if cfg else CASE.num_classes,
        )

    params = {k: v for k, v in vars(args).items() if k not in ("command", "func") and not k.startswith("_")}
    params.update(size=[h, w], precision=precisions, models=models)
    report = {
        "tool": TOOL,
        "schema": SCHEMA,
        "meta": run_meta(device, command=command_line(["cosemdepth", "benchmark", *sys.argv[2:]])),
        "params": params,
        "results": [],
        "joint_vs_separate": [],
    }
    report["meta"]["resolution"] = [h, w]

    def idle():
        return (
            wait_for_idle(args.wait_idle, args.wait_timeout) if args.wait_idle is not None else cpu_busy_fraction(0.5)
        )

    def record(res, busy):
        res.busy_before = busy
        s = res.summary()
        report["results"].append(s)
        print(
            f"{s['arch']:>20} {s['device']:>6} {s['precision']:>5} {s['path']:>9} b={s['batch']:<3} "
            f"{format_spread(spread(res.ms_per_frame), 'ms/frame')} {s['fps']:.1f} FPS "
            f"peak {s['peak_mem_mb']:.0f} MB ({format_busy(busy)})",
            flush=True,
        )
        return res

    if args.backend == "onnxruntime":
        report["meta"]["backend"] = "onnxruntime"
        _run_onnxruntime(args, models, weights, case, idle, record)
        report["meta"]["loadavg_end"] = _loadavg()
        write_report(report, args.json, args.md)
        print(f"wrote {args.json} and {args.md}")
        return 0

    joint_precisions = []
    for arch in models:
        if not args.no_reference:
            busy = idle()
            record(run_case(case(arch, 1, "fp32", "reference"), weights), busy)
        for precision in precisions:
            for batch in args.batch:
                busy = idle()
                record(run_case(case(arch, batch, precision), weights), busy)
                if cuda and not args.no_graph:
                    busy = idle()
                    record(run_case(case(arch, batch, precision, "graph"), weights), busy)
                if arch == "cosemdepth" and batch == 1:
                    joint_precisions.append(precision)
    if not args.no_joint and weights is None and "cosemdepth" in models:
        for precision in joint_precisions:
            c = case("cosemdepth", 1, precision)
            # one unrecorded round of each first: one-time allocations (oneDNN kernels JIT-compiled and cached for
            # these shapes, thread pools) would otherwise be charged to whichever runs first
            run_case(BenchCase(**{**asdict(c), "warmup": 1, "iters": 1}))
            run_separate(BenchCase(**{**asdict(c), "warmup": 1, "iters": 1}))
            busy = idle()
            res = run_case(c)
            res.busy_before = busy
            busy = idle()
            sep = run_separate(c)
            report["joint_vs_separate"].append(joint_vs_separate(res, sep))
            res.case = BenchCase(**{**asdict(c), "path": "fast (joint-vs-separate run)"})
            sep.case = BenchCase(**{**asdict(sep.case), "path": "fast (joint-vs-separate run)"})
            record(res, res.busy_before)
            record(sep, busy)
    report["meta"]["loadavg_end"] = _loadavg()
    write_report(report, args.json, args.md)
    for path in (args.json, args.md):
        if path:
            record_output_file(path, "benchmark")  # replaced by a later run only while unchanged
    print(f"wrote {args.json} and {args.md}")
    if report["joint_vs_separate"]:
        print(markdown({**report, "results": []}).split("Joint vs separate", 1)[-1])
    return 0
