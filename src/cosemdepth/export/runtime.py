"""An exported streaming step run by ONNX Runtime behind the ``step`` contract of :class:`SceneModel`.

:class:`OnnxStep` wraps an ``InferenceSession`` of a graph written by :func:`~cosemdepth.export.onnx.export_onnx`:
``step(rgb, rot, trans, intrinsics, reset, state) -> (StepOutput, StreamState)`` with torch tensors in and out, the
state fed back as the graph's ``state_*`` inputs (zeros when ``state`` is None). What the graph does not compute
(the per-pixel validity, the per-sample status) is left empty in the :class:`StepOutput`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterator, Optional, Sequence

import numpy as np
import torch

from ..errors import ConfigError
from ..models.config import ModelConfig
from ..models.infer import infer_sequence
from ..models.model import SceneModel
from ..models.outputs import StepOutput, StreamState
from ..models.protocol import StreamingModel
from ..operating_point import OperatingPoint
from .onnx import state_components
from .provenance import PRECISION, check_model, read_provenance


def _session_options(threads: Optional[int], profile_prefix: Optional[str]):
    import onnxruntime as ort  # deferred: an optional dependency (cosemdepth[export])

    so = ort.SessionOptions()
    if threads:
        so.intra_op_num_threads = threads
        so.inter_op_num_threads = 1
    if profile_prefix:
        so.enable_profiling = True
        so.profile_file_prefix = profile_prefix
    return so


class OnnxStep:
    """``step`` over an exported ONNX streaming step (see the module docstring).

    Args:
        path: the ``.onnx`` file.
        providers: ONNX Runtime execution providers in order of preference (default: the CPU one), each a name or a
            ``(name, options)`` pair as ``InferenceSession`` takes them.
        threads: intra-op threads (default: ONNX Runtime's choice).
        profile_prefix: write ONNX Runtime's per-node profile (JSON) with this file prefix (:meth:`end_profiling`).
        model: the PyTorch model the graph must have been exported from (:meth:`check_model`), if given.
        provenance: False: run the graph whatever its metadata records (timing an older export side by side,
            ``benchmarks/infer_vs_original.py``); :attr:`provenance` and :attr:`precision` are then None.

    A graph without the provenance an export records, or changed since, is refused
    (:func:`~cosemdepth.export.provenance.read_provenance`); :attr:`provenance` holds it, :attr:`precision` is
    ``fp32`` or ``int8``.
    """

    def __init__(
        self,
        path: str | Path,
        providers: Optional[Sequence] = None,
        threads: Optional[int] = None,
        profile_prefix: Optional[str] = None,
        model: Optional[StreamingModel] = None,
        provenance: bool = True,
    ):
        try:
            import onnxruntime as ort  # deferred: an optional dependency (cosemdepth[export])
        except ImportError:  # pragma: no cover - optional dependency
            raise ConfigError("running an ONNX graph needs onnxruntime (pip install 'cosemdepth[export]')") from None
        self.path = Path(path)
        self.provenance = read_provenance(self.path) if provenance or model is not None else None
        self.precision = None if self.provenance is None else self.provenance[PRECISION]
        if model is not None:
            self.check_model(model)
        try:
            self.session = ort.InferenceSession(
                str(self.path),
                _session_options(threads, profile_prefix),
                providers=list(providers or ["CPUExecutionProvider"]),
            )
        except Exception as e:  # noqa: BLE001 - ONNX Runtime raises its own exception types for unreadable graphs
            raise ConfigError(f"{self.path}: ONNX Runtime cannot load it: {str(e).splitlines()[0]}") from None
        ins = self.session.get_inputs()
        self.input_names = [i.name for i in ins]
        self.state_inputs = [i.name for i in ins if i.name.startswith("state_")]
        self.output_names = [o.name for o in self.session.get_outputs()]
        self.reset_float = any(i.name == "reset" and i.type == "tensor(float)" for i in ins)
        shape = ins[0].shape
        self.shape = tuple(d if isinstance(d, int) else None for d in shape)  # [B, 3, H, W]; None: dynamic axis
        self._state_shapes = [tuple(i.shape) for i in ins if i.name.startswith("state_")]
        self.components = state_components(self.state_inputs)

    def check_model(self, model: StreamingModel, model_name: str = "the model") -> None:
        """Refuse, in one line naming the file and what differs, a graph not exported from ``model`` (its
        architecture, config and weights; :func:`~cosemdepth.export.provenance.check_model`)."""
        if self.provenance is None:  # opened without it: a model's graph must have it all the same
            self.provenance = read_provenance(self.path)
            self.precision = self.provenance[PRECISION]
        check_model(self.provenance, model, self.path, model_name)

    @property
    def providers(self) -> list[str]:
        """The execution providers the session actually uses."""
        return list(self.session.get_providers())

    def zero_state(self, batch: int) -> list[np.ndarray]:
        return [np.zeros([d if isinstance(d, int) else batch for d in s], np.float32) for s in self._state_shapes]

    def inputs(self, feeds: dict[str, np.ndarray], state: Sequence[np.ndarray]) -> dict[str, np.ndarray]:
        """Every input of one call: the graph's own of ``feeds`` (M4Semantic's takes the image only), ``reset`` as
        the graph takes it, and ``state`` as the ``state_*`` inputs."""
        full = {k: v for k, v in feeds.items() if k in self.input_names}
        if self.reset_float and "reset" in full:
            full["reset"] = full["reset"].astype(np.float32)
        full.update(zip(self.state_inputs, state))
        return full

    def run(
        self, feeds: dict[str, np.ndarray], state: Sequence[np.ndarray]
    ) -> tuple[dict[str, np.ndarray], list[np.ndarray]]:
        """One call on numpy arrays: ``(outputs by name, next state)``."""
        res = dict(zip(self.output_names, self.session.run(None, self.inputs(feeds, state))))
        return res, [res["next_" + n] for n in self.state_inputs]

    @staticmethod
    def frame_feeds(rgb, rot, trans, intrinsics, reset) -> dict[str, np.ndarray]:
        """The per-frame inputs of a call from torch tensors (float32 on the CPU; ``reset`` bool)."""
        f32 = lambda t: t.detach().to("cpu", torch.float32).contiguous().numpy()  # noqa: E731
        return {
            "rgb": f32(rgb),
            "rot": f32(rot),
            "trans": f32(trans),
            "intrinsics": f32(intrinsics),
            "reset": reset.detach().cpu().bool().numpy(),
        }

    def step(
        self,
        rgb: torch.Tensor,
        rot: torch.Tensor,
        trans: torch.Tensor,
        intrinsics: torch.Tensor,
        reset: Optional[torch.Tensor] = None,
        state: Optional[StreamState] = None,
    ):
        """The streaming step of :class:`~cosemdepth.models.protocol.StreamingModel` on numpy's side of the graph
        (``decoders`` and ``guide_depth`` are :class:`OnnxModel`'s); returns ``(StepOutput, StreamState)``."""
        b = int(rgb.shape[0])
        want = tuple(s if s is not None else d for s, d in zip(self.shape, rgb.shape))
        if tuple(rgb.shape) != want:
            raise ConfigError(f"{self.path}: the graph takes images of shape {list(want)}, got {list(rgb.shape)}")
        if reset is None:
            reset = torch.zeros(b, dtype=torch.bool)
        feeds = self.frame_feeds(rgb, rot, trans, intrinsics, reset)
        st = (
            [t.detach().to("cpu", torch.float32).contiguous().numpy() for t in state.flatten()]
            if state is not None and state.flatten()
            else self.zero_state(b)
        )
        res, nxt = self.run(feeds, st)
        dev = rgb.device
        heads = {k: torch.from_numpy(v).to(dev) for k, v in res.items() if not k.startswith("next_")}
        out = StepOutput(heads=heads)
        new = (
            StreamState.unflatten([torch.from_numpy(s).to(dev) for s in nxt], self.components) if nxt else StreamState()
        )
        return out, new

    def end_profiling(self) -> str:
        """Stop profiling; the path of the profile ONNX Runtime wrote."""
        return self.session.end_profiling()


class OnnxModel:
    """A loaded model whose ``step`` runs an exported graph of it in ONNX Runtime: what the inference commands drive
    (``predict --backend onnxruntime``) in place of the PyTorch model. The model supplies what the graph does not
    hold (its config, operating point and parameters' device); the graph computes every decoder on each call, and
    a call asked for a subset of ``decoders`` returns the state of the others as it came in, like
    :meth:`SceneModel.step`.

    Args:
        model: the PyTorch model the graph was exported from (its config and operating point are read; its modules
            are the reference path, :attr:`model`); a graph exported from another architecture, config or weights is
            refused (:meth:`OnnxStep.check_model`).
        step: an :class:`OnnxStep` over the graph.
        model_name: how error messages name ``model`` (e.g. ``"--model weights/x"``).
    """

    def __init__(self, model: SceneModel, step: OnnxStep, model_name: str = "the model"):
        step.check_model(model, model_name)
        self.model = model
        self.onnx = step
        # the state components each decoder owns (the components of a graph's state are those of the model's)
        self._owned = {name: tuple(dec.state_shapes(1, 32, 32)) for name, dec in model.decoders.items()}

    # ------------------------------------------------------------------ what the model is
    @property
    def config(self) -> ModelConfig:
        return self.model.config

    @property
    def decoders(self) -> dict:
        return self.model.decoders

    @property
    def operating_point(self) -> Optional[OperatingPoint]:
        return self.model.operating_point

    def parameters(self) -> Iterator[torch.nn.Parameter]:
        """The model's parameters (on the CPU, where the graph runs)."""
        return self.model.parameters()

    def num_parameters(self) -> int:
        return self.model.num_parameters()

    def state_shapes(self, batch: int, height: int, width: int) -> dict[str, list[tuple[int, ...]]]:
        return self.model.state_shapes(batch, height, width)

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
        """The streaming step of :class:`~cosemdepth.models.protocol.StreamingModel` by the graph (which computes
        every decoder; a call asked for a subset returns the others' state as it came in; a model that reads a
        ground-truth depth cannot be exported, so ``guide_depth`` is refused)."""
        if guide_depth is not None:
            raise ValueError("argument guide_depth: an exported graph takes no ground-truth depth")
        out, new = self.onnx.step(rgb, rot, trans, intrinsics, reset, state)
        if decoders is None or state is None or not state.flatten():
            return out, new
        keep = {c for name in self._owned if name not in decoders for c in self._owned.get(name, ())}
        comps = {
            k: (state.components[k] if k in keep and k in state.components else v) for k, v in new.components.items()
        }
        return out, StreamState(**comps)

    @torch.no_grad()
    def infer(
        self,
        frames,
        motions,
        intrinsics,
        reset: Optional[torch.Tensor] = None,
        guide_depth: Optional[torch.Tensor] = None,
    ) -> StepOutput:
        """A whole sequence, :meth:`StreamingModel.infer <cosemdepth.models.protocol.StreamingModel.infer>`: the
        graph in a loop."""
        return infer_sequence(
            self.step, frames, motions, intrinsics, reset, guide_depth, device=torch.device("cpu"), dtype=torch.float32
        )


__all__ = ["OnnxModel", "OnnxStep"]
