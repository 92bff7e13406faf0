"""A TensorRT engine built from an exported streaming step, behind the ``step`` contract of :class:`SceneModel`.

:func:`build_engine` parses the ONNX graph of :func:`~cosemdepth.export.onnx.export_onnx` (exported with
``reset_float=True``: the reset mask as float32) and serialises an engine (fp16 kernels allowed with ``fp16``);
:class:`TrtStep` runs it on CUDA tensors with the state fed back, like :class:`~cosemdepth.export.runtime.OnnxStep`.
Needs the ``tensorrt`` package and a CUDA device.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import torch

from ..errors import ConfigError
from ..models.outputs import StepOutput, StreamState
from ..output_safety.atomic import atomic_path
from .onnx import state_components

#: Builder workspace (bytes).
WORKSPACE_BYTES = 4 << 30


def _trt():
    try:
        import tensorrt as trt  # deferred: optional, GPU machines only
    except ImportError:  # pragma: no cover - optional dependency
        raise ConfigError("a TensorRT engine needs the tensorrt package (pip install tensorrt)") from None
    return trt


def build_engine(onnx_path: str | Path, out: str | Path, fp16: bool = True) -> Path:
    """Parse ``onnx_path`` and write a serialised engine to ``out`` (atomically); returns ``out``."""
    trt = _trt()
    logger = trt.Logger(trt.Logger.WARNING)
    builder = trt.Builder(logger)
    flags = 0
    if hasattr(trt, "NetworkDefinitionCreationFlag") and hasattr(trt.NetworkDefinitionCreationFlag, "EXPLICIT_BATCH"):
        flags = 1 << int(trt.NetworkDefinitionCreationFlag.EXPLICIT_BATCH)  # TensorRT 8; the only mode from 10 on
    network = builder.create_network(flags)
    parser = trt.OnnxParser(network, logger)
    if not parser.parse_from_file(str(onnx_path)):
        errors = "; ".join(str(parser.get_error(i)) for i in range(parser.num_errors))
        raise ConfigError(f"{onnx_path}: TensorRT cannot parse it: {errors}")
    config = builder.create_builder_config()
    config.set_memory_pool_limit(trt.MemoryPoolType.WORKSPACE, WORKSPACE_BYTES)
    if fp16:
        config.set_flag(trt.BuilderFlag.FP16)
    blob = builder.build_serialized_network(network, config)
    if blob is None:
        raise ConfigError(f"{onnx_path}: TensorRT could not build an engine (see its log above)")
    out = Path(out)
    with atomic_path(out) as tmp:
        Path(tmp).write_bytes(bytes(blob))
    return out


class TrtStep:
    """``step(rgb, rot, trans, intrinsics, reset, state) -> (StepOutput, StreamState)`` over a serialised engine."""

    def __init__(self, engine_path: str | Path, device: str | torch.device = "cuda"):
        trt = _trt()
        self.device = torch.device(device)
        self._logger = trt.Logger(trt.Logger.WARNING)
        self.runtime = trt.Runtime(self._logger)
        self.engine = self.runtime.deserialize_cuda_engine(Path(engine_path).read_bytes())
        if self.engine is None:
            raise ConfigError(f"{engine_path}: not a TensorRT engine of this TensorRT version")
        self.context = self.engine.create_execution_context()
        types = {
            trt.DataType.FLOAT: torch.float32,
            trt.DataType.HALF: torch.float16,
            trt.DataType.BOOL: torch.bool,
            trt.DataType.INT32: torch.int32,
        }
        if hasattr(trt.DataType, "INT64"):
            types[trt.DataType.INT64] = torch.int64
        self.inputs: dict[str, torch.Tensor] = {}
        self.outputs: dict[str, torch.Tensor] = {}
        for i in range(self.engine.num_io_tensors):
            name = self.engine.get_tensor_name(i)
            buf = torch.zeros(
                tuple(self.engine.get_tensor_shape(name)),
                dtype=types[self.engine.get_tensor_dtype(name)],
                device=self.device,
            )
            is_input = self.engine.get_tensor_mode(name) == trt.TensorIOMode.INPUT
            (self.inputs if is_input else self.outputs)[name] = buf
            self.context.set_tensor_address(name, buf.data_ptr())
        self.state_inputs = [n for n in self.inputs if n.startswith("state_")]
        self.components = state_components(self.state_inputs)

    def step(
        self, rgb, rot, trans, intrinsics, reset: Optional[torch.Tensor] = None, state: Optional[StreamState] = None
    ):
        if reset is None:
            reset = torch.zeros(rgb.shape[0], dtype=torch.bool, device=rgb.device)
        given = {"rgb": rgb, "rot": rot, "trans": trans, "intrinsics": intrinsics, "reset": reset}
        for name, value in given.items():
            if name in self.inputs:
                self.inputs[name].copy_(value.to(self.inputs[name].dtype))
        flat = state.flatten() if state is not None else ()
        for name, value in zip(self.state_inputs, flat or [None] * len(self.state_inputs)):
            if value is None:
                self.inputs[name].zero_()
            else:
                self.inputs[name].copy_(value)
        stream = torch.cuda.current_stream(self.device)
        if not self.context.execute_async_v3(stream.cuda_stream):
            raise RuntimeError("TensorRT execution failed")
        heads = {k: v.float().clone() for k, v in self.outputs.items() if not k.startswith("next_")}
        nxt = [self.outputs["next_" + n].float().clone() for n in self.state_inputs]
        out = StepOutput(heads=heads)
        return out, (StreamState.unflatten(nxt, self.components) if nxt else StreamState())


__all__ = ["TrtStep", "build_engine"]
