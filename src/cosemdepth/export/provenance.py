"""What an exported graph was made from, recorded in its ONNX metadata and checked by everything that runs it.

The export writes, as ``metadata_props`` of the ONNX model (all strings): the architecture, the model config (JSON),
a digest of the weights (:func:`weights_digest`), the input size and batch, the precision (``fp32``, or ``int8`` for
a quantised graph), the opset, the cosemdepth version, and a digest of the model as written (:func:`graph_digest`:
the graph with its initialisers, without the metadata). A consumer reads them back with :func:`read_provenance`,
which refuses a graph without them (an older export, or another tool's) and a graph whose digest no longer matches
(changed after export), and compares them with the PyTorch model it runs the graph for (:func:`check_model`): a
graph of another architecture, config or weights is refused in one line saying what differs.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Mapping

import torch

from .. import __version__
from ..errors import ConfigError
from ..inference.fast_model import reference_model
from ..models.protocol import StreamingModel
from ..optional import require

#: metadata key that marks an ONNX file written by ``cosemdepth export`` (its value: the cosemdepth version)
ONNX_MARK = "cosemdepth_export"
ARCH, CONFIG, WEIGHTS = "cosemdepth_arch", "cosemdepth_model_config", "cosemdepth_weights_sha256"
INPUT_SIZE, BATCH, PRECISION = "cosemdepth_input_size", "cosemdepth_batch", "cosemdepth_precision"
OPSET, GRAPH = "cosemdepth_opset", "cosemdepth_graph_sha256"
#: every key a consumer needs (the graph digest is added when the file is stamped)
KEYS = (ONNX_MARK, ARCH, CONFIG, WEIGHTS, INPUT_SIZE, BATCH, PRECISION, OPSET, GRAPH)
PRECISIONS = ("fp32", "int8")


def weights_digest(model: StreamingModel) -> str:
    """sha256 of ``model``'s state (a :class:`~cosemdepth.models.SceneModel`, or a FastModel's model) in a canonical
    order: for each entry of the state dict sorted by name, its name, dtype and shape, then its bytes, floating
    tensors as float32 (the values an fp32 graph holds) on the CPU."""
    h = hashlib.sha256()
    state = reference_model(model).state_dict()
    for name in sorted(state):
        t = state[name].detach().to("cpu")
        if t.is_floating_point():
            t = t.to(torch.float32)
        h.update(f"{name}\0{str(t.dtype).removeprefix('torch.')}\0{list(t.shape)}\0".encode())
        h.update(t.contiguous().numpy().tobytes())
    return h.hexdigest()


def graph_digest(proto) -> str:
    """sha256 of the ONNX ``proto`` (a ``ModelProto``) without its ``metadata_props``: graph, initialisers, opsets."""
    props = list(proto.metadata_props)
    del proto.metadata_props[:]
    try:
        return hashlib.sha256(proto.SerializeToString(deterministic=True)).hexdigest()
    finally:
        proto.metadata_props.extend(props)


def provenance(
    model: StreamingModel, height: int, width: int, batch: int, dynamic_batch: bool, opset: int
) -> dict[str, str]:
    """The metadata of an fp32 export of ``model`` (without the graph digest, which :func:`stamp` adds)."""
    cfg = reference_model(model).config
    return {
        ONNX_MARK: __version__,
        ARCH: cfg.arch,
        CONFIG: json.dumps(cfg.to_dict(), sort_keys=True),
        WEIGHTS: weights_digest(model),
        INPUT_SIZE: f"{height}x{width}",
        BATCH: "dynamic" if dynamic_batch else str(batch),
        PRECISION: "fp32",
        OPSET: str(opset),
    }


def stamp(path: str | Path, record: Mapping[str, str]) -> None:
    """Write ``record`` and the digest of the model as it is into the metadata of the ONNX file ``path`` (other
    metadata kept; ``record`` replaces keys of the same name)."""
    onnx = require("onnx", "writing an ONNX graph")
    m = onnx.load(str(path), load_external_data=False)
    props = {p.key: p.value for p in m.metadata_props}
    props.update(record)
    props[GRAPH] = graph_digest(m)
    onnx.helper.set_model_props(m, props)
    onnx.save(m, str(path))


def reexport_hint(path) -> str:
    return f"re-export it: cosemdepth export --onnx {path} --model MODEL"


def read_provenance(path: str | Path) -> dict[str, str]:
    """The provenance recorded in the ONNX file ``path``, after checking that it is complete and that the model is
    the one the export wrote; else a one-line :class:`ConfigError` naming the file."""
    onnx = require("onnx", "reading an ONNX graph's provenance")
    try:
        m = onnx.load_model_from_string(Path(path).read_bytes())
    except OSError as e:
        raise ConfigError(f"{path}: cannot read it: {e.strerror or e}") from None
    except Exception as e:  # noqa: BLE001 - protobuf's decode errors have no common public type
        raise ConfigError(
            f"{path}: not an ONNX model ({str(e).splitlines()[0] if str(e) else type(e).__name__})"
        ) from None
    props = {p.key: p.value for p in m.metadata_props}
    missing = [k for k in KEYS if k not in props]
    if missing:
        raise ConfigError(
            f"{path}: the graph records no provenance (the model, weights and precision it was made from: an export "
            f"by an older cosemdepth, or another tool's): {reexport_hint(path)}"
        )
    if graph_digest(m) != props[GRAPH]:
        raise ConfigError(
            f"{path}: the graph was changed after export (its digest is not the one recorded at export): "
            f"{reexport_hint(path)}"
        )
    if props[PRECISION] not in PRECISIONS:
        raise ConfigError(f"{path}: unknown precision {props[PRECISION]!r} in the graph's metadata")
    return props


def check_model(record: Mapping[str, str], model: StreamingModel, path, model_name: str = "the model") -> None:
    """Refuse (one-line :class:`ConfigError` naming ``path`` and what differs) a graph whose recorded provenance is
    not ``model``'s: another architecture, another config (the differing keys), or other weights."""
    cfg = reference_model(model).config
    where = f"{path}: not an export of {model_name}"
    if record[ARCH] != cfg.arch:
        raise ConfigError(f"{where}: architecture {record[ARCH]} in the graph, {cfg.arch} in the model")
    try:
        graph_cfg = json.loads(record[CONFIG])
    except ValueError:
        raise ConfigError(
            f"{path}: the model config in the graph's metadata is not JSON: {reexport_hint(path)}"
        ) from None
    mine = cfg.to_dict()
    keys = sorted(k for k in set(graph_cfg) | set(mine) if graph_cfg.get(k, "(none)") != mine.get(k, "(none)"))
    if keys:
        diff = ", ".join(
            f"{k} {graph_cfg.get(k, '(none)')!r} in the graph, {mine.get(k, '(none)')!r} in the model" for k in keys
        )
        raise ConfigError(f"{where}: its config differs from the model's: {diff}")
    digest = weights_digest(model)
    if record[WEIGHTS] != digest:
        raise ConfigError(
            f"{where}: other weights (sha256 {record[WEIGHTS][:12]}... in the graph, {digest[:12]}... in the model)"
        )


__all__ = [
    "ONNX_MARK",
    "PRECISIONS",
    "check_model",
    "graph_digest",
    "provenance",
    "read_provenance",
    "stamp",
    "weights_digest",
]
