from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from cosemdepth.errors import ConfigError
from cosemdepth.export import export_onnx, state_names
from cosemdepth.export.check import (
    ABSOLUTE_FLOOR,
    CRITERIA,
    NOISE_MULTIPLE,
    Criterion,
    OnnxComparison,
    acceptance_limit,
    compare_onnx,
    nrms,
    relative_percentile,
    run_onnx_stream,
    synthetic_sequence,
    valid_depth,
)
from cosemdepth.inference import FastModel
from cosemdepth.models import build_model

H, W = 32, 48


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(11)
    m = build_model().eval()
    with torch.no_grad():  # well-conditioned depth (see tests/inference/test_fast_engine.py::tame)
        for lvl in m.depth_decoder.levels:
            lvl.refiner.convs[-1].weight.mul_(0.1)
    path = export_onnx(FastModel(m), tmp_path_factory.mktemp("onnx") / "step.onnx", H, W, batch=2)  # its modules
    return m, path


def test_graph_interface(exported):
    m, path = exported
    proto = onnx.load(str(path))
    onnx.checker.check_model(proto)
    assert max(o.version for o in proto.opset_import if o.domain in ("", "ai.onnx")) >= 16
    ops = {n.op_type for n in proto.graph.node}
    assert "GridSample" not in ops and "Gather" in ops  # the warps as row gathers (geometry.warp.sample_bilinear_rows)
    ins = [i.name for i in proto.graph.input]
    outs = [o.name for o in proto.graph.output]
    assert ins == ["rgb", "rot", "trans", "intrinsics", "reset", *state_names(5)]
    assert outs == ["depth", "semantic", *state_names(5, "next_state")]
    assert not m.depth_decoder.static and not m.training  # the model is given back as it was


def test_onnxruntime_matches_pytorch_over_streamed_frames_with_a_reset(exported):
    m, path = exported
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    b, t = 2, 7
    rgb, rot, trans, K = synthetic_sequence(b, t, H, W, seed=5)
    reset = torch.zeros(b, t, dtype=torch.bool)
    reset[:, 0] = True
    reset[1, 4] = True
    ort_state = [np.zeros(i.shape, np.float32) for i in sess.get_inputs()[5:]]  # first frame: zeros + reset
    state = None
    with torch.no_grad():
        for k in range(t):
            ref, state = m.step(rgb[:, k], rot[:, k], trans[:, k], K, reset[:, k], state)
            feeds = {
                "rgb": rgb[:, k].numpy(),
                "rot": rot[:, k].numpy(),
                "trans": trans[:, k].numpy(),
                "intrinsics": K.numpy(),
                "reset": reset[:, k].numpy(),
            }
            res, ort_state = run_onnx_stream(sess, feeds, ort_state)
            d = ref.depth.numpy()
            assert np.max(np.abs(res["depth"] - d) / np.abs(d)) < 1e-3, k
            assert np.max(np.abs(res["semantic"] - ref.semantic.numpy())) < 1e-4, k
            for a, s in zip(ort_state, state.flatten()):
                np.testing.assert_allclose(a, s.numpy(), rtol=1e-3, atol=1e-4)
    assert np.all(res["depth"][1] != 1000.0) and np.std(res["depth"]) > 0


def test_single_task_graphs_and_bad_opset(tmp_path):
    sem = build_model(arch="m4semantic", levels=2).eval()
    p = export_onnx(sem, tmp_path / "sem.onnx", 16, 16)
    sess = ort.InferenceSession(str(p), providers=["CPUExecutionProvider"])
    assert [i.name for i in sess.get_inputs()] == ["rgb"]  # no temporal input: the unused ones are dropped
    assert [o.name for o in sess.get_outputs()] == ["semantic"]
    x = torch.rand(1, 3, 16, 16)
    feeds = {
        "rgb": x.numpy(),
        "rot": np.array([[1, 0, 0, 0]], np.float32),
        "trans": np.zeros((1, 3), np.float32),
        "intrinsics": np.array([[8, 8, 8, 8]], np.float32),
        "reset": np.array([True]),
    }
    with torch.no_grad():
        ref = sem.step(x, torch.tensor([[1.0, 0, 0, 0]]), torch.zeros(1, 3), torch.tensor([[8.0, 8, 8, 8]]))[0]
    res, state = run_onnx_stream(sess, feeds, [])
    assert state == []
    np.testing.assert_allclose(res["semantic"], ref.semantic.numpy(), atol=1e-5)
    report = compare_onnx(sem, p)  # no depth, no state: the semantic probabilities only
    assert [c.output for c in report.criteria] == ["semantic"] and report.ok, report.summary()
    with pytest.raises(ConfigError, match="opset"):
        export_onnx(sem, tmp_path / "x.onnx", 16, 16, opset=12)
    assert not (tmp_path / "x.onnx").exists()


def test_the_oldest_opset_exports_the_same_graph(tmp_path):
    """Opset 13, the minimum: the temporal model streams as at the default opset (torch writes its reshapes as
    opset-13 operators, so 12 cannot export it)."""
    torch.manual_seed(3)
    m = build_model(levels=2).eval()
    rgb, rot, trans, K = synthetic_sequence(1, 3, 16, 16, seed=2)
    outs = {}
    for opset in (13, 17):
        sess = ort.InferenceSession(str(export_onnx(m, tmp_path / f"o{opset}.onnx", 16, 16, opset=opset)))
        state = [np.zeros(i.shape, np.float32) for i in sess.get_inputs() if i.name.startswith("state_")]
        outs[opset] = []
        for k in range(3):
            feeds = {"rgb": rgb[:, k].numpy(), "rot": rot[:, k].numpy(), "trans": trans[:, k].numpy()}
            feeds.update(intrinsics=K.numpy(), reset=np.array([k == 0]))
            res, state = run_onnx_stream(sess, feeds, state)
            outs[opset] += [res["depth"], res["semantic"]]
    for a, b in zip(outs[13], outs[17]):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


def test_float_reset_input_for_runtimes_without_bool(tmp_path):
    m = build_model(arch="m4depth", levels=2).eval()
    p = export_onnx(m, tmp_path / "d.onnx", 16, 16, reset_float=True)
    sess = ort.InferenceSession(str(p), providers=["CPUExecutionProvider"])
    reset_in = [i for i in sess.get_inputs() if i.name == "reset"][0]
    assert reset_in.type == "tensor(float)"
    assert [o.name for o in sess.get_outputs()] == ["depth", *state_names(2, "next_state")]
    rgb, rot, trans, K = synthetic_sequence(1, 2, 16, 16)
    state = [np.zeros(i.shape, np.float32) for i in sess.get_inputs() if i.name.startswith("state_")]
    depths = []
    for k, r in enumerate([1.0, 0.0]):
        feeds = {
            "rgb": rgb[:, k].numpy(),
            "rot": rot[:, k].numpy(),
            "trans": trans[:, k].numpy(),
            "intrinsics": K.numpy(),
            "reset": np.array([r], np.float32),
        }
        res, state = run_onnx_stream(sess, feeds, state)
        depths.append(res["depth"])
    assert np.all(depths[0] == 1000.0) and not np.all(depths[1] == 1000.0)
    report = compare_onnx(m, p)  # what `cosemdepth export --check` runs
    assert report.ok, report.summary()
    assert report.criterion("depth").frames == list(range(6)) and report.resets == [0, 3]
    assert report.criterion("state").worst < 1e-3


def perturbed_copy(path: Path, out: Path, name: str, factor: float, index=None) -> Path:
    """A copy of the ONNX file ``path`` with initializer ``name`` multiplied by ``factor`` (only its element
    ``index`` when given): a deliberately broken export (stamped as the exporter stamps its graphs: what the check
    must catch is a wrong graph, not a changed file)."""
    from onnx import numpy_helper

    from cosemdepth.export.provenance import stamp

    proto = onnx.load(str(path))
    init = next(i for i in proto.graph.initializer if i.name == name)
    a = numpy_helper.to_array(init).copy()
    if index is None:
        a *= np.float32(factor)
    else:
        a[index] *= np.float32(factor)
    init.CopyFrom(numpy_helper.from_array(a, name))
    onnx.save(proto, str(out))
    stamp(out, {})
    return out


def test_check_passes_on_a_correct_export_of_a_random_weight_model(exported):
    m, path = exported
    report = compare_onnx(FastModel(m), path)  # a FastModel: its model's modules are what is compared
    assert report.ok, report.summary()
    assert (report.size, report.batch, report.frames, report.resets) == ((H, W), 2, 6, [0, 3])
    assert [(c.output, c.metric) for c in report.criteria] == list(CRITERIA)
    assert report.criterion("depth", CRITERIA[1][1]).frames == [1, 2, 4, 5]  # reset frames hold no valid pixel
    for c in report.criteria:  # the two PyTorch runs differ (else the floor measures nothing)
        assert c.floor > 0 and c.limit == max(NOISE_MULTIPLE * c.floor, ABSOLUTE_FLOOR)


SHIPPED = Path(__file__).resolve().parents[2] / "weights" / "synthair-cosemdepth"


@pytest.fixture(scope="module")
def shipped_export(tmp_path_factory):
    from cosemdepth.checkpoints.model_io import load_model

    m = load_model(SHIPPED)
    path = export_onnx(m, tmp_path_factory.mktemp("shipped") / "s64.onnx", 64, 64)
    return m, path, compare_onnx(m, path)


def test_documented_check_passes_on_the_shipped_weights(shipped_export):
    """`cosemdepth export --model weights/synthair-cosemdepth --check`: SynthAir frames, step by step on the same
    state, ONNX Runtime within a multiple of the drift of two float32 PyTorch runs that differ only in rounding."""
    m, path, report = shipped_export
    assert report.ok, report.summary()
    assert {c.output for c in report.criteria} == {"depth", "semantic", "state"}
    assert all(c.frames == list(range(6)) for c in report.criteria if c.metric == "normalised RMS")
    depth = report.criterion("depth")
    assert depth.noise[0] == depth.onnx[0] == 0.0  # a reset frame: the constant initial depth, exactly
    assert 0 < depth.worst <= depth.limit
    text = report.summary()
    assert text.endswith("OK") and "64x64" in text and "resets at frames 0,3" in text
    for c in report.criteria:  # what was compared, per output: metric, frames, floor, ONNX's figure, the limit
        assert f"{c.floor:8.2e}" in text and f"{c.worst:8.2e}" in text and f"{c.limit:8.2e}" in text
    assert f"within {NOISE_MULTIPLE:g} x that floor" in text


# Deliberately broken exports of the shipped weights at 64 px: (initializer, factor, element or None, the output
# that must go over its limit). At 64 px the limits are near 1e-5 and these changes move their output by 25-2000x
# that (a 0.1 % change of the semantic decoder's last convolution is the subtlest: about 25x).
BROKEN = [
    ("model.depth_decoder.levels.0.refiner.convs.6.weight", 1.01, None, "depth"),
    ("model.semantic_decoder.levels.0.refiner.convs.6.weight", 1.001, None, "semantic"),
    ("model.depth_decoder.levels.0.refiner.convs.6.weight", 1.01, (0, 0, 1, 1), "depth"),
]


@pytest.mark.parametrize("name, factor, index, output", BROKEN)
def test_check_fails_on_a_broken_export(shipped_export, tmp_path, name, factor, index, output):
    m, path, good = shipped_export
    bad = compare_onnx(m, perturbed_copy(path, tmp_path / "bad.onnx", name, factor, index))
    assert not bad.ok and bad.summary().endswith("MISMATCH")
    c = bad.criterion(output)
    assert c.worst > 10 * c.limit, bad.summary()  # far over: not a matter of this CPU's rounding
    assert "OVER on frame(s)" in bad.summary()
    # the floor is PyTorch's rounding: the broken graph moves it only through the incoming state it feeds back
    assert c.floor == pytest.approx(good.criterion(output).floor, rel=0.5)


def test_acceptance_rule_on_hand_made_figures():
    noise = [0.0, 1e-4, 3e-4]
    assert acceptance_limit(noise, multiple=4.0) == pytest.approx(1.2e-3)
    assert acceptance_limit([0.0, 0.0], multiple=4.0, absolute=1e-6) == 1e-6  # the runs agree exactly: the floor
    assert acceptance_limit([], absolute=1e-6) == 1e-6
    assert np.isnan(acceptance_limit([1e-4, float("nan")]))
    c = Criterion("depth", "normalised RMS", multiple=4.0, absolute=1e-6)
    for k, (o, n) in enumerate(zip([0.0, 5e-4, 1.1e-3], noise)):
        c.add(k, o, n)
    c.add(3, None, None)  # nothing to compare on that frame
    assert (c.frames, c.floor, c.worst, c.over, c.ok) == ([0, 1, 2], 3e-4, 1.1e-3, [], True)
    c.add(3, 1.3e-3, 1e-4)
    assert c.over == [3] and not c.ok
    for bad in (float("nan"), float("inf")):  # a non-finite distance is never within the limit
        d = Criterion("semantic", "normalised RMS")
        d.add(0, bad, 1e-4)
        assert not d.ok and d.over == [0]
    report = OnnxComparison(size=(8, 8), frames=4, resets=[0], criteria=[c])
    assert not report.ok and report.summary().endswith("MISMATCH") and "OVER on frame(s) 3" in report.summary()


def test_metrics_on_hand_made_arrays():
    b = np.array([[1.0, 2.0], [2.0, 4.0]])
    a = b * np.array([[1.0, 1.01], [1.0, 0.98]])
    # ||a - b|| = sqrt(0.02^2 + 0.08^2), ||b|| = 5
    assert nrms(a, b) == pytest.approx(np.hypot(0.02, 0.08) / 5)
    assert nrms(np.zeros(3), np.zeros(3)) == 0.0 and nrms(np.ones(3), np.zeros(3)) == pytest.approx(np.sqrt(3))
    assert nrms(np.array([1.0, np.nan]), np.array([1.0, 1.0])) == np.inf
    ok = np.array([[True, True], [True, False]])
    assert relative_percentile(a, b, ok, 100.0) == pytest.approx(0.01)  # 0.02 is at an invalid pixel
    # 0, 0, 0.01, 0.02: "higher" takes the observed value above the interpolation point
    assert relative_percentile(a, b, np.ones((2, 2), bool), 50.0) == pytest.approx(0.01)
    assert relative_percentile(a, b, np.zeros((2, 2), bool)) is None
    assert relative_percentile(np.array([np.nan, 1.0]), np.ones(2), np.ones(2, bool), 100.0) == np.inf
    depth = np.array([1.0, -1.0, np.inf, 2.0, 3.0, 4.0]).reshape(2, 1, 1, 3)
    assert valid_depth(depth, np.array([False, True])).ravel().tolist() == [True, False, False, False, False, False]


def test_sequential_spatial_mean_sums_in_float32_chains():
    """Hand-made: 1 followed by 2^-24's. One chain (the textbook loop) rounds every small term away (each addition
    ties to even at 1.0); with 4 lanes, lanes 1-3 sum their small terms exactly and only then meet the 1; float64
    keeps everything. 18 terms are padded with exact zeros to 20."""
    from cosemdepth.export.check import sequential_spatial_mean

    x = torch.full((1, 1, 3, 6), 2.0**-24)
    x[0, 0, 0, 0] = 1.0
    assert sequential_spatial_mean(x, lanes=1).item() == np.float32(1.0) / np.float32(18)
    # lane 0: 1 + 4 tiny terms (all lost); lanes 1-3: 13 tiny terms exactly (5+4+4); 1 + 13 * 2^-24 rounds to
    # 1 + 12 * 2^-24 (float32 spacing at 1 is 2^-23, ties to even)
    four = np.float32(1.0) + np.float32(5 * 2.0**-24) + np.float32(4 * 2.0**-24) + np.float32(4 * 2.0**-24)
    assert four == np.float32(1 + 12 * 2.0**-24)
    assert sequential_spatial_mean(x, lanes=4).item() == four / np.float32(18)
    assert sequential_spatial_mean(x.double(), lanes=4).item() == (1.0 + 17 * 2.0**-24) / 18
    assert sequential_spatial_mean(x).shape == (1, 1, 1, 1)
