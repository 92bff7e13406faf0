from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from cosemdepth.errors import ConfigError
from cosemdepth.export import export_onnx, state_names
from cosemdepth.export.check import compare_onnx, run_onnx_stream, synthetic_sequence
from cosemdepth.models import build_model

H, W = 32, 48


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(11)
    m = build_model().eval()
    with torch.no_grad():  # well-conditioned depth (see tests/inference/test_fast_engine.py::tame)
        for lvl in m.depth_decoder.levels:
            lvl.refiner.convs[-1].weight.mul_(0.1)
    m.optimize("fast")  # export must use (and then restore) the reference modules
    path = export_onnx(m, tmp_path_factory.mktemp("onnx") / "step.onnx", H, W, batch=2)
    return m, path


def test_graph_interface(exported):
    m, path = exported
    proto = onnx.load(str(path))
    onnx.checker.check_model(proto)
    assert max(o.version for o in proto.opset_import if o.domain in ("", "ai.onnx")) >= 16
    assert "GridSample" in {n.op_type for n in proto.graph.node}
    ins = [i.name for i in proto.graph.input]
    outs = [o.name for o in proto.graph.output]
    assert ins == ["rgb", "rot", "trans", "intrinsics", "reset", *state_names(5)]
    assert outs == ["depth", "semantic", *state_names(5, "next_state")]
    assert m.inference_mode == "fast" and not m.depth_decoder.static  # the model is given back as it was


def test_onnxruntime_matches_pytorch_over_streamed_frames_with_a_reset(exported):
    m, path = exported
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    b, t = 2, 7
    rgb, rot, trans, K = synthetic_sequence(b, t, H, W, seed=5)
    reset = torch.zeros(b, t, dtype=torch.bool)
    reset[:, 0] = True
    reset[1, 4] = True
    ort_state = [np.zeros(i.shape, np.float32) for i in sess.get_inputs()[5:]]  # first frame: zeros + reset
    m.optimize("reference")
    state = None
    try:
        with torch.no_grad():
            for k in range(t):
                ref, state = m.step(rgb[:, k], rot[:, k], trans[:, k], K, reset[:, k], state)
                feeds = {"rgb": rgb[:, k].numpy(), "rot": rot[:, k].numpy(), "trans": trans[:, k].numpy(),
                         "intrinsics": K.numpy(), "reset": reset[:, k].numpy()}
                res, ort_state = run_onnx_stream(sess, feeds, ort_state)
                d = ref.depth.numpy()
                assert np.max(np.abs(res["depth"] - d) / np.abs(d)) < 1e-3, k
                assert np.max(np.abs(res["semantic"] - ref.semantic.numpy())) < 1e-4, k
                for a, s in zip(ort_state, state.flatten()):
                    np.testing.assert_allclose(a, s.numpy(), rtol=1e-3, atol=1e-4)
    finally:
        m.optimize("fast")
    assert np.all(res["depth"][1] != 1000.0) and np.std(res["depth"]) > 0
    assert m.inference_mode == "fast"


def test_single_task_graphs_and_bad_opset(tmp_path):
    sem = build_model(arch="m4semantic", levels=2).eval()
    p = export_onnx(sem, tmp_path / "sem.onnx", 16, 16)
    sess = ort.InferenceSession(str(p), providers=["CPUExecutionProvider"])
    assert [i.name for i in sess.get_inputs()] == ["rgb"]  # no temporal input: the unused ones are dropped
    assert [o.name for o in sess.get_outputs()] == ["semantic"]
    x = torch.rand(1, 3, 16, 16)
    feeds = {"rgb": x.numpy(), "rot": np.array([[1, 0, 0, 0]], np.float32), "trans": np.zeros((1, 3), np.float32),
             "intrinsics": np.array([[8, 8, 8, 8]], np.float32), "reset": np.array([True])}
    with torch.no_grad():
        ref = sem.step(x, torch.tensor([[1.0, 0, 0, 0]]), torch.zeros(1, 3), torch.tensor([[8.0, 8, 8, 8]]))[0]
    res, state = run_onnx_stream(sess, feeds, [])
    assert state == []
    np.testing.assert_allclose(res["semantic"], ref.semantic.numpy(), atol=1e-5)
    with pytest.raises(ConfigError, match="opset"):
        export_onnx(sem, tmp_path / "x.onnx", 16, 16, opset=15)
    assert not (tmp_path / "x.onnx").exists()


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
        feeds = {"rgb": rgb[:, k].numpy(), "rot": rot[:, k].numpy(), "trans": trans[:, k].numpy(),
                 "intrinsics": K.numpy(), "reset": np.array([r], np.float32)}
        res, state = run_onnx_stream(sess, feeds, state)
        depths.append(res["depth"])
    assert np.all(depths[0] == 1000.0) and not np.all(depths[1] == 1000.0)
    report = compare_onnx(m, p, frames=6)  # what `cosemdepth export --check` runs
    assert len(report.depth_rel) == 6 and report.ok, report.summary()
    assert max(report.state_rel) < 1e-3


SHIPPED = Path(__file__).resolve().parents[2] / "weights" / "synthair-cosemdepth"


@pytest.fixture(scope="module")
def shipped_export(tmp_path_factory):
    from cosemdepth.io.model_io import load_model

    m = load_model(SHIPPED)
    path = export_onnx(m, tmp_path_factory.mktemp("shipped") / "s64.onnx", 64, 64)
    return m, path


def test_documented_check_passes_on_the_shipped_weights(shipped_export):
    """Issue 9: `cosemdepth export --model weights/synthair-cosemdepth --check` said MISMATCH (noise images and random
    poses made the recurrent depth chaotic; a picked 1e-3 max-relative tolerance). Now: SynthAir frames, step by
    step on the same state, a tolerance derived from float32-vs-float64 rounding noise of two summation orders."""
    m, path = shipped_export
    report = compare_onnx(m, path, frames=6)
    assert report.ok, report.summary()
    assert len(report.depth_rel) == len(report.semantic_rel) == len(report.state_rel) == 6
    assert report.depth_tol == max(report.depth_e) + max(report.depth_s) and max(report.depth_e) > 0
    assert report.semantic_tol == max(report.semantic_e) + max(report.semantic_s)
    # the sequentially summed normalisation means round more than PyTorch's pairwise sums
    assert max(report.semantic_s) > max(report.semantic_e) and max(report.state_s) > max(report.state_e)
    assert 0 < max(report.depth_rel) <= report.depth_tol and max(report.semantic_rel) <= report.semantic_tol
    assert "OK" in report.summary()


def _compare_with_changed_weight(m, path, decoder):
    """``compare_onnx`` after the last convolution of ``decoder``'s finest refiner was scaled by 1.001 (restored)."""
    w = getattr(m, f"{decoder}_decoder").levels[0].refiner.convs[-1].weight
    saved = w.detach().clone()
    try:
        with torch.no_grad():
            w.mul_(1.001)
        return compare_onnx(m, path, frames=4)
    finally:
        with torch.no_grad():
            w.copy_(saved)


def test_check_catches_a_real_difference(shipped_export):
    """A graph that computes something else (one weight of the PyTorch model changed by 0.1 %) is a MISMATCH."""
    report = _compare_with_changed_weight(*shipped_export, "depth")
    assert not report.ok and "MISMATCH" in report.summary()
    assert max(report.depth_rel) > report.depth_tol


def test_check_catches_a_real_semantic_difference(shipped_export):
    """The same for the semantic decoder: its last convolution's weights changed by 0.1 % is a MISMATCH on the
    semantic probabilities (the depth is untouched and stays within its tolerance)."""
    report = _compare_with_changed_weight(*shipped_export, "semantic")
    assert not report.ok and "MISMATCH" in report.summary()
    assert max(report.semantic_rel) > report.semantic_tol
    assert max(report.depth_rel) <= report.depth_tol


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
    four = (np.float32(1.0) + np.float32(5 * 2.0**-24) + np.float32(4 * 2.0**-24) + np.float32(4 * 2.0**-24))
    assert four == np.float32(1 + 12 * 2.0**-24)
    assert sequential_spatial_mean(x, lanes=4).item() == four / np.float32(18)
    assert sequential_spatial_mean(x.double(), lanes=4).item() == (1.0 + 17 * 2.0**-24) / 18
    assert sequential_spatial_mean(x).shape == (1, 1, 1, 1)
