"""int8 ONNX graphs (``export --onnx OUT --int8``): the fast path's int8 policy picks the convolutions, ONNX Runtime
runs them as fused int8 convolutions, and everything the policy keeps float computes what the float32 graph does."""

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from cosemdepth.checkpoints.model_io import load_model
from cosemdepth.errors import ConfigError
from cosemdepth.export import export_onnx
from cosemdepth.export.check import synthetic_sequence
from cosemdepth.export.onnx import is_our_onnx
from cosemdepth.export.quantize import int8_nodes, int8_weights, quantize_onnx, quantized_convolutions
from cosemdepth.export.runtime import OnnxStep
from cosemdepth.models import build_model

SHIPPED = Path(__file__).resolve().parents[2] / "weights" / "synthair-cosemdepth"
H = W = 64


def frames(n: int, seed: int, h: int = H, w: int = W):
    rgb, rot, trans, k = synthetic_sequence(1, n, h, w, seed=seed)
    return [(rgb[:, t], rot[:, t], trans[:, t], k, torch.tensor([t == 0])) for t in range(n)]


def test_policy_quantises_the_semantic_hidden_convolutions_only():
    m = build_model()  # Co-SemDepth, 5 levels, refiners of 7 convolutions
    expected = {f"semantic_decoder.levels.{i}.refiner.convs.{k}.weight" for i in range(5) for k in range(6)}
    assert int8_weights(m) == expected
    # the policy's tables decide: nothing kept float quantises every hidden convolution of both decoders
    both = {
        f"{d}_decoder.levels.{i}.refiner.convs.{k}.weight"
        for d in ("depth", "semantic")
        for i in range(5)
        for k in range(6)
    }
    assert int8_weights(m, keep_float={}, float32_from_level={}) == both
    # levels at or above float32_from_level stay float (level 1 = finest = levels.0)
    assert int8_weights(m, float32_from_level={"semantic": 3}) == {n for n in expected if n.split(".")[2] in ("0", "1")}
    assert int8_weights(build_model(arch="m4depth")) == set()


@pytest.fixture(scope="module")
def graphs(tmp_path_factory):
    model = load_model(SHIPPED)
    d = tmp_path_factory.mktemp("int8")
    fp = export_onnx(model, d / "fp32.onnx", H, W)
    q = quantize_onnx(model, fp, d / "int8.onnx", frames(6, seed=7))
    return model, fp, q


def test_int8_graph_keeps_the_interface_and_quantises_what_the_policy_says(graphs):
    model, fp, q = graphs
    a, b = onnx.load(str(fp)), onnx.load(str(q))
    assert [i.name for i in a.graph.input] == [i.name for i in b.graph.input]
    assert [o.name for o in a.graph.output] == [o.name for o in b.graph.output]
    assert is_our_onnx(q)
    # its metadata is the float32 graph's but for the precision (and the digest of what it now holds)
    pa, pb = ({p.key: p.value for p in g.metadata_props if p.key.startswith("cosemdepth_")} for g in (a, b))
    assert pb.pop("cosemdepth_precision") == "int8" and pa.pop("cosemdepth_precision") == "fp32"
    assert pb.pop("cosemdepth_graph_sha256") != pa.pop("cosemdepth_graph_sha256")
    assert pa == pb
    assert OnnxStep(q, model=model).precision == "int8"
    assert quantized_convolutions(q) == sorted("model." + n for n in int8_weights(model))
    assert len(int8_nodes(a.graph, int8_weights(model))) == 30
    # ONNX Runtime fuses every quantised convolution into one int8 convolution
    so = ort.SessionOptions()
    so.optimized_model_filepath = str(Path(q).with_suffix(".opt.onnx"))
    ort.InferenceSession(str(q), so, providers=["CPUExecutionProvider"])
    ops = [n.op_type for n in onnx.load(so.optimized_model_filepath).graph.node]
    assert ops.count("QLinearConv") == 30


def test_int8_graph_streams_like_the_float32_one(graphs):
    """Depth (its decoder stays float) as the float32 graph computes it; labels nearly all the same."""
    _, fp, q = graphs
    sessions = [ort.InferenceSession(str(p), providers=["CPUExecutionProvider"]) for p in (fp, q)]
    states = [None, None]
    agree, worst_depth = [], 0.0
    for t, (rgb, rot, trans, k, reset) in enumerate(frames(8, seed=12)):
        outs = []
        for j, s in enumerate(sessions):
            feeds = {"rgb": rgb.numpy(), "rot": rot.numpy(), "trans": trans.numpy(), "intrinsics": k.numpy()}
            feeds["reset"] = reset.numpy()
            names = [i.name for i in s.get_inputs() if i.name.startswith("state_")]
            if states[j] is None:
                states[j] = {n: np.zeros([d for d in i.shape], np.float32) for n, i in zip(names, s.get_inputs()[5:])}
            feeds.update(states[j])
            res = dict(zip([o.name for o in s.get_outputs()], s.run(None, feeds)))
            states[j] = {n: res["next_" + n] for n in names}
            outs.append(res)
        if t > 0:
            rel = np.abs(outs[1]["depth"] / outs[0]["depth"] - 1)
            worst_depth = max(worst_depth, float(rel.max()))
            agree.append(float((outs[0]["semantic"].argmax(1) == outs[1]["semantic"].argmax(1)).mean()))
    assert worst_depth < 1e-4, worst_depth
    assert min(agree) > 0.9 and np.mean(agree) > 0.95, agree


def test_a_model_without_int8_convolutions_is_refused(tmp_path):
    m = build_model(arch="m4depth", levels=1).eval()
    fp = export_onnx(m, tmp_path / "m4depth.onnx", 16, 16)
    with pytest.raises(ConfigError, match="no convolution the int8 policy quantises"):
        quantize_onnx(m, fp, tmp_path / "q.onnx", frames(2, seed=1, h=16, w=16))
    assert not (tmp_path / "q.onnx").exists()
