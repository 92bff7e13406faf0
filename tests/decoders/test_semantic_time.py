"""The semantic decoder's temporal input S^{t-1}: the warp of the previous probabilities and its validity, resets,
frames the streaming policy holds, and the config switches."""

import pytest
import torch

from cosemdepth.decoders.semantic.decoder import (
    SemanticFrame,
    SemanticLevel,
    fuse_previous,
    semantic_refiner_in_channels,
)
from cosemdepth.errors import ConfigError
from cosemdepth.export.check import synthetic_sequence
from cosemdepth.models import build_model
from cosemdepth.models.config import ModelConfig

N = 7


def level1():
    return SemanticLevel(1, 16, ModelConfig(arch="cosemdepth-t", levels=2, num_classes=N))


def frame(trans, depth, fresh=None, intrinsics=(8.0, 8.0, 4.0, 2.0)):
    return SemanticFrame(
        torch.eye(3).unsqueeze(0),
        torch.tensor([trans]),
        torch.tensor([intrinsics]),
        fresh,
        None if depth is None else [depth],
    )


def test_a_sideways_step_reads_the_previous_probabilities_one_pixel_over_and_nothing_outside_the_view():
    # level 1 (4x2) of an 8x4 input with f = 8: f = 4 px, t_x = 1 m, depth 4 m -> every point was f t_x / d = 1 px
    # to the right
    h, w = 2, 4
    prev = torch.arange(N * h * w, dtype=torch.float32).view(1, N, h, w)
    depth = torch.full((1, 1, h, w), 4.0)
    warped, valid = level1().previous_probs(torch.zeros(1, 16, h, w), frame([1.0, 0.0, 0.0], depth), prev)
    assert valid[0, 0].tolist() == [[1, 1, 1, 0], [1, 1, 1, 0]]
    assert torch.equal(warped[..., :3], prev[..., 1:]) and not warped[..., 3].any()  # 0 where not valid


def test_no_previous_frame_or_a_reset_gives_an_empty_temporal_input():
    h, w = 2, 4
    lvl, f_hat = level1(), torch.zeros(2, 16, h, w)
    prev = torch.rand(2, N, h, w)
    depth = torch.full((2, 1, h, w), 4.0)
    fr = SemanticFrame(
        torch.eye(3).expand(2, 3, 3),
        torch.zeros(2, 3),
        torch.tensor([[8.0, 8.0, 4.0, 2.0]] * 2),
        torch.tensor([True, False]),
        [depth],
    )
    warped, valid = lvl.previous_probs(f_hat, fr, prev)
    assert not valid[0].any() and not warped[0].any()  # sample 0 resets
    assert valid[1].all() and torch.allclose(warped[1], prev[1])  # no motion: the previous map itself
    warped, valid = lvl.previous_probs(f_hat, fr, None)
    assert not valid.any() and not warped.any()


def test_without_depth_the_warp_follows_the_rotation_alone():
    # a frame the streaming policy holds has no depth of its own: every point at infinity, the translation ignored
    h, w = 2, 4
    prev = torch.rand(1, N, h, w)
    warped, valid = level1().previous_probs(torch.zeros(1, 16, h, w), frame([1.0, 0.0, 0.0], None), prev)
    assert valid.all() and torch.allclose(warped, prev)


def test_a_held_frame_keeps_the_semantic_state_of_the_reference_frame():
    torch.manual_seed(0)
    m = build_model(arch="cosemdepth-t", levels=2).eval()
    rgb, rot, trans, K = synthetic_sequence(1, 2, 32, 32, seed=1)
    with torch.no_grad():
        _, st = m.step(rgb[:, 0], rot[:, 0], trans[:, 0], K, torch.tensor([True]), None)
        out, held = m.step(rgb[:, 1], rot[:, 1], trans[:, 1], K, torch.tensor([False]), st, decoders=("semantic",))
        _, ran = m.step(rgb[:, 1], rot[:, 1], trans[:, 1], K, torch.tensor([False]), st)
    assert out.semantic is not None and out.depth is None
    assert held == st  # depth and semantic states both those of the reference frame
    assert not all(torch.equal(a, b) for a, b in zip(ran.components["semantic"], st.components["semantic"]))


def test_the_refiner_inputs_and_the_switches_rules():
    cfg = ModelConfig(levels=3, num_classes=N, semantic_sncv=True, semantic_time="own")
    assert semantic_refiner_in_channels(2, 32, cfg) == N + 4 + 32 + 49 + N + 1
    assert ModelConfig(arch="cosemdepth-t").semantic_time == "own" and ModelConfig().semantic_time == "off"
    assert ModelConfig(semantic_time="gt").needs_depth_input and not ModelConfig(arch="cosemdepth-t").needs_depth_input
    with pytest.raises(ConfigError, match="semantic_time must be one of"):
        ModelConfig(semantic_time="yes")
    with pytest.raises(ConfigError, match="has semantic_time 'own'"):
        ModelConfig(arch="cosemdepth-t", semantic_time="gt")
    with pytest.raises(ConfigError, match="no depth decoder"):
        ModelConfig(arch="m4semantic", semantic_time="own")
    with pytest.raises(ConfigError, match="no semantic decoder"):
        ModelConfig(arch="m4depth", semantic_sncv=True)


def test_the_ground_truth_variant_needs_a_depth_and_the_others_refuse_one():
    rgb, rot, trans, K = synthetic_sequence(1, 2, 32, 32, seed=1)
    gt = build_model(levels=2, semantic_time="gt").eval()
    with torch.no_grad(), pytest.raises(ValueError, match="guide_depth.*needs its depth"):
        gt.step(rgb[:, 0], rot[:, 0], trans[:, 0], K, torch.tensor([True]), None)
    with torch.no_grad(), pytest.raises(ValueError, match="takes no ground-truth depth"):
        build_model(arch="cosemdepth-t", levels=2).step(
            rgb[:, 0], rot[:, 0], trans[:, 0], K, None, None, guide_depth=torch.ones(1, 1, 32, 32)
        )


def test_fusion_by_hand():
    p = torch.tensor([0.8, 0.2]).view(1, 2, 1, 1).expand(1, 2, 1, 2).contiguous()
    w = torch.tensor([0.0, 1.0]).view(1, 2, 1, 1).expand(1, 2, 1, 2).contiguous()
    v = torch.tensor([1.0, 0.0]).view(1, 1, 1, 2)  # the second pixel's warp is not valid
    out = fuse_previous(p, w * v, v, 0.25)
    assert torch.allclose(out[0, :, 0, 0], torch.tensor([0.6, 0.4])) and torch.equal(out[0, :, 0, 1], p[0, :, 0, 1])


def test_fusion_switch_rules():
    assert ModelConfig(arch="cosemdepth-t", semantic_fusion=0.5).semantic_fusion == 0.5
    assert ModelConfig(semantic_time="gt", semantic_fusion=0).semantic_fusion == 0.0
    for bad in (1.0, -0.1, True, "0.5"):
        with pytest.raises(ConfigError, match=r"semantic_fusion must be a number in \[0, 1\)"):
            ModelConfig(arch="cosemdepth-t", semantic_fusion=bad)
    with pytest.raises(ConfigError, match="needs semantic_time 'own'"):
        ModelConfig(semantic_fusion=0.5)


def fused_pair(weight: float):
    torch.manual_seed(3)
    plain = build_model(arch="cosemdepth-t", levels=2).eval()
    fused = build_model(arch="cosemdepth-t", levels=2, semantic_fusion=weight).eval()
    fused.load_state_dict(plain.state_dict())  # no parameter of its own
    return plain, fused


def test_fusion_averages_the_output_with_the_warped_previous_output():
    """On a reset the output is the softmax; then, on the finest level, (1 - a V) P + a V W with W the previous
    fused output warped as the decoder warps it, V its validity; the coarser level and the depth untouched."""
    a = 0.4
    plain, fused = fused_pair(a)
    rgb, rot, trans, K = synthetic_sequence(1, 3, 32, 32, seed=4)
    with torch.no_grad():
        o0, s0 = fused.step(rgb[:, 0], rot[:, 0], trans[:, 0], K, torch.tensor([True]), None)
        p0, _ = plain.step(rgb[:, 0], rot[:, 0], trans[:, 0], K, torch.tensor([True]), None)
        assert torch.equal(o0.semantic, p0.semantic)  # nothing to average with on a reset
        # the next frame from the same state: the plain model gives P (and, through its level, W and V)
        o1, s1 = fused.step(rgb[:, 1], rot[:, 1], trans[:, 1], K, torch.tensor([False]), s0)
        p1, q1 = plain.step(rgb[:, 1], rot[:, 1], trans[:, 1], K, torch.tensor([False]), s0)
    assert torch.equal(o1.depth, p1.depth)
    assert torch.equal(s1.components["semantic"][1], q1.components["semantic"][1])  # level 2 untouched
    lvl = fused.semantic_decoder.levels[0]
    dec = fused.semantic_decoder
    frame = dec.frame(rot[:, 1], trans[:, 1], K, torch.tensor([False]), {dec.reads[0]: o1.levels[dec.reads[0]]})
    h, w = s0.components["semantic"][0].shape[-2:]
    warped, valid = lvl.previous_probs(torch.zeros(1, 1, h, w), frame, s0.components["semantic"][0])
    assert 0 < valid.mean() < 1
    expected = (1 - a * valid) * q1.components["semantic"][0] + a * warped
    assert torch.allclose(s1.components["semantic"][0], expected, atol=1e-6)
    assert torch.allclose(s1.components["semantic"][0].sum(1), torch.ones(1, h, w), atol=1e-5)


def test_fusion_in_the_fast_path_and_the_onnx_graph(tmp_path):
    import numpy as np
    import onnxruntime as ort

    from cosemdepth.export import export_onnx
    from cosemdepth.inference import FastModel

    _, fused = fused_pair(0.5)
    with torch.no_grad():  # well-conditioned depth (see tests/inference/test_fast_engine.py::tame)
        for lvl in fused.depth_decoder.levels:
            lvl.refiner.convs[-1].weight.mul_(0.1)
    rgb, rot, trans, K = synthetic_sequence(1, 4, 32, 32, seed=6)
    fast = FastModel(fused, "float32")
    path = export_onnx(fused, tmp_path / "fused.onnx", 32, 32)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = [i.name for i in sess.get_inputs()]
    outs = [o.name for o in sess.get_outputs()]
    st_ref = st_fast = None
    st_onnx = [np.zeros(i.shape, np.float32) for i in sess.get_inputs()[5:]]
    with torch.no_grad():
        for t in range(4):
            args = (rgb[:, t], rot[:, t], trans[:, t], K, torch.tensor([t == 0]))
            ref, st_ref = fused.step(*args, st_ref)
            fo, st_fast = fast.step(*args, st_fast)
            feeds = dict(zip(names, [a.numpy() for a in args] + st_onnx))
            res = dict(zip(outs, sess.run(None, feeds)))
            st_onnx = [res["next_" + n] for n in names[5:]]
            assert torch.allclose(fo.semantic, ref.semantic, atol=1e-5), t
            assert np.allclose(res["semantic"], ref.semantic.numpy(), atol=1e-4), t
