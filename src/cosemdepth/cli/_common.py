"""Helpers shared by the inference commands (benchmark, export): getting a model from the command line."""

from __future__ import annotations

import argparse

from ..config import ARCHITECTURES, ModelConfig
from ..errors import CheckpointError, ConfigError


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model",
        metavar="DIR",
        help="model folder (config.json + model.safetensors) or official TensorFlow checkpoint; "
        "default: a freshly initialised model of --arch (random weights: fine for speed, not for outputs)",
    )
    parser.add_argument("--arch", choices=ARCHITECTURES, default="cosemdepth", help="architecture without --model")
    parser.add_argument("--levels", type=int, default=5, help="pyramid levels without --model (default 5)")
    parser.add_argument("--classes", type=int, default=7, help="semantic classes without --model (default 7)")


def load_or_build(args: argparse.Namespace, device: str = "cpu"):
    """The model named by ``--model``, or a freshly initialised one from ``--arch/--levels/--classes``."""
    from ..models import build_model

    if getattr(args, "model", None):
        try:
            from ..io.model_io import load_model
        except ImportError as e:  # the model-folder reader ships with the converter
            raise CheckpointError(
                f"--model {args.model}: this installation has no model-folder reader (cosemdepth.io.model_io): {e}"
            ) from e
        return load_model(args.model, device=device).eval()
    cfg = ModelConfig(arch=args.arch, levels=args.levels, num_classes=args.classes)
    return build_model(cfg).to(device).eval()


def parse_size(values: list[int] | None, default: tuple[int, int] = (384, 384)) -> tuple[int, int]:
    if values is None:
        return default
    h, w = values
    if h < 8 or w < 8:
        raise ConfigError(f"--size must be at least 8 8, got {h} {w}")
    return h, w
