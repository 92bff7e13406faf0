"""The fast streaming path of a model as an object of its own: :class:`FastModel`.

``FastModel(model, dtype=...)`` wraps a :class:`~cosemdepth.models.SceneModel` and streams with a
:class:`~cosemdepth.inference.engine.FastEngine` built from its weights: the same ``step`` and ``infer`` (arguments,
input checks, outputs, state) as the model's, which always runs its modules. It is what
:func:`~cosemdepth.checkpoints.model_io.load_model` returns unless asked for ``mode="reference"``.

The engine holds packed copies of the weights. It follows its model: after any change of the model's weights
(``load_state_dict``, an optimiser step, any in-place edit) or a move to another device, the next step rebuilds it,
so it never runs stale weights.
"""

from __future__ import annotations

from typing import Iterator, Optional, Sequence

import torch

from ..models.infer import infer_sequence
from ..models.model import SceneModel
from ..models.outputs import StepOutput, StreamState
from ..models.protocol import StreamingModel
from .engine import FastEngine


def weights_version(model: torch.nn.Module) -> tuple[int, ...]:
    """Changes whenever a parameter of ``model`` is modified in place (an optimiser step), replaced or moved."""
    return tuple(v for p in model.parameters() for v in (p.data_ptr(), p._version))


class FastModel:
    """The fast streaming path of ``model`` (a :class:`~cosemdepth.models.SceneModel`), on the model's device.

    Args:
        model: the model whose weights the engine packs; kept as :attr:`model` (its modules are the reference path).
        dtype: ``torch.float32`` / ``"fp32"`` (default: the modules' results up to float rounding, the setting the
            commands use), ``"bf16"`` (CPU with native bf16, or GPU) or ``"fp16"`` (GPU): the refiners' hidden
            convolutions in that precision, faster and less exact; ``"int8"`` (CPU): oneDNN int8 convolutions with
            statically calibrated activations (:mod:`cosemdepth.inference.int8`). Check the reduced precisions on
            your weights first (``cosemdepth fast-accuracy``).
        **options: further options of :class:`~cosemdepth.inference.engine.FastEngine` (``calibration``,
            ``calibration_frames``, ``float32_levels``, ``int8_keep_float``, ``int8_float_dtype``, ``use_mkldnn``,
            ``static``).

    It describes itself as its model does (:attr:`config`, :attr:`decoders`, :meth:`state_shapes`,
    :attr:`operating_point`, :meth:`parameters`) and never records gradients.
    """

    def __init__(self, model: SceneModel, dtype: torch.dtype | str = torch.float32, **options):
        if not isinstance(model, SceneModel):
            raise TypeError(f"FastModel needs a cosemdepth SceneModel, got {type(model).__name__}")
        if "device" in options:
            raise TypeError("FastModel runs on its model's device: move the model (model.to(device)) instead")
        self.model = model
        self.options = {"dtype": dtype, **options}
        self._engine = FastEngine(model, **self.options)
        self._weights = weights_version(model)

    @property
    def engine(self) -> FastEngine:
        """The engine, rebuilt first if the model's weights changed since it packed them."""
        version = weights_version(self.model)
        if version != self._weights:
            self._engine = FastEngine(self.model, **self.options)
            self._weights = version
        return self._engine

    # ------------------------------------------------------------------ what the model is
    @property
    def config(self):
        return self.model.config

    @property
    def decoders(self):
        return self.model.decoders

    @property
    def operating_point(self):
        """The model folder's :class:`~cosemdepth.operating_point.OperatingPoint` (set by ``load_model``), or None."""
        return getattr(self.model, "operating_point", None)

    @property
    def device(self) -> torch.device:
        return self.engine.device

    @property
    def dtype(self):
        """The compute precision: a torch dtype, or ``"int8"``."""
        return "int8" if self.engine.int8 else self.engine.dtype

    def state_shapes(self, batch: int, height: int, width: int) -> dict[str, list[tuple[int, ...]]]:
        return self.model.state_shapes(batch, height, width)

    def zero_state(self, batch: int, height: int, width: int) -> StreamState:
        return self.engine.zero_state(batch, height, width)

    def parameters(self) -> Iterator[torch.nn.Parameter]:
        """The model's parameters (what the engine packed)."""
        return self.model.parameters()

    def num_parameters(self) -> int:
        return self.model.num_parameters()

    # ------------------------------------------------------------------ streaming
    def step(
        self,
        rgb: torch.Tensor,
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
        state: Optional[StreamState] = None,
        decoders: Optional[Sequence[str]] = None,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> tuple[StepOutput, StreamState]:
        """The streaming step of :class:`~cosemdepth.models.protocol.StreamingModel` (the model's input checks,
        outputs and state; states of the two paths are interchangeable)."""
        self.model.check_step(rgb, rot, trans, intrinsics, reset, decoders, guide_depth)
        if decoders is not None and not decoders:  # nothing to run: the state passes through
            return StepOutput(), state if state is not None else StreamState()
        return self.engine.step(rgb, rot, trans, intrinsics, reset, state, decoders=decoders, guide_depth=guide_depth)

    @torch.no_grad()
    def infer(
        self,
        frames,
        motions,
        intrinsics,
        reset: Optional[torch.Tensor] = None,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> StepOutput:
        """A whole sequence, :meth:`StreamingModel.infer <cosemdepth.models.protocol.StreamingModel.infer>`: :meth:`step`
        in a loop."""
        return infer_sequence(
            self.step, frames, motions, intrinsics, reset, guide_depth, device=self.device, dtype=torch.float32
        )

    def __repr__(self) -> str:
        return f"FastModel({self.config.arch}, dtype={self.dtype}, device={self.device})"


def reference_model(model: StreamingModel) -> SceneModel:
    """The :class:`~cosemdepth.models.SceneModel` whose modules ``model`` runs: ``model`` itself, or the ``model`` of
    a wrapper (a :class:`FastModel`, an ONNX Runtime model, a :class:`~cosemdepth.inference.Streamer`), through
    every layer; a stand-in without either is returned as it is."""
    while not isinstance(model, SceneModel) and getattr(model, "model", None) is not None:
        model = model.model
    return model


__all__ = ["FastModel", "reference_model", "weights_version"]
