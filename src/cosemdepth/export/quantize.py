"""int8 ONNX graphs: static QDQ quantisation of an exported float32 streaming step (``export --onnx OUT --int8``).

Which convolutions are int8 is the fast CPU path's policy (:data:`~cosemdepth.inference.engine.INT8_KEEP_FLOAT` and
:data:`~cosemdepth.inference.engine.FLOAT32_FROM_LEVEL`), read from the weights each ``Conv`` node takes: the hidden
convolutions of the refiners, except those the policy keeps float (the depth decoder's: the recurrent depth moves by
tens of percent of AbsRel when its refiners are quantised per tensor) and the last one of every refiner (it writes the
logits or the log-parallax). Everything else (the encoder, the cost volumes, the warps, the state) stays float32.

Quantisation: ONNX Runtime's static quantiser (``onnxruntime.quantization.quantize_static``) in the QDQ format, int8
weights per output channel (symmetric), uint8 activations per tensor with min/max ranges calibrated over a stream of
frames. The calibration stream runs through the float32 graph itself, its state fed back, so the state inputs see the
values a deployed stream feeds them. ONNX Runtime fuses each QuantizeLinear -> DequantizeLinear -> Conv ->
QuantizeLinear into one ``QLinearConv`` (VNNI / AMX-INT8 kernels where the CPU has them) and the LeakyReLU between
two of them into a ``QLinearLeakyRelu``.

The graph keeps the float32 graph's inputs, outputs and metadata: whatever runs the float32 graph runs this one.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Iterable, Optional, Sequence

import numpy as np

from ..errors import ConfigError
from ..inference.engine import FLOAT32_FROM_LEVEL, INT8_KEEP_FLOAT
from ..inference.fast_model import reference_model
from ..models.protocol import StreamingModel
from ..output_safety.atomic import atomic_path
from .provenance import PRECISION, stamp
from .runtime import OnnxStep

#: calibration frames ``export --int8`` streams by default
CALIBRATION_FRAMES = 16
#: a Conv weight of a refiner, as the exporter names it: ``model.<decoder module>.levels.<i>.refiner.convs.<k>.weight``
_REFINER_WEIGHT = re.compile(
    r"^(?:model\.)?(?P<module>\w+)\.levels\.(?P<index>\d+)\.refiner\.convs\.(?P<k>\d+)\.weight$"
)


def int8_weights(
    model: StreamingModel,
    keep_float: Optional[dict[str, tuple[int, ...]]] = None,
    float32_from_level: Optional[dict[str, int]] = None,
) -> set[str]:
    """The parameter names (``<decoder module>.levels.<i>.refiner.convs.<k>.weight``) of the convolutions the int8
    policy quantises in ``model``: every refiner's hidden convolutions (all but the last), less those of
    ``keep_float`` (per decoder name; default :data:`INT8_KEEP_FLOAT`) and the levels at or above
    ``float32_from_level`` (level 1 = finest; default :data:`FLOAT32_FROM_LEVEL`)."""
    model = reference_model(model)
    keep_float = INT8_KEEP_FLOAT if keep_float is None else keep_float
    float32_from_level = FLOAT32_FROM_LEVEL if float32_from_level is None else float32_from_level
    module_names = {id(m): n for n, m in model.named_children()}
    out: set[str] = set()
    for name, dec in model.decoders.items():
        module = module_names[id(dec)]
        first_float = float32_from_level.get(name)
        for i, lvl in enumerate(dec.levels):
            if first_float is not None and lvl.level >= first_float:
                continue
            hidden = len(lvl.refiner.convs) - 1
            for k in range(hidden):
                if k not in keep_float.get(name, ()):
                    out.add(f"{module}.levels.{i}.refiner.convs.{k}.weight")
    return out


def int8_nodes(graph, weights: set[str]) -> list[str]:
    """The names of the ``Conv`` nodes of the ONNX ``graph`` whose weight initialiser is one of ``weights``."""
    picked = []
    for node in graph.node:
        if node.op_type != "Conv" or len(node.input) < 2:
            continue
        m = _REFINER_WEIGHT.match(node.input[1])
        if m and f"{m['module']}.levels.{m['index']}.refiner.convs.{m['k']}.weight" in weights:
            picked.append(node.name)
    return picked


def calibration_feeds(step: OnnxStep, frames: Iterable[tuple]) -> list[dict[str, np.ndarray]]:
    """Every input of the float32 graph over a stream: ``frames`` are ``(rgb, rot, trans, intrinsics, reset)`` torch
    tensors of batch 1 (:func:`~cosemdepth.bench.accuracy.calibration_frames`), the state fed back as a stream."""
    feeds, state = [], None
    for frame in frames:
        f = step.frame_feeds(*frame)
        state = step.zero_state(f["rgb"].shape[0]) if state is None else state
        feeds.append(step.inputs(f, state))
        _, state = step.run(f, state)
    if not feeds:
        raise ConfigError("the int8 calibration stream is empty")
    return feeds


def _reader(feeds: Sequence[dict]):
    """The calibration reader ``quantize_static`` pulls the recorded inputs from."""
    from onnxruntime.quantization import CalibrationDataReader  # deferred: optional (cosemdepth[export])

    class Feeds(CalibrationDataReader):
        def __init__(self):
            self._it = iter(feeds)

        def get_next(self):
            return next(self._it, None)

    return Feeds()


def quantize_onnx(
    model: StreamingModel, src: str | Path, dst: str | Path, frames: Iterable[tuple], threads: Optional[int] = None
) -> Path:
    """Write ``dst``: the float32 graph ``src`` (exported from ``model`` by :func:`export_onnx`; refused otherwise)
    with the int8 policy's convolutions quantised, calibrated on ``frames`` (see :func:`calibration_feeds`). Written
    atomically; its metadata is ``src``'s with precision ``int8``.

    Returns:
        ``dst``.
    """
    import onnx  # deferred: optional (cosemdepth[export])
    from onnxruntime.quantization import quantize_static

    src, dst = Path(src), Path(dst)
    step = OnnxStep(src, threads=threads, model=model)
    if step.precision != "fp32":
        raise ConfigError(f"{src}: the graph is already {step.precision}; quantise the fp32 export")
    graph = onnx.load(str(src), load_external_data=False).graph
    nodes = int8_nodes(graph, int8_weights(model))
    if not nodes:
        raise ConfigError(f"{src}: the model has no convolution the int8 policy quantises (M4Depth keeps float)")
    feeds = calibration_feeds(step, frames)
    root = logging.getLogger()  # the quantiser logs advice (pre-processing) on the root logger: not for our users
    level = root.level
    root.setLevel(max(level, logging.ERROR))
    try:
        with atomic_path(dst) as tmp:
            _quantize(quantize_static, src, tmp, feeds, nodes)
            stamp(tmp, {**step.provenance, PRECISION: "int8"})
    finally:
        root.setLevel(level)
    return dst


def _quantize(quantize_static, src: Path, tmp: Path, feeds: list, nodes: list[str]) -> None:
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType

    quantize_static(
        str(src),
        str(tmp),
        _reader(feeds),
        quant_format=QuantFormat.QDQ,
        op_types_to_quantize=["Conv"],
        nodes_to_quantize=nodes,
        per_channel=True,
        activation_type=QuantType.QUInt8,
        weight_type=QuantType.QInt8,
        calibrate_method=CalibrationMethod.MinMax,
        extra_options={"ActivationSymmetric": False, "WeightSymmetric": True},
    )


def quantized_convolutions(path: str | Path) -> list[str]:
    """The weight names of the convolutions an int8 graph runs in int8 (those a DequantizeLinear feeds with weights)."""
    import onnx  # deferred: optional

    graph = onnx.load(str(path), load_external_data=False).graph
    weights = (n.input[0].removesuffix("_quantized") for n in graph.node if n.op_type == "DequantizeLinear")
    return sorted({w for w in weights if _REFINER_WEIGHT.match(w)})


__all__ = [
    "CALIBRATION_FRAMES",
    "calibration_feeds",
    "int8_nodes",
    "int8_weights",
    "quantize_onnx",
    "quantized_convolutions",
]
