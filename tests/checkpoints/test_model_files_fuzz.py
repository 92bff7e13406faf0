"""Fuzzing the model-folder readers: damaged ``config.json`` and ``model.safetensors`` (truncated, flipped bytes,
wrong types, NaN/inf, empty, huge sizes) give either the right model or a :class:`CheckpointError` naming the file,
never another exception."""

import json
import math
import struct

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cosemdepth.checkpoints.convert import expected_param_shapes
from cosemdepth.checkpoints.model_io import read_config_file, read_model_files, save_weights
from cosemdepth.errors import CheckpointError
from cosemdepth.models.config import ModelConfig

CFG = ModelConfig(arch="m4semantic", levels=1, num_classes=3)
FUZZ = settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


def _state(cfg=CFG):
    g = torch.Generator().manual_seed(0)
    return {k: torch.randn(s, generator=g) for k, s in expected_param_shapes(cfg).items()}


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    d = tmp_path_factory.mktemp("good") / "model"
    save_weights(_state(), CFG, d)
    return (d / "config.json").read_bytes(), (d / "model.safetensors").read_bytes()


def _folder(tmp_path_factory, config: bytes, weights: bytes):
    d = tmp_path_factory.mktemp("fuzz") / "model"
    d.mkdir()
    (d / "config.json").write_bytes(config)
    (d / "model.safetensors").write_bytes(weights)
    return d


def _outcome(folder, target: str):
    """Read the folder; the result must be right or the error must name ``folder/target``."""
    try:
        sd, cfg, _ = read_model_files(folder)
    except CheckpointError as e:
        assert str(folder) in str(e), str(e)
        return None
    # a result: the weights fit the config, and every value is finite
    shapes = expected_param_shapes(cfg)
    assert {k: tuple(v.shape) for k, v in sd.items()} == shapes
    assert all(torch.isfinite(v).all() for v in sd.values())
    return cfg


json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=6,
)
MODEL_KEYS = [
    "arch",
    "levels",
    "num_classes",
    "dinl",
    "sncv",
    "time_recurrence",
    "feature_normalization",
    "feature_subdivision",
    "level_memory",
    "pscv_dtype",
]


@FUZZ
@given(data=st.data())
def test_damaged_config_json(good, tmp_path_factory, data):
    config, weights = good
    kind = data.draw(st.sampled_from(["truncate", "flip", "field", "model_field", "top", "empty", "nan"]))
    if kind == "truncate":
        config = config[: data.draw(st.integers(0, len(config) - 1))]
    elif kind == "flip":
        i = data.draw(st.integers(0, len(config) - 1))
        config = config[:i] + bytes([config[i] ^ data.draw(st.integers(1, 255))]) + config[i + 1 :]
    elif kind in ("field", "model_field"):
        meta = json.loads(config)
        where = meta["model"] if kind == "model_field" else meta
        key = data.draw(st.sampled_from(MODEL_KEYS if kind == "model_field" else list(meta)))
        if data.draw(st.booleans()):
            where[key] = data.draw(json_values)
        else:
            where.pop(key)
        config = json.dumps(meta, allow_nan=True).encode()
    elif kind == "top":
        config = json.dumps(data.draw(json_values), allow_nan=True).encode()
    elif kind == "empty":
        config = b""
    else:
        meta = json.loads(config)
        meta["model"][data.draw(st.sampled_from(["levels", "num_classes"]))] = data.draw(
            st.sampled_from([math.nan, math.inf, -math.inf, 1e308, 10**30, -1, 0, 2.5, True])
        )
        config = json.dumps(meta, allow_nan=True).encode()
    folder = _folder(tmp_path_factory, config, weights)
    try:
        cfg, _ = read_config_file(folder)
    except CheckpointError as e:
        assert str(folder / "config.json") in str(e), str(e)
        return
    assert isinstance(cfg, ModelConfig)
    _outcome(folder, "config.json")


def _header(weights: bytes) -> tuple[dict, bytes]:
    n = struct.unpack("<Q", weights[:8])[0]
    return json.loads(weights[8 : 8 + n]), weights[8 + n :]


def _pack(header: dict, body: bytes) -> bytes:
    h = json.dumps(header, allow_nan=True).encode()
    return struct.pack("<Q", len(h)) + h + body


@FUZZ
@given(data=st.data())
def test_damaged_model_safetensors(good, tmp_path_factory, data):
    config, weights = good
    kind = data.draw(
        st.sampled_from(
            [
                "truncate",
                "flip",
                "flip_body",
                "dtype",
                "shape",
                "offsets",
                "header_size",
                "nan",
                "empty",
                "random_header",
            ]
        )
    )
    header, body = _header(weights)
    names = sorted(k for k in header if k != "__metadata__")
    if kind == "truncate":
        weights = weights[: data.draw(st.integers(0, len(weights) - 1))]
    elif kind in ("flip", "flip_body"):
        lo = len(weights) - len(body) if kind == "flip_body" else 0
        i = data.draw(st.integers(lo, len(weights) - 1))
        weights = weights[:i] + bytes([weights[i] ^ data.draw(st.integers(1, 255))]) + weights[i + 1 :]
    elif kind == "dtype":
        header[data.draw(st.sampled_from(names))]["dtype"] = data.draw(
            st.sampled_from(["I32", "U8", "F16", "BF16", "F64", "BOOL", "XX", 3])
        )
        weights = _pack(header, body)
    elif kind == "shape":
        header[data.draw(st.sampled_from(names))]["shape"] = data.draw(
            st.lists(st.integers(-2, 2**40), max_size=4) | json_values
        )
        weights = _pack(header, body)
    elif kind == "offsets":
        header[data.draw(st.sampled_from(names))]["data_offsets"] = data.draw(
            st.lists(st.integers(-5, 2**63), min_size=0, max_size=3) | json_values
        )
        weights = _pack(header, body)
    elif kind == "header_size":
        weights = struct.pack("<Q", data.draw(st.integers(0, 2**64 - 1))) + weights[8:]
    elif kind == "nan":
        name = data.draw(st.sampled_from(names))
        a, _ = header[name]["data_offsets"]
        k = data.draw(st.integers(0, (header[name]["data_offsets"][1] - a) // 4 - 1))
        value = data.draw(st.sampled_from([math.nan, math.inf, -math.inf]))
        body = body[: a + 4 * k] + struct.pack("<f", value) + body[a + 4 * k + 4 :]
        weights = _pack(header, body)
    elif kind == "empty":
        weights = b""
    else:
        weights = _pack(data.draw(st.dictionaries(st.text(max_size=6), json_values, max_size=3)), body)
    folder = _folder(tmp_path_factory, config, weights)
    cfg = _outcome(folder, "model.safetensors")
    if kind in ("nan", "empty", "header_size", "random_header", "dtype"):
        assert cfg is None  # never a valid model


def test_non_finite_weights_are_named(good, tmp_path):
    sd = _state()
    key = sorted(sd)[3]
    sd[key].view(-1)[5] = math.nan
    save_weights(sd, CFG, tmp_path / "m")
    with pytest.raises(
        CheckpointError,
        match=rf"{tmp_path / 'm' / 'model.safetensors'}: weights hold NaN/inf: "
        rf"{key} \(1 of",
    ):
        read_model_files(tmp_path / "m")
