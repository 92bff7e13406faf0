"""Convert the weights of an official TensorFlow checkpoint (Co-SemDepth, M4Depth, M4Semantic) to ours.

Key map (design section 13.1; ``<enc>``, ``<dec>`` are whatever root attribute names the model used,
e.g. ``encoder``, ``d_estimator``, ``s_estimator``; keys are matched by pattern below the root)::

    <enc>/conv_layers_s{1,2}/{k}/kernel|bias                    -> encoder.conv_s{1,2}.{k}.weight|bias
    <enc>/dn_layers/0/scale|bias                                -> encoder.dinl.weight|bias
    <dec>/levels/{j}/disp_refiner/prep_conv_layers/{k}/...      -> depth_decoder.levels.{j}.refiner.convs.{k}...
    <dec>/levels/{j}/disp_refiner/est_d_conv_layers/{k}/...     -> depth_decoder.levels.{j}.refiner.convs.{3+k}...
    <dec>/levels/{j}/semantic_refiner/(prep|est_s)_conv_layers  -> semantic_decoder.levels.{j}.refiner.convs...

(each TF key ends in ``/.ATTRIBUTES/VARIABLE_VALUE``). Kernels ``[3,3,C_in,C_out]`` become ``[C_out,C_in,3,3]``;
DINL ``[1,1,1,16]`` becomes ``[16]``. Optimizer slots and variables, metric variables, step/save counters,
inference state variables (``*prev_*``) and the object graph are ignored; any other weight tensor is an error.

The model config is inferred from shapes: the architecture from which refiners exist, the number of levels from
the encoder, the classes from the last semantic conv (``N + 4`` channels), DINL from its presence, the semantic
decoder's SNCV from its refiners' input channels (design 6.3), and the depth ablations from the depth refiners' input
channels ``9K + 1 + 4·[level memory] + 49K·[SNCV] + [time recurrence]``
with ``K = 2^floor(l/2)`` (``1`` without feature subdivision) at absolute level ``l`` (design 5.1, 5.5). Feature
normalization has no weights, so it cannot be read from a checkpoint: it is taken from the caller (default on), and
so is the cost-volume precision (default float16, as the original computes it).
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
import torch

from .. import __version__
from ..errors import CheckpointError, ConfigError
from ..models.config import (
    ARCHITECTURES,
    ENCODER_CHANNELS,
    MIDAIR_IMAGE_SIZE,
    ORIGINAL_PSCV_DTYPE,
    PSCV_DTYPES,
    ModelConfig,
)
from ..models.model import build_model
from ..models.registry import architecture_of
from ..operating_point import MotionStats, OperatingPoint
from .tf_checkpoint import CheckpointReader
from .tf_decoders import TF_DECODERS

#: Convs of the refiner's ``prep_conv_layers`` stack; the ``est_*_conv_layers`` stack holds the other four.
PREP_CONVS = 3

#: Per-step camera translation ``||t||`` (metres) of Mid-Air's training windows: the rows after the first of every
#: 4-row chunk (the paper's seq_len = db_seq_len = 4) of the authors' published training-split CSVs
#: (Malga-Vision/Co-SemDepth, data/midair/train_data, 70,399 rows). Recomputed by
#: ``python scripts/midair_motion_stats.py AUTHORS_DIR``.
MIDAIR_STEP_TRANSLATION = MotionStats(
    count=52632,
    mean=1.6760828560801506,
    median=1.604856814287929,
    p05=0.7155285897518835,
    p25=1.164078108511934,
    p75=2.1368632936091183,
    p95=2.909905478710922,
)
#: The operating point of the official checkpoints (trained on Mid-Air at 384x384, a 90-degree camera: f = W/2),
#: written by ``cosemdepth convert`` and given to TensorFlow checkpoints loaded on the fly.
MIDAIR_OPERATING_POINT = OperatingPoint(
    (MIDAIR_IMAGE_SIZE, MIDAIR_IMAGE_SIZE),
    (MIDAIR_IMAGE_SIZE / 2, MIDAIR_IMAGE_SIZE / 2),
    MIDAIR_STEP_TRANSLATION,
    "Mid-Air at 384x384, 90-degree field of view; motion: the authors' Mid-Air training-split CSVs",
)

_VAR = r"/\.ATTRIBUTES/VARIABLE_VALUE$"
_ENC_CONV = re.compile(r"^(?P<root>(?:.*/)?)conv_layers_s(?P<s>[12])/(?P<k>\d+)/(?P<p>kernel|bias)" + _VAR)
_ENC_DINL = re.compile(r"^(?P<root>(?:.*/)?)dn_layers/(?P<k>\d+)/(?P<p>scale|bias)" + _VAR)
_REFINER = re.compile(
    r"^(?P<root>(?:.*/)?)levels/(?P<j>\d+)/(?P<ref>\w+)/"
    r"(?P<stack>prep_conv_layers|est_[a-z]+_conv_layers)/(?P<k>\d+)/(?P<p>kernel|bias)" + _VAR
)
_SLOT = re.compile(r"/\.OPTIMIZER_SLOT/")
#: Keys that are not weights: what they are, and the pattern.
_IGNORED = (
    ("object graph", re.compile(r"^_CHECKPOINTABLE_OBJECT_GRAPH$")),
    ("optimizer slot", _SLOT),
    ("optimizer", re.compile(r"(^|/)optimizer/")),
    ("metric", re.compile(r"(^|/)[A-Za-z0-9_]*metrics?(/|$)")),
    ("counter", re.compile(r"(^|/)(step_counter|save_counter)/")),
    ("inference state", re.compile(r"(^|/)[A-Za-z0-9_]*prev_[A-Za-z0-9_]*/\.ATTRIBUTES/")),
)


@dataclass
class Conversion:
    """The result of a conversion: our state dict, the inferred config, and what happened to each TF key."""

    state_dict: dict[str, torch.Tensor]
    config: ModelConfig
    converted_keys: dict[str, str]  #: our parameter name -> TF key
    ignored_keys: dict[str, str]  #: TF key -> why (optimizer, metric, ...)
    dropped_keys: list[str]  #: weights of a part not loaded (e.g. the semantic decoder with ``arch="m4depth"``)
    inferred: list[str] = field(default_factory=list)  #: config fields read from the checkpoint's shapes
    source: dict[str, Any] = field(default_factory=dict)

    @property
    def num_parameters(self) -> int:
        return sum(int(t.numel()) for t in self.state_dict.values())

    def parameters_by_part(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for name, t in self.state_dict.items():
            part = name.split(".", 1)[0]
            out[part] = out.get(part, 0) + int(t.numel())
        return out


# ----------------------------------------------------------------------------------------------------------------
# Expected parameters of a config


def expected_param_shapes(cfg: ModelConfig) -> dict[str, tuple[int, ...]]:
    """Name -> shape of every parameter of a model with config ``cfg`` (our layout, PyTorch NCHW kernels), read off
    the model built on the meta device (nothing allocated)."""
    with torch.device("meta"):
        model = build_model(cfg)
    return {k: tuple(v.shape) for k, v in model.state_dict().items()}


def count_parameters(cfg: ModelConfig) -> int:
    """Number of parameters of a model with config ``cfg``."""
    return sum(int(np.prod(s)) for s in expected_param_shapes(cfg).values())


def _tf_shape(name: str, shape: tuple[int, ...]) -> tuple[int, ...]:
    """The TF checkpoint shape of our parameter ``name`` of shape ``shape``."""
    if name.startswith("encoder.dinl."):
        return (1, 1, 1, *shape)
    if len(shape) == 4:
        c_out, c_in, kh, kw = shape
        return (kh, kw, c_in, c_out)
    return shape


# ----------------------------------------------------------------------------------------------------------------
# Matching keys


def _classify(key: str) -> tuple[str, str, str] | None:
    """``(part, root, our name)`` for a weight key of ours, or None."""
    m = _ENC_CONV.match(key)
    if m:
        p = "weight" if m["p"] == "kernel" else "bias"
        return "encoder", m["root"], f"encoder.conv_s{m['s']}.{int(m['k'])}.{p}"
    m = _ENC_DINL.match(key)
    if m:
        p = "weight" if m["p"] == "scale" else "bias"
        k = int(m["k"])
        # Only the level-1 DINL ever gets weights (design 4.2); another index is reported as unexpected below.
        return "encoder", m["root"], ("encoder.dinl." if k == 0 else f"encoder.dinl{k}.") + p
    m = _REFINER.match(key)
    if m:
        name = next((n for n, t in TF_DECODERS.items() if t.refiner == m["ref"]), None)
        if name is None:
            return None
        part = f"{name}_decoder"
        k = int(m["k"]) + (0 if m["stack"] == "prep_conv_layers" else PREP_CONVS)
        p = "weight" if m["p"] == "kernel" else "bias"
        return part, m["root"], f"{part}.levels.{int(m['j'])}.refiner.convs.{k}.{p}"
    return None


def _ignored_reason(key: str) -> str | None:
    for why, pattern in _IGNORED:
        if pattern.search(key):
            return why
    return None


def _show(keys, n: int = 6) -> str:
    keys = list(keys)
    shown = ", ".join(repr(k) for k in keys[:n])
    return shown + (f", ... ({len(keys)} in all)" if len(keys) > n else "")


# ----------------------------------------------------------------------------------------------------------------
# Inference of the config


def _level_count(names: set[str], pattern: str, what: str, origin: str) -> int:
    idx = sorted({int(m.group(1)) for n in names if (m := re.match(pattern, n))})
    if not idx:
        return 0
    if idx != list(range(len(idx))):
        raise CheckpointError(f"{origin}: {what} indices {idx} are not 0..{len(idx) - 1}: incomplete checkpoint")
    return len(idx)


def infer_config(
    shapes: Mapping[str, tuple[int, ...]],
    *,
    arch: str | None = None,
    feature_normalization: bool = True,
    pscv_dtype: str = ORIGINAL_PSCV_DTYPE,
    origin: str = "checkpoint",
) -> tuple[ModelConfig, list[str]]:
    """Infer the :class:`ModelConfig` from our parameter names and their **TF** shapes (see :func:`convert_tensors`).

    Returns the config and the names of its fields that were read from the shapes (the others keep defaults).
    """
    if pscv_dtype not in PSCV_DTYPES:
        raise ConfigError(f"pscv_dtype must be 'float16' or 'float32', got {pscv_dtype!r}")
    names = set(shapes)
    levels = _level_count(names, r"encoder\.conv_s1\.(\d+)\.", "encoder level", origin)
    if levels == 0:
        raise CheckpointError(f"{origin}: no encoder weights (conv_layers_s1/...) found")
    if levels > len(ENCODER_CHANNELS):
        raise CheckpointError(f"{origin}: {levels} encoder levels; at most {len(ENCODER_CHANNELS)} are supported")
    has = {}
    for name in TF_DECODERS:
        part = f"{name}_decoder"
        n = _level_count(names, rf"{part}\.levels\.(\d+)\.", f"{part.replace('_', ' ')} level", origin)
        if n and n != levels:
            raise CheckpointError(f"{origin}: the encoder has {levels} levels but the {part.replace('_', ' ')} has {n}")
        has[name] = bool(n)
    found = architecture_of(k for k, v in has.items() if v)
    if found is None:
        scopes = " or ".join(sorted(f"'{t.refiner}'" for t in TF_DECODERS.values()))
        raise CheckpointError(
            f"{origin}: an encoder but no decoder (no {scopes} weights): not a "
            "Co-SemDepth, M4Depth or M4Semantic checkpoint"
            if not any(has.values())
            else f"{origin}: its decoders {sorted(k for k, v in has.items() if v)} make no registered architecture"
        )
    arch_inferred = arch is None
    if arch is None:
        arch = found
    elif arch not in ARCHITECTURES:
        raise ConfigError(f"arch must be one of {tuple(ARCHITECTURES)}, got {arch!r}")
    wanted = [name for name in TF_DECODERS if name in ARCHITECTURES[arch]]
    for name in wanted:
        if not has[name]:
            raise CheckpointError(
                f"{origin}: holds a {found} model, which has no {name} decoder (no '{TF_DECODERS[name].refiner}' "
                f"weights); it cannot be loaded as {arch}"
            )

    kw: dict[str, Any] = dict(
        arch=arch, levels=levels, feature_normalization=feature_normalization, pscv_dtype=pscv_dtype
    )
    kw["dinl"] = any(n.startswith("encoder.dinl.") for n in names)
    inferred = (["arch"] if arch_inferred else []) + ["levels", "dinl"]
    for name in wanted:
        fields = TF_DECODERS[name].config(shapes, levels, origin)
        kw.update(fields)
        inferred += list(fields)
    try:
        return ModelConfig(**kw), inferred
    except ConfigError as e:
        raise CheckpointError(f"{origin}: inferred an invalid model config: {e}") from e


# ----------------------------------------------------------------------------------------------------------------
# Conversion


def convert_tensors(
    tensors: Mapping[str, np.ndarray],
    *,
    arch: str | None = None,
    feature_normalization: bool = True,
    pscv_dtype: str = ORIGINAL_PSCV_DTYPE,
    origin: str = "checkpoint",
) -> Conversion:
    """Map TF checkpoint tensors ``{key: array}`` to our state dict and infer the config.

    ``arch`` loads only part of a checkpoint (e.g. ``"m4depth"`` from a joint checkpoint: the semantic decoder's
    weights are dropped); by default the architecture the checkpoint holds. ``feature_normalization`` and
    ``pscv_dtype`` leave no trace in the weights and are set as given: float16 cost-volume products reproduce the
    original's numbers (design 5.5.2). ``origin`` names the checkpoint in error messages. Raises :class:`CheckpointError` on a missing, unexpected or wrongly shaped tensor.
    """
    hits: list[tuple[str, str, str]] = []  # (tf key, part, our name)
    ignored: dict[str, str] = {}
    unknown: list[str] = []
    roots: dict[str, set[str]] = {}
    for key in tensors:
        hit = None if _SLOT.search(key) else _classify(key)
        if hit is None:
            why = _ignored_reason(key)
            if why is not None:
                ignored[key] = why
            else:
                unknown.append(key)
            continue
        part, root, name = hit
        roots.setdefault(part, set()).add(root)
        hits.append((key, part, name))
    if not hits:
        raise CheckpointError(
            f"{origin}: no Co-SemDepth / M4Depth / M4Semantic weights found among its {len(tensors)} tensors "
            f"(e.g. {_show(sorted(tensors), 4)}): a checkpoint of another model?"
        )
    for part, rs in roots.items():
        if len(rs) > 1:
            raise CheckpointError(
                f"{origin}: {part.replace('_', ' ')} weights under several roots {sorted(r.rstrip('/') for r in rs)}: "
                "ambiguous checkpoint"
            )
    mapped: dict[str, tuple[str, np.ndarray]] = {}  # our name -> (tf key, array)
    for key, _, name in hits:
        if name in mapped:
            raise CheckpointError(f"{origin}: {key!r} and {mapped[name][0]!r} both map to {name}")
        mapped[name] = (key, np.asarray(tensors[key]))

    tf_shapes = {name: tuple(int(d) for d in arr.shape) for name, (_, arr) in mapped.items()}
    cfg, inferred = infer_config(
        tf_shapes, arch=arch, feature_normalization=feature_normalization, pscv_dtype=pscv_dtype, origin=origin
    )
    expected = expected_param_shapes(cfg)

    loaded_parts = {"encoder"} | {f"{name}_decoder" for name in cfg.decoders}
    dropped = sorted(key for name, (key, _) in mapped.items() if name.split(".", 1)[0] not in loaded_parts)
    unexpected = sorted(
        key for name, (key, _) in mapped.items() if name not in expected and name.split(".", 1)[0] in loaded_parts
    )
    missing = sorted(name for name in expected if name not in mapped)
    problems = []
    if missing:
        problems.append(f"missing weights {_show(missing)}")
    if unexpected or unknown:
        problems.append(f"unexpected tensors {_show(unexpected + sorted(unknown))}")
    bad_shapes = []
    for name, shape in expected.items():
        if name in mapped:
            key, arr = mapped[name]
            want = _tf_shape(name, shape)
            if tuple(arr.shape) != want:
                bad_shapes.append(f"{key!r} has shape {list(arr.shape)}, expected {list(want)}")
    if bad_shapes:
        more = f" ({len(bad_shapes)} in all)" if len(bad_shapes) > 6 else ""
        problems.append("wrong shapes: " + "; ".join(bad_shapes[:6]) + more)
    if problems:
        raise CheckpointError(f"{origin}: does not match the inferred {_describe(cfg)} model: " + "; ".join(problems))

    state_dict: dict[str, torch.Tensor] = {}
    converted: dict[str, str] = {}
    for name in expected:
        key, arr = mapped[name]
        if not np.issubdtype(arr.dtype, np.floating):
            raise CheckpointError(f"{origin}: weight {key!r} has dtype {arr.dtype}, expected a floating-point type")
        arr = arr.astype(np.float32, copy=False)
        if arr.ndim == 4 and not name.startswith("encoder.dinl."):
            arr = arr.transpose(3, 2, 0, 1)  # [kh, kw, C_in, C_out] -> [C_out, C_in, kh, kw]
        elif name.startswith("encoder.dinl."):
            arr = arr.reshape(-1)
        state_dict[name] = torch.from_numpy(np.ascontiguousarray(arr).copy())
        converted[name] = key
    return Conversion(state_dict, cfg, converted, ignored, dropped, inferred)


def _describe(cfg: ModelConfig) -> str:
    return f"{cfg.arch} (levels={cfg.levels}, classes={cfg.num_classes})"


def import_checkpoint(
    path: str | os.PathLike,
    *,
    arch: str | None = None,
    feature_normalization: bool = True,
    pscv_dtype: str = ORIGINAL_PSCV_DTYPE,
) -> Conversion:
    """Read the TF checkpoint at ``path`` (prefix, ``.index`` file or folder) and convert it.

    The returned :class:`Conversion` carries a ``source`` dict recording where the weights came from.
    """
    reader = CheckpointReader(path)
    origin = str(reader.prefix)
    conv = convert_tensors(
        reader.read_all(),
        arch=arch,
        feature_normalization=feature_normalization,
        pscv_dtype=pscv_dtype,
        origin=origin,
    )
    conv.source = {
        "type": "tensorflow_checkpoint",
        "checkpoint": str(reader.prefix.resolve()),
        "index_sha256": hashlib.sha256(reader.index_path.read_bytes()).hexdigest(),
        "entries": len(reader),
        "converted_tensors": len(conv.converted_keys),
        "ignored_tensors": len(reader) - len(conv.converted_keys) - len(conv.dropped_keys),
        "dropped_tensors": len(conv.dropped_keys),
        "inferred": list(conv.inferred),
        "not_from_checkpoint": {"feature_normalization": feature_normalization, "pscv_dtype": pscv_dtype},
        "converter": f"cosemdepth {__version__}",
    }
    return conv


def convert_checkpoint(
    path: str | os.PathLike,
    *,
    arch: str | None = None,
    feature_normalization: bool = True,
    pscv_dtype: str = ORIGINAL_PSCV_DTYPE,
) -> tuple[dict[str, torch.Tensor], ModelConfig]:
    """``(state_dict, config)`` of the TF checkpoint at ``path``; see :func:`import_checkpoint`."""
    conv = import_checkpoint(path, arch=arch, feature_normalization=feature_normalization, pscv_dtype=pscv_dtype)
    return conv.state_dict, conv.config


__all__ = [
    "MIDAIR_OPERATING_POINT",
    "MIDAIR_STEP_TRANSLATION",
    "Conversion",
    "convert_checkpoint",
    "convert_tensors",
    "count_parameters",
    "expected_param_shapes",
    "import_checkpoint",
    "infer_config",
]
