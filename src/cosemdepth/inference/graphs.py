"""Streaming with static buffers, replayed as a CUDA graph on GPU.

A streaming step has fixed shapes once the batch size and resolution are fixed, and with a static engine
(``FastEngine(static=True)``: no branch on the reset values) its whole computation can be captured once and replayed:
one launch per frame instead of hundreds. The state lives in fixed buffers: the captured program reads them, computes
the frame, then copies the new state into them, so nothing but the inputs has to be copied per frame.

:class:`StaticStreamer` implements that program. On CUDA it captures a :class:`torch.cuda.CUDAGraph`; elsewhere (or
with ``use_graph=False``) it runs the very same static-buffer program eagerly, which is what the CPU tests check.
"""

from __future__ import annotations

from typing import Optional

import torch

from ..models.model import SceneModel
from ..models.outputs import StepOutput, StreamState
from .engine import FastEngine


class StaticStreamer:
    """Stream frames of a fixed ``batch x 3 x height x width`` through a static engine with persistent buffers.

    Args:
        engine: a :class:`~cosemdepth.inference.FastEngine` built with ``static=True``.
        batch, height, width: the fixed input shape.
        use_graph: capture a CUDA graph (default: when the engine is on CUDA).
        warmup: eager iterations before capture (cuDNN autotuning, allocator warm-up).
    Call :meth:`step` with one frame per sample and a reset mask; the first call must reset every sample (the state
    buffers start as zeros). Outputs are views of static buffers, overwritten by the next call: clone them to keep.
    """

    def __init__(
        self, engine: FastEngine, batch: int, height: int, width: int, use_graph: Optional[bool] = None, warmup: int = 3
    ):
        if not engine.static:
            raise ValueError("StaticStreamer needs an engine built with static=True")
        dev = engine.device
        self.engine = engine
        self.shape = (batch, 3, height, width)
        self.use_graph = (dev.type == "cuda") if use_graph is None else use_graph
        if self.use_graph and dev.type != "cuda":
            raise ValueError("CUDA graphs need a CUDA engine")
        f32 = dict(device=dev, dtype=torch.float32)
        self.rgb = torch.zeros(self.shape, **f32)
        self.rot = torch.tensor([1.0, 0.0, 0.0, 0.0], **f32).repeat(batch, 1)
        self.trans = torch.zeros(batch, 3, **f32)
        self.intrinsics = torch.tensor([width / 2, height / 2, width / 2, height / 2], **f32).repeat(batch, 1)
        self.reset = torch.ones(batch, dtype=torch.bool, device=dev)
        self.state = engine.zero_state(batch, height, width)
        self._out: Optional[StepOutput] = None
        self._started = False
        self.graph = None
        if self.use_graph:
            self._capture(warmup)

    # ------------------------------------------------------------------ the static program
    def _program(self) -> StepOutput:
        """Read the input and state buffers, compute one frame, write the new state into the state buffers."""
        out, new = self.engine.step(self.rgb, self.rot, self.trans, self.intrinsics, self.reset, self.state)
        for buf, val in zip(self.state.flatten(), new.flatten()):
            buf.copy_(val)
        return out

    def _capture(self, warmup: int) -> None:  # pragma: no cover - needs a GPU
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            for _ in range(warmup):
                self._program()
        torch.cuda.current_stream().wait_stream(side)
        self._zero_state()
        self.graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(self.graph):
            self._out = self._program()
        self._zero_state()

    def _zero_state(self) -> None:
        for buf in self.state.flatten():
            buf.zero_()

    # ------------------------------------------------------------------ public
    @torch.inference_mode()
    def step(
        self,
        rgb: torch.Tensor,
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
    ) -> StepOutput:
        """One frame per sample: the streaming step of :class:`~cosemdepth.models.protocol.StreamingModel` without
        ``state`` (it lives in the static buffers; :meth:`current_state`), ``decoders`` or ``guide_depth``; batch and
        size as given at construction. Returns the outputs only."""
        if tuple(rgb.shape) != self.shape:
            raise ValueError(
                f"argument rgb must have shape {list(self.shape)} (fixed at construction), got {list(rgb.shape)}"
            )
        if reset is None:
            reset = torch.zeros(self.shape[0], dtype=torch.bool)
        if not self._started and not bool(reset.all()):
            raise ValueError("the first frame must reset every sample (reset=True): the state starts empty")
        self._started = True
        self.rgb.copy_(rgb)
        self.rot.copy_(rot)
        self.trans.copy_(trans)
        self.intrinsics.copy_(intrinsics)
        self.reset.copy_(reset)
        if self.graph is not None:  # pragma: no cover - needs a GPU
            self.graph.replay()
            return self._out
        return self._program()

    def current_state(self) -> StreamState:
        """The state buffers (after the last call): a copy, safe to keep."""
        return StreamState(**{k: tuple(t.clone() for t in v) for k, v in self.state.components.items()})


def make_streamer(
    model: SceneModel, batch: int, height: int, width: int, dtype=torch.float32, device=None, **kw
) -> StaticStreamer:
    """A :class:`StaticStreamer` over a static :class:`FastEngine` of ``model`` (CUDA graph on GPU)."""
    engine = FastEngine(model, dtype=dtype, device=device, static=True)
    return StaticStreamer(engine, batch, height, width, **kw)
