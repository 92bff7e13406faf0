"""The model of a streaming command: which one, on which path and device (:class:`ModelOptions`), loaded once
(:func:`load_for`), and the input size it asks for (:func:`input_size`, :func:`warn_far_size`, :func:`check_run_size`)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import torch

from ..checkpoints.model_io import load_model, operating_point_of
from ..data.frames import FocalSize, as_size
from ..defaults import DEFAULT_DEVICE
from ..devices import resolve_device
from ..errors import CheckpointError, ConfigError
from ..inference.fast_model import FastModel, reference_model
from ..models.footprint import check_size
from ..models.protocol import StreamingModel
from ..operating_point import OperatingPoint
from ..output_safety.outdir import Input, model_inputs

#: ``--precision`` -> ``FastModel(model, dtype)``
PRECISION_DTYPES = {"fp32": "float32", "bf16": "bfloat16", "int8": "int8"}
#: The inference backends (``--backend``): the PyTorch paths, or an exported ONNX graph run by ONNX Runtime.
BACKENDS = ("pytorch", "onnxruntime")


@dataclass(frozen=True)
class ModelOptions:
    """The model of a streaming command, checked here once.

    Attributes:
        path: a model folder (config.json + model.safetensors) or an official TensorFlow checkpoint.
        reference: run the plain modules instead of the fast path (fp32 only).
        precision: the fast path's precision (:data:`PRECISION_DTYPES`).
        device: ``auto``, ``cpu``, ``cuda``, ``cuda:N`` or ``mps``; threads: CPU threads for torch (None: its choice).
        backend: ``pytorch`` or ``onnxruntime`` (the graph ``onnx``, fp32 on the CPU provider).
    """

    path: str | Path
    reference: bool = False
    precision: str = "fp32"
    device: str = DEFAULT_DEVICE
    threads: Optional[int] = None
    backend: str = "pytorch"
    onnx: Optional[Path] = None

    def __post_init__(self) -> None:
        if self.precision not in PRECISION_DTYPES:
            raise ConfigError(f"--precision must be one of {list(PRECISION_DTYPES)}, got {self.precision!r}")
        if self.backend not in BACKENDS:
            raise ConfigError(f"--backend must be one of {', '.join(BACKENDS)}, got {self.backend!r}")
        if self.threads is not None and (not isinstance(self.threads, int) or self.threads < 1):
            raise ConfigError(f"--threads must be a positive integer, got {self.threads!r}")
        if self.backend == "onnxruntime":
            if self.reference or self.precision != "fp32":
                raise ConfigError(
                    "--backend onnxruntime runs --onnx at the precision it was exported in: drop --reference / --precision"
                )
            if self.onnx is None:
                raise ConfigError(
                    "--backend onnxruntime needs --onnx FILE (a graph written by 'cosemdepth export --onnx')"
                )
            if self.device not in ("auto", "cpu"):
                raise ConfigError(f"--backend onnxruntime runs on the CPU provider, not --device {self.device}")
        elif self.onnx is not None:
            raise ConfigError("--onnx is the graph of --backend onnxruntime: add --backend onnxruntime")
        if self.reference and self.precision != "fp32":
            raise ConfigError(
                f"--precision {self.precision} is a setting of the fast path: drop --reference (which runs fp32)"
            )

    @property
    def path_name(self) -> str:
        """``predictions.json``'s ``run.path``: ``onnxruntime``, ``reference`` or ``fast``."""
        return "onnxruntime" if self.backend == "onnxruntime" else "reference" if self.reference else "fast"

    def inputs(self) -> list[Input]:
        """The paths the model reads (the output policy of :mod:`cosemdepth.output_safety.outdir`)."""
        return model_inputs(self.path)

    def apply_threads(self) -> None:
        """``torch.set_num_threads(threads)`` when given."""
        if self.threads:
            torch.set_num_threads(self.threads)

    def operating_point(self) -> OperatingPoint | None:
        """The model's operating point (read from its config.json, without the weights), or None: it has none, or
        its folder is unreadable (loading it reports that)."""
        return model_operating_point(self.path)


def model_operating_point(model_path) -> OperatingPoint | None:
    """The operating point of the model at ``model_path``, or None (see :meth:`ModelOptions.operating_point`)."""
    try:
        return operating_point_of(model_path)
    except (CheckpointError, OSError):
        return None


def load(model_path, device_name: str = DEFAULT_DEVICE, fast: bool = True, precision: str = "fp32"):
    """``(model, device)``: the model at ``model_path`` on the device named ``device_name``, in eval mode: a
    :class:`~cosemdepth.inference.FastModel` in ``precision`` (``--precision``), or with ``fast`` False
    (``--reference``) the :class:`~cosemdepth.models.SceneModel` (checked as :class:`ModelOptions`)."""
    return load_for(ModelOptions(model_path, reference=not fast, precision=precision, device=device_name))


def load_for(options: ModelOptions, frame_size: tuple[int, int] | None = None, lanes: int = 1):
    """``(model, device)`` of ``options``: the PyTorch paths (:func:`load`), or for ``backend="onnxruntime"`` the
    graph behind the model's ``step``, checked against the input's ``frame_size`` and ``lanes`` before any frame is
    read."""
    if options.backend == "onnxruntime":
        return _onnx_model(options, frame_size, lanes)
    device = resolve_device(options.device)
    model = load_model(options.path, device=device, mode="reference")
    if options.reference:
        return model, device
    try:
        return FastModel(model, PRECISION_DTYPES[options.precision]), device
    except ValueError as e:
        raise ConfigError(f"--precision {options.precision}: {e}") from None


def _onnx_model(options: ModelOptions, frame_size: tuple[int, int] | None, lanes: int):
    from ..export.runtime import OnnxModel, OnnxStep  # deferred: onnxruntime is optional
    from ..optional import require

    require("onnxruntime", "predict --backend onnxruntime")
    onnx = Path(options.onnx)
    if not onnx.is_file():
        raise ConfigError(f"--onnx {onnx}: no such file")
    model, _ = load(options.path, "cpu", fast=False)
    step = OnnxStep(onnx, threads=options.threads)
    onnx_model = OnnxModel(model, step, model_name=f"--model {options.path}")  # refuses a graph of another model
    want = (None, 3, *frame_size) if frame_size is not None else None
    got = step.shape
    if want is not None and tuple(got[1:]) != tuple(want[1:]):
        raise ConfigError(
            f"--onnx {onnx}: the graph takes {got[2]}x{got[3]} images, the input is read at "
            f"{want[2]}x{want[3]} (export at this size with --size, or give --size)"
        )
    if got[0] is not None and (got[0] != 1 or lanes != 1):
        raise ConfigError(
            f"--onnx {onnx}: the graph has a fixed batch of {got[0]}; streaming needs batch 1 "
            "(and --trajectories-per-batch 1) or a graph exported with --dynamic-batch"
        )
    return onnx_model, torch.device("cpu")


def input_size(requested, op: OperatingPoint | None):
    """The size to open an input at: ``requested`` (``--size``) when given; else, for a model with an operating
    point, the size rule of its focal length (:class:`~cosemdepth.data.frames.FocalSize`: every reader applies it
    to its camera, keeping the input's aspect ratio); else None (the reader's default)."""
    if requested is not None or op is None:
        return requested
    return FocalSize(op.focal)


def warn_far_size(
    op: OperatingPoint | None, requested, intrinsics, what: str = "--size", default_size=None
) -> str | None:
    """When the user's ``requested`` size puts the input's focal length (``intrinsics[0]``, at that size) more than
    :data:`~cosemdepth.operating_point.FOCAL_WARN_FACTOR` away from the model's, print one warning line on stderr
    naming both and ``default_size``, the size the input runs at without ``what`` (:func:`input_size`'s rule, as
    the input's reader opens it), and return it."""
    if op is None or requested is None or intrinsics is None:
        return None
    msg = op.size_warning(as_size(requested, what), float(intrinsics[0]), what, default_size=default_size)
    if msg:
        print(msg, file=sys.stderr)
    return msg


def check_run_size(
    model: StreamingModel, size: tuple[int, int] | None, device, batch: int = 1, trajectories: int | None = None
) -> None:
    """The size check of a streaming run (:func:`cosemdepth.models.footprint.check_size` at the input's frame
    ``size``, ``batch`` trajectories at once: at most one lane per trajectory), before the first frame is read."""
    if trajectories is not None:
        batch = max(min(batch, trajectories), 1)
    if size is not None:
        check_size(
            reference_model(model),
            *size,
            device=device,
            batch=batch,
            what="--size" if batch == 1 else "--size/--trajectories-per-batch",
        )


__all__ = [
    "BACKENDS",
    "ModelOptions",
    "PRECISION_DTYPES",
    "check_run_size",
    "input_size",
    "load",
    "load_for",
    "model_operating_point",
    "warn_far_size",
]
