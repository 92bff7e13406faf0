"""Arguments shared by the commands that run a model (evaluate, predict, view, demo, benchmark, export): how they are
declared and parsed. What the values mean and how they are checked belongs to the options they become
(:mod:`cosemdepth.jobs`, :mod:`cosemdepth.cli._options`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from ..checkpoints.model_io import load_model
from ..data.decode import DEFAULT_JPEG_IDCT, JPEG_IDCTS
from ..data.registry import DATASETS, split_datasets
from ..defaults import DEFAULT_DEVICE
from ..errors import ConfigError
from ..inference.policy import BASELINE, EVERY_FRAME, POLICIES
from ..jobs.model import PRECISION_DTYPES
from ..jobs.options import RunOptions
from ..models import build_model
from ..models.config import ARCHITECTURES, MIDAIR_IMAGE_SIZE, ModelConfig
from ..models.protocol import StreamingModel
from ..workers import WORKERS_PER_CORE

#: The model config's defaults (``--arch/--levels/--classes`` read them: one home for defaults).
MODEL_DEFAULTS = ModelConfig()
#: The streaming options' defaults (``--trajectories-per-batch``, ``--workers`` read them).
RUN_DEFAULTS = RunOptions()
#: ``--size H W`` when not given.
DEFAULT_SIZE_PAIR = (MIDAIR_IMAGE_SIZE, MIDAIR_IMAGE_SIZE)


def parse_size(text: str) -> int | tuple[int, int]:
    """``"384"`` -> 384; ``"720x1280"`` -> (720, 1280) (height x width)."""
    try:
        if "x" in text.lower():
            h, w = text.lower().split("x")
            size: int | tuple[int, int] = (int(h), int(w))
            vals = list(size)
        else:
            size = int(text)
            vals = [size]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected S or HxW in pixels, got {text!r}") from None
    if any(v < 8 for v in vals):
        raise argparse.ArgumentTypeError(f"sizes must be at least 8 pixels, got {text!r}")
    return size


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def add_model_args(parser: argparse.ArgumentParser, required: bool = True) -> None:
    parser.add_argument(
        "--model",
        required=required,
        metavar="MODEL",
        help="a model folder (config.json + model.safetensors) or an official TensorFlow checkpoint",
    )
    add_reference_arg(parser)
    add_precision_arg(parser)
    add_device_args(parser)


def add_reference_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--reference",
        action="store_true",
        help="run the plain PyTorch modules instead of the fast inference path (the default: fp32, "
        "the same results up to float rounding, faster: docs/benchmarks.md)",
    )


def add_precision_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--precision",
        choices=list(PRECISION_DTYPES),
        default="fp32",
        help="precision of the fast path's refiners: fp32 (default; the reference results up to float "
        "rounding), bf16, or int8 (CPU; oneDNN int8 convolutions in the semantic refiners, activation "
        "ranges calibrated on the first 8 frames, which run in fp32); check the accuracy of your "
        "weights with 'cosemdepth fast-accuracy' before using bf16 or int8",
    )


def add_model_or_arch_args(parser: argparse.ArgumentParser) -> None:
    """``--model``, or ``--arch/--levels/--classes`` for a freshly initialised model (speed, export tests)."""
    parser.add_argument(
        "--model",
        metavar="DIR",
        help="model folder (config.json + model.safetensors) or official TensorFlow checkpoint; "
        "default: a freshly initialised model of --arch (random weights: fine for speed, not for outputs)",
    )
    d = MODEL_DEFAULTS
    parser.add_argument(
        "--arch", choices=ARCHITECTURES, default=d.arch, help=f"architecture without --model (default {d.arch})"
    )
    parser.add_argument(
        "--levels", type=int, default=d.levels, help=f"pyramid levels without --model (default {d.levels})"
    )
    parser.add_argument(
        "--classes", type=int, default=d.num_classes, help=f"semantic classes without --model (default {d.num_classes})"
    )


def load_or_build(args: argparse.Namespace, device: str = "cpu"):
    """The model named by ``--model``, or a freshly initialised one from ``--arch/--levels/--classes``; eval mode, on
    the reference modules (export traces them; the benchmark selects its paths itself)."""
    if getattr(args, "model", None):
        return load_model(args.model, device=device, mode="reference")
    cfg = ModelConfig(arch=args.arch, levels=args.levels, num_classes=args.classes)
    return build_model(cfg).to(device).eval()


def model_size_pair(values: list[int] | None, model: StreamingModel, warn: bool = True) -> tuple[int, int]:
    """``--size H W`` of export / benchmark: as given, else the model's training size (its operating point), else
    :data:`DEFAULT_SIZE_PAIR`. With ``warn``, a given size far from the model's focal length (its camera's field of
    view assumed) gets a warning on stderr."""
    op = getattr(model, "operating_point", None)
    if values is None:
        return tuple(op.size) if op is not None else DEFAULT_SIZE_PAIR
    h, w = parse_size_pair(values)
    if warn and op is not None:  # without --size: the training size (above)
        msg = op.size_warning((h, w), op.focal * w / op.size[1], default_size=op.size)
        if msg:
            print(msg, file=sys.stderr)
    return h, w


def parse_size_pair(values: list[int] | None, default: tuple[int, int] = DEFAULT_SIZE_PAIR) -> tuple[int, int]:
    """``--size H W`` (nargs=2) -> ``(H, W)``."""
    if values is None:
        return default
    h, w = values
    if h < 8 or w < 8:
        raise ConfigError(f"--size must be at least 8 8, got {h} {w}")
    return h, w


def add_device_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--device",
        default=DEFAULT_DEVICE,
        help=f"{DEFAULT_DEVICE} (the default: CUDA when available, else the CPU), cpu, cuda, cuda:N or mps",
    )
    parser.add_argument(
        "--threads",
        type=positive_int,
        default=None,
        metavar="N",
        help="CPU threads for torch (default: torch's choice, usually the number of cores)",
    )


def apply_threads(args: argparse.Namespace) -> None:
    """``torch.set_num_threads(args.threads)`` when given."""
    if getattr(args, "threads", None):
        torch.set_num_threads(args.threads)


def add_split_args(parser: argparse.ArgumentParser, required: bool = True) -> None:
    """``--dataset/--root/--split-dir/--split``; the dataset choices are the registered datasets with split files
    (:func:`cosemdepth.data.registry.split_datasets`, read when the parser is built; flights are opened by
    ``predict --flight``)."""
    names = split_datasets()
    parser.add_argument(
        "--dataset", choices=names, required=required, metavar="NAME", help=f"dataset: {', '.join(names)}"
    )
    parser.add_argument("--root", type=Path, required=required, metavar="ROOT", help="dataset root folder")
    required_for = [n for n in names if DATASETS[n].needs_split_dir]
    folders = [f"ROOT/{DATASETS[n].split_dir} for {n}" for n in names if DATASETS[n].split_dir is not None]
    parser.add_argument(
        "--split-dir",
        type=Path,
        default=None,
        metavar="D",
        help="folder of the split files ("
        + "; ".join(
            [
                *(["required for " + ", ".join(required_for)] if required_for else []),
                *(["default " + ", ".join(folders)] if folders else []),
            ]
        )
        + ")",
    )
    defaults = ", ".join(f"{name} {DATASETS[name].split}" for name in names)
    parser.add_argument("--split", default=None, help=f"split to use (default: {defaults})")


#: What the commands that run a model on an input with a camera do without --size.
MODEL_SIZE_RULE = (
    "the size at which the input's focal length in pixels is the model's (its operating point in "
    "config.json), with the input's aspect ratio"
)


def size_help(what: str = "network input size, S or HxW") -> str:
    """``--size`` help: the model's focal length by default, else each split dataset's default size (from the
    dataset table)."""
    sizes: dict[str, list[str]] = {}
    for name in split_datasets():
        size = DATASETS[name].size
        sizes.setdefault("native" if size is None else str(size), []).append(name)
    return (
        f"{what} (default: {MODEL_SIZE_RULE}; for a model without one: "
        + "; ".join(f"{v} for {', '.join(n)}" for v, n in sizes.items())
        + ")"
    )


def add_policy_args(parser: argparse.ArgumentParser, default: str) -> None:
    """``--policy`` and ``--min-baseline`` (:mod:`cosemdepth.inference.policy`); ``default`` describes the default in
    the help (the flag's value stays None: :func:`stream_policy` resolves it per input)."""
    g = parser.add_argument_group("streaming policy (docs/motion.md)")
    g.add_argument(
        "--policy",
        choices=POLICIES,
        default=None,
        help=f"which frame a depth is estimated against: {BASELINE} (a reference frame the camera has moved "
        f"far enough from; frames closer to it carry its depth, status held) or {EVERY_FRAME} (the "
        f"previous frame, the paper's protocol); default: {default}",
    )
    g.add_argument(
        "--min-baseline",
        type=float,
        default=None,
        metavar="M",
        help=f"metres the camera must move from the reference frame before a frame is estimated "
        f"(--policy {BASELINE}; default: 0.75 x the 5th percentile of the per-step translations the model "
        "was trained with, from its folder)",
    )


def add_run_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--max-frames",
        type=positive_int,
        default=None,
        metavar="N",
        help="only the first N frames of the split (in order)",
    )
    parser.add_argument(
        "--trajectories-per-batch",
        type=positive_int,
        default=RUN_DEFAULTS.lanes,
        metavar="B",
        dest="lanes",
        help=f"stream B trajectories at once as one batch, with per-sample resets (default {RUN_DEFAULTS.lanes}, as "
        "the original)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=RUN_DEFAULTS.workers,
        metavar="N",
        help=f"data-loading worker processes (default {RUN_DEFAULTS.workers}: in the main process; at most "
        f"{WORKERS_PER_CORE} per CPU core)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_jpeg_idct_arg(parser)


def add_jpeg_idct_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--jpeg-idct",
        choices=JPEG_IDCTS,
        default=DEFAULT_JPEG_IDCT,
        help=f"JPEG decoding (default {DEFAULT_JPEG_IDCT}): fast (libjpeg-turbo's fast integer IDCT, "
        "bit-exact with the original's tf.io.decode_jpeg) or accurate (the accurate integer IDCT, as "
        "Pillow)",
    )


__all__ = [
    "add_device_args",
    "add_model_args",
    "add_model_or_arch_args",
    "add_precision_arg",
    "add_reference_arg",
    "add_jpeg_idct_arg",
    "add_policy_args",
    "add_run_args",
    "add_split_args",
    "apply_threads",
    "load_or_build",
    "model_size_pair",
    "parse_size",
    "parse_size_pair",
    "positive_int",
]
