"""ONNX export of the streaming step with an explicit state.

The exported graph is one call of :meth:`SceneModel.step` in static mode (no data-dependent branch on the reset
mask): ONNX Runtime and TensorRT are stateless, so the per-level state goes in as inputs and comes back as outputs.

Inputs: ``rgb [B,3,H,W]`` float32 in [0, 1], ``rot [B,4]`` (w, x, y, z), ``trans [B,3]`` metres, ``intrinsics [B,4]``
(fx, fy, cx, cy) in pixels of H x W, ``reset [B]`` bool, then ``state_feat_{1..L} [B,C_l,h_l,w_l]`` and
``state_depth_{1..L} [B,1,h_l,w_l]`` (the flattened :class:`StreamState`; absent for M4Semantic), and for
Co-SemDepth-T ``state_semantic_{1..L} [B,N,h_l,w_l]`` (the previous probabilities, design 6.3).
Outputs: ``depth [B,1,H,W]`` metres (not for M4Semantic), ``semantic [B,N,H,W]`` probabilities (not for M4Depth),
then ``next_state_feat_{1..L}``, ``next_state_depth_{1..L}`` (and ``next_state_semantic_{1..L}``): feed them back
as the state of the next call. A model with ``semantic_time="gt"`` (it needs the ground-truth depth) is refused.

First frame: zeros for every state input with ``reset=True``. M4Semantic has no temporal input: its graph takes
``rgb`` only (the exporter drops inputs a graph does not use).
"""

from __future__ import annotations

import contextlib
import warnings
from pathlib import Path

import torch
import torch.nn as nn

from ..errors import ConfigError
from ..inference.fast_model import reference_model
from ..models.config import MIDAIR_IMAGE_SIZE
from ..models.model import SceneModel
from ..models.outputs import StreamState
from ..models.protocol import StreamingModel
from ..output_safety.atomic import atomic_path
from .provenance import ONNX_MARK, provenance, stamp

#: ONNX opset (``--opset``). ``MIN_OPSET``: torch's exporter writes the model's reshapes (``unflatten``) from opset
#: 13 on, and an int8 graph's per-channel QuantizeLinear/DequantizeLinear (an ``axis``) are opset 13 too.
DEFAULT_OPSET = 17
MIN_OPSET = 13
#: why ``MIN_OPSET`` (the ``--opset`` error says it)
MIN_OPSET_REASON = "the graph's reshapes and the int8 graph's per-channel quantisation are opset-13 operators"


def max_opset() -> int:
    """The newest ONNX opset the installed torch's (TorchScript-based) exporter writes."""
    from torch.onnx import _constants  # deferred: the exporter's own table

    return int(getattr(_constants, "ONNX_TORCHSCRIPT_EXPORTER_MAX_OPSET", _constants.ONNX_MAX_OPSET))


def state_names(levels: int, prefix: str = "state", components: tuple[str, ...] = ("feat", "depth")) -> list[str]:
    """``[prefix_feat_1, .., prefix_feat_L, prefix_depth_1, .., prefix_depth_L]`` (the order of StreamState.flatten)."""
    return [f"{prefix}_{c}_{l}" for c in components for l in range(1, levels + 1)]


def state_components(names) -> tuple[str, ...]:
    """The state components of a graph's state input names, in their order: ``state_feat_1`` -> ``feat``."""
    comps: list[str] = []
    for n in names:
        c = n[len("state_") :].rsplit("_", 1)[0]
        if c not in comps:
            comps.append(c)
    return tuple(comps)


def state_shapes(model: StreamingModel, batch: int, height: int, width: int) -> list[tuple[int, ...]]:
    """Shapes of the flattened state for a ``batch x 3 x height x width`` input (empty for M4Semantic)."""
    return [s for comp in model.state_shapes(batch, height, width).values() for s in comp]


class StreamingStep(nn.Module):
    """``forward(rgb, rot, trans, intrinsics, reset, *state) -> (depth?, semantic?, *next_state)``, a pure function of
    its inputs: :meth:`SceneModel.step` with the state flattened, in static mode."""

    def __init__(self, model: SceneModel, reset_float: bool = False):
        super().__init__()
        self.model = model
        self.reset_float = reset_float

    def forward(self, rgb, rot, trans, intrinsics, reset, *state):
        if self.reset_float:
            reset = reset > 0.5
        st = StreamState.unflatten(state, self._components()) if state else None
        out, new = self.model.step(rgb, rot, trans, intrinsics, reset, st)
        return (*out.heads.values(), *new.flatten())

    def _components(self) -> tuple[str, ...]:
        return tuple(n for dec in self.model.decoders.values() for n in dec.state_names)

    def names(self) -> tuple[list[str], list[str]]:
        """ONNX input and output names."""
        levels, comps = self.model.config.levels, self._components()
        inputs = ["rgb", "rot", "trans", "intrinsics", "reset", *state_names(levels, components=comps)]
        heads = [dec.head for dec in self.model.decoders.values()]
        return inputs, heads + state_names(levels, "next_state", comps)

    def example_inputs(self, batch: int, height: int, width: int, reset: bool = True) -> tuple[torch.Tensor, ...]:
        """A first-frame input: a mid-grey image, identity motion with 1 m forward, f = W/2, zero state."""
        p = next(self.model.parameters())
        kw = dict(device=p.device, dtype=torch.float32)
        rgb = torch.full((batch, 3, height, width), 0.5, **kw)
        rot = torch.tensor([1.0, 0.0, 0.0, 0.0], **kw).expand(batch, 4).contiguous()
        trans = torch.tensor([0.0, 0.0, 1.0], **kw).expand(batch, 3).contiguous()
        intr = torch.tensor([width / 2, height / 2, width / 2, height / 2], **kw).expand(batch, 4).contiguous()
        rst = torch.full((batch,), reset, dtype=torch.bool, device=p.device)
        if self.reset_float:
            rst = rst.float()
        state = [torch.zeros(s, **kw) for s in state_shapes(self.model, batch, height, width)]
        return (rgb, rot, trans, intr, rst, *state)


def export_onnx(
    model: StreamingModel,
    path: str | Path,
    height: int = MIDAIR_IMAGE_SIZE,
    width: int = MIDAIR_IMAGE_SIZE,
    batch: int = 1,
    opset: int = DEFAULT_OPSET,
    dynamic_batch: bool = False,
    reset_float: bool = False,
) -> Path:
    """Export ``model``'s streaming step to an ONNX file (written atomically).

    Args:
        model: a :class:`SceneModel` (exported in float32 on CPU; the model itself is left as it was), or a
            :class:`~cosemdepth.inference.FastModel`, whose model's modules are exported.
        path: output ``.onnx`` file.
        height, width: input resolution (fixed in the graph; the state shapes depend on it).
        batch: batch size of the example (fixed unless ``dynamic_batch``).
        opset: ONNX opset, at least :data:`MIN_OPSET`.
        dynamic_batch: mark the batch axis dynamic.
        reset_float: take ``reset`` as float32 (1 = reset) instead of bool, for runtimes without bool inputs.
    Returns:
        the path written; its metadata records what it was made from (:mod:`cosemdepth.export.provenance`).
    """
    model = reference_model(model)
    cfg = getattr(model, "config", None)
    if cfg is not None and cfg.needs_depth_input:
        raise ConfigError(
            f"the model's semantic decoder warps the previous labels with the ground-truth depth "
            f"(semantic_time {cfg.semantic_time!r}): a training- and evaluation-time variant that a "
            "deployed graph cannot feed, so it is not exported; Co-SemDepth-T (arch cosemdepth-t, "
            "semantic_time 'own') warps with its own depth and exports"
        )
    top = max_opset()
    if not MIN_OPSET <= opset <= top:
        raise ConfigError(
            f"--opset must be in [{MIN_OPSET}, {top}] ({MIN_OPSET_REASON}; {top} is the newest this torch "
            f"{torch.__version__} exports), got {opset}"
        )
    if height < 1 or width < 1 or batch < 1:
        raise ConfigError(f"--size and --batch must be positive, got size {height}x{width}, batch {batch}")
    path = Path(path)
    with _frozen_for_export(model):
        step = StreamingStep(model, reset_float=reset_float).eval()
        args = step.example_inputs(batch, height, width)
        in_names, out_names = step.names()
        dynamic_axes = {n: {0: "batch"} for n in in_names + out_names} if dynamic_batch else None
        record = provenance(model, height, width, batch, dynamic_batch, opset)
        with atomic_path(path) as tmp, torch.no_grad(), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # tracer warnings about Python shape arithmetic (constant here)
            torch.onnx.export(
                step,
                args,
                str(tmp),
                input_names=in_names,
                output_names=out_names,
                opset_version=opset,
                dynamic_axes=dynamic_axes,
                dynamo=False,
                do_constant_folding=True,
            )
            stamp(tmp, record)
    return path


def is_our_onnx(path: str | Path) -> bool:
    """True if ``path`` is an ONNX file that ``cosemdepth export`` wrote (its metadata has :data:`~cosemdepth.export.provenance.ONNX_MARK`)."""
    try:
        import onnx  # deferred: heavy; without it no file can be ours

        m = onnx.load(str(path), load_external_data=False)
    except Exception:  # noqa: BLE001 - anything unreadable is not ours
        return False
    return any(p.key == ONNX_MARK for p in m.metadata_props)


@contextlib.contextmanager
def _frozen_for_export(model: SceneModel):
    """Eval mode, static numerics, float32 on CPU; everything restored on exit."""
    p = next(model.parameters())
    device, dtype, training = p.device, p.dtype, model.training
    static = {name: dec.static for name, dec in model.decoders.items()}
    model.eval().float().cpu()
    model.set_numerics(static=True)
    try:
        yield
    finally:
        model.to(device=device, dtype=dtype).train(training)
        for name, dec in model.decoders.items():
            dec.static = static[name]
