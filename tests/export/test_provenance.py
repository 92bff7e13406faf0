"""What an exported graph records about its making, and the refusal of a graph that is not the model's or was changed
after export (every consumer opens graphs through :class:`OnnxStep` / :class:`OnnxModel` / ``compare_onnx``)."""

import hashlib
import json

import numpy as np
import onnx
import pytest
import torch

from cosemdepth import __version__
from cosemdepth.errors import ConfigError
from cosemdepth.export import export_onnx
from cosemdepth.export.check import compare_onnx
from cosemdepth.export.provenance import read_provenance, weights_digest
from cosemdepth.export.runtime import OnnxModel, OnnxStep
from cosemdepth.models import build_model

H, W = 16, 24


def tiny(seed=0, **kw):
    torch.manual_seed(seed)
    return build_model(levels=2, **kw).eval()


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    m = tiny()
    path = export_onnx(m, tmp_path_factory.mktemp("prov") / "g.onnx", H, W, batch=1, opset=17)
    return m, path


def test_the_export_records_what_it_was_made_from(exported):
    m, path = exported
    props = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert props["cosemdepth_export"] == __version__
    assert props["cosemdepth_arch"] == "cosemdepth"
    assert json.loads(props["cosemdepth_model_config"]) == m.config.to_dict()
    assert props["cosemdepth_weights_sha256"] == weights_digest(m)
    assert (props["cosemdepth_input_size"], props["cosemdepth_batch"]) == (f"{H}x{W}", "1")
    assert (props["cosemdepth_precision"], props["cosemdepth_opset"]) == ("fp32", "17")
    assert len(props["cosemdepth_graph_sha256"]) == 64
    step = OnnxStep(path, model=m)  # the model it was exported from: accepted
    assert step.precision == "fp32" and step.provenance == props


def test_weights_digest_is_the_state_in_name_order_as_float32():
    lin = torch.nn.Linear(2, 1)
    with torch.no_grad():
        lin.weight.copy_(torch.tensor([[1.0, -2.0]]))
        lin.bias.fill_(0.5)
    h = hashlib.sha256()
    h.update(b"bias\0float32\0[1]\0" + np.float32([0.5]).tobytes())
    h.update(b"weight\0float32\0[1, 2]\0" + np.float32([1.0, -2.0]).tobytes())
    assert weights_digest(lin) == h.hexdigest()
    assert weights_digest(lin.to(torch.float64)) == h.hexdigest()  # the values an fp32 graph holds


@pytest.mark.parametrize(
    "other, words",
    [
        (lambda: tiny(arch="m4depth"), "architecture cosemdepth in the graph, m4depth in the model"),
        (lambda: tiny(arch="cosemdepth-t"), "architecture cosemdepth in the graph, cosemdepth-t in the model"),
        (lambda: build_model(levels=3), "its config differs from the model's: levels 2 in the graph, 3"),
        (lambda: tiny(semantic_time="own"), "semantic_time 'off' in the graph, 'own'"),
        (lambda: tiny(seed=1), "other weights (sha256 "),
    ],
)
def test_a_graph_of_another_model_is_refused_in_one_line(exported, other, words):
    _, path = exported
    model = other()
    with pytest.raises(ConfigError) as e:
        OnnxModel(model, OnnxStep(path), model_name="--model M")
    msg = str(e.value)
    assert msg.startswith(f"{path}: not an export of --model M: ") and words in msg and "\n" not in msg
    with pytest.raises(ConfigError, match="not an export of the model"):
        compare_onnx(model, path)  # what export --check runs


def test_one_changed_weight_in_the_model_is_another_model(exported):
    m, path = exported
    changed = tiny()
    with torch.no_grad():
        next(changed.parameters()).view(-1)[0] += 1e-3
    with pytest.raises(ConfigError, match="other weights"):
        OnnxStep(path, model=changed)


def test_a_graph_changed_after_export_is_refused(exported, tmp_path):
    m, path = exported
    data = bytearray(path.read_bytes())
    init = max(onnx.load(str(path)).graph.initializer, key=lambda i: len(i.raw_data))
    at = bytes(data).find(init.raw_data) + len(init.raw_data) // 2
    data[at] ^= 0x01  # one bit of one weight, flipped in the file
    bad = tmp_path / "flipped.onnx"
    bad.write_bytes(bytes(data))
    with pytest.raises(ConfigError) as e:
        OnnxStep(bad, model=m)
    assert str(e.value) == (
        f"{bad}: the graph was changed after export (its digest is not the one recorded at export): "
        f"re-export it: cosemdepth export --onnx {bad} --model MODEL"
    )


def test_a_graph_without_provenance_is_refused(exported, tmp_path):
    m, path = exported
    proto = onnx.load(str(path))
    keep = [(p.key, p.value) for p in proto.metadata_props if p.key == "cosemdepth_export"]  # an older export
    del proto.metadata_props[:]
    onnx.helper.set_model_props(proto, dict(keep))
    old = tmp_path / "old.onnx"
    onnx.save(proto, str(old))
    with pytest.raises(ConfigError, match=r"old.onnx: the graph records no provenance .* re-export it"):
        OnnxStep(old)
    timed = OnnxStep(old, provenance=False)  # timing an older export side by side: run as it is
    assert timed.provenance is None and timed.precision is None
    with pytest.raises(ConfigError, match="records no provenance"):
        OnnxModel(m, timed)  # run for a model, it must say it is that model's
    with pytest.raises(ConfigError, match="records no provenance"):
        read_provenance(old)
