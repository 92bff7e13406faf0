"""Every registered architecture through the same checks: forward/backward, streaming == sequence, save/load round
trip, ONNX export run by ONNX Runtime, fast path == reference; a toy third decoder registered at run time (temporal,
with its own state) goes through them too, and so do the semantic decoder's switches (SNCV; S^{t-1} warped with the
ground-truth depth, which every pass is given and which the export refuses)."""

from dataclasses import dataclass

import numpy as np
import onnxruntime as ort
import pytest
import torch

from cosemdepth.checkpoints.model_io import load_model, save_model
from cosemdepth.errors import ConfigError
from cosemdepth.export import export_onnx
from cosemdepth.export.check import run_onnx_stream, synthetic_sequence
from cosemdepth.inference import FastModel
from cosemdepth.models import build_model
from cosemdepth.models.config import ARCHITECTURES
from cosemdepth.models.layers import Refiner
from cosemdepth.models.pyramid import PyramidDecoder, PyramidLevel
from cosemdepth.models.registry import register, register_architecture, unregister

B, T, H, W = 2, 3, 32, 48
LEVELS = 3
BUILTIN = ("cosemdepth", "m4depth", "m4semantic", "cosemdepth-t")


@dataclass
class ToyLevelOutput:
    probs: torch.Tensor
    logits: torch.Tensor


class ToyLevel(PyramidLevel):
    """A temporal 3-class segmentation level: the refiner sees the features, the coarser level's probabilities
    and this level's probabilities of the previous frame."""

    def __init__(self, level, channels, cfg):
        super().__init__()
        self.level = level
        self.refiner = Refiner(channels + 6, 3)

    def coarse_inputs(self, coarse, f_hat, ops):
        b, _, h, w = f_hat.shape
        p = f_hat.new_full((b, 3, h, w), 1 / 3) if coarse is None else ops.nearest(coarse.probs, (h, w))
        return ToyLevelOutput(p, torch.log(p))

    def refine(self, f_hat, inputs, frame, prev, ops):
        logits = (ops.refiner or self.refiner)(ops.concat([f_hat, inputs.probs, prev[0]]))
        return ToyLevelOutput(torch.softmax(logits, 1), logits)

    def next_state(self, f_hat, out):
        return (out.probs,)

    def reset_state(self, f_hat, inputs):
        return (inputs.probs,)


class ToyDecoder(PyramidDecoder):
    level_class = ToyLevel
    state_names = ("toy_probs",)
    maps = {"toy": "probs", "toy_logits": "logits"}
    head = "toy"

    def level_state_shapes(self, level, batch, h, w):
        return ((batch, 3, h, w),)


@pytest.fixture(scope="module", autouse=True)
def toy_registered():
    register("toy", ToyDecoder)  # the module alone (no task): enough for the model checks
    register_architecture("cosemtoy", ("depth", "semantic", "toy"))
    yield
    unregister("toy")
    assert "cosemtoy" not in ARCHITECTURES


#: Model-config variants that go through the same checks: name -> build_model keywords.
SWITCHES = {
    "cosemdepth+sncv": dict(arch="cosemdepth", semantic_sncv=True),
    "cosemdepth+s_prev_gt": dict(arch="cosemdepth", semantic_time="gt"),
}
ARCHS = [*BUILTIN, "cosemtoy", *SWITCHES]


def test_the_registry_lists_the_architectures_and_the_toy_one():
    assert set(BUILTIN) <= set(ARCHITECTURES) and ARCHITECTURES["cosemtoy"] == ("depth", "semantic", "toy")
    m = build_model(arch="cosemtoy", levels=LEVELS)
    assert list(m.decoders) == ["depth", "semantic", "toy"] and m.toy_decoder is m.decoders["toy"]
    assert any(k.startswith("toy_decoder.levels.2.refiner.") for k in m.state_dict())
    assert build_model(arch="m4depth").semantic_decoder is None  # the old slot names stay
    assert m.state_shapes(1, H, W)["toy_probs"] == [(1, 3, 16, 24), (1, 3, 8, 12), (1, 3, 4, 6)]


@pytest.fixture(scope="module")
def models():
    out = {}
    for arch in ARCHS:
        torch.manual_seed(7)
        m = build_model(levels=LEVELS, **SWITCHES.get(arch, dict(arch=arch))).eval()
        if m.depth_decoder is not None:  # well-conditioned depth (see tests/inference/test_fast_engine.py::tame)
            with torch.no_grad():
                for lvl in m.depth_decoder.levels:
                    lvl.refiner.convs[-1].weight.mul_(0.1)
        out[arch] = m
    return out


def inputs(seed=3):
    rgb, rot, trans, K = synthetic_sequence(B, T, H, W, seed=seed)
    reset = torch.zeros(B, T, dtype=torch.bool)
    reset[:, 0] = True
    reset[1, 2] = True  # sample 1 restarts at the last frame
    return rgb, rot, trans, K, reset


def guide(model, rgb, seed=0):
    """A ground-truth depth per frame ``[B, T, 1, H, W]`` (10-60 m) for a model that reads one, else None."""
    if not model.config.needs_depth_input:
        return None
    g = torch.Generator().manual_seed(seed)
    return 10.0 + 50.0 * torch.rand(*rgb.shape[:2], 1, *rgb.shape[-2:], generator=g)


def stream(model, rgb, rot, trans, K, reset, depth=None):
    state, outs = None, []
    with torch.no_grad():
        for k in range(rgb.shape[1]):
            kw = {} if depth is None else {"guide_depth": depth[:, k]}
            out, state = model.step(rgb[:, k], rot[:, k], trans[:, k], K, reset[:, k], state, **kw)
            outs.append(out)
    return outs, state


@pytest.mark.parametrize("arch", ARCHS)
def test_forward_backward_reaches_every_parameter(models, arch):
    m = models[arch]
    rgb, rot, trans, K, reset = inputs()
    m.train()
    try:
        seq = m.forward_sequence(rgb, rot, trans, K, reset, guide_depth=guide(m, rgb))
        maps = [seq.maps(dec.head) for dec in m.decoders.values()]
        loss = sum(x.float().mean() for lvls in maps for x in lvls)
        m.zero_grad()
        loss.backward()
    finally:
        m.eval()
    grads = {n: p.grad for n, p in m.named_parameters()}
    assert all(g is not None and torch.isfinite(g).all() for g in grads.values()), arch
    for name in m.decoders:  # every decoder's refiners learn
        assert any(g.abs().sum() > 0 for n, g in grads.items() if n.startswith(f"{name}_decoder.")), name
    m.zero_grad(set_to_none=True)


@pytest.mark.parametrize("arch", ARCHS)
def test_streaming_equals_sequence(models, arch):
    m = models[arch]
    rgb, rot, trans, K, reset = inputs()
    depth = guide(m, rgb)
    with torch.no_grad():
        seq = m.forward_sequence(rgb, rot, trans, K, reset, guide_depth=depth)
    outs, _ = stream(m, rgb, rot, trans, K, reset, depth)
    keys = [k for dec in m.decoders.values() for k in dec.maps]
    for k, out in enumerate(outs):
        assert set(out.levels) == set(keys) and list(out.heads) == [d.head for d in m.decoders.values()]
        for key in keys:
            seq_maps = seq.maps(key)
            for j in range(LEVELS):
                assert torch.equal(out.levels[key][j], seq_maps[j][:, k]), (arch, key, j, k)
        for head, full in out.heads.items():
            assert full.shape[-2:] == (H, W) and torch.equal(full[..., ::2, ::2], out.levels[head][0])


@pytest.mark.parametrize("arch", ARCHS)
def test_save_load_round_trip(models, arch, tmp_path):
    m = models[arch]
    save_model(m, tmp_path / arch)
    back = load_model(tmp_path / arch, mode="reference")  # the same modules: bit-identical outputs
    assert back.config == m.config
    sd, sd2 = m.state_dict(), back.state_dict()
    assert sd.keys() == sd2.keys() and all(torch.equal(sd[k], sd2[k]) for k in sd)
    rgb, rot, trans, K, reset = inputs(seed=4)
    a, _ = stream(m, rgb, rot, trans, K, reset, guide(m, rgb))
    b, _ = stream(back, rgb, rot, trans, K, reset, guide(m, rgb))
    for x, y in zip(a, b):
        assert x.heads.keys() == y.heads.keys() and all(torch.equal(x.heads[h], y.heads[h]) for h in x.heads)


@pytest.mark.parametrize("arch", ARCHS)
def test_onnx_export_runs_in_onnxruntime_like_pytorch(models, arch, tmp_path):
    m = models[arch]
    if m.config.needs_depth_input:  # a training- and evaluation-time variant: refused, nothing written
        with pytest.raises(ConfigError, match="ground-truth depth.*not exported"):
            export_onnx(m, tmp_path / f"{arch}.onnx", H, W, batch=B)
        assert not list(tmp_path.iterdir())
        return
    path = export_onnx(m, tmp_path / f"{arch}.onnx", H, W, batch=B)
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    heads = [d.head for d in m.decoders.values()]
    assert [o.name for o in sess.get_outputs()][: len(heads)] == heads
    rgb, rot, trans, K, reset = inputs()
    ort_state = [np.zeros(i.shape, np.float32) for i in sess.get_inputs() if i.name.startswith("state_")]
    ref, _ = stream(m, rgb, rot, trans, K, reset)
    for k in range(T):
        feeds = {
            "rgb": rgb[:, k].numpy(),
            "rot": rot[:, k].numpy(),
            "trans": trans[:, k].numpy(),
            "intrinsics": K.numpy(),
            "reset": reset[:, k].numpy(),
        }
        res, ort_state = run_onnx_stream(sess, feeds, ort_state)
        for h in heads:
            want = ref[k].heads[h].numpy()
            if h == "depth":
                assert np.max(np.abs(res[h] - want) / np.abs(want)) < 1e-3, (arch, k)
            else:
                assert np.max(np.abs(res[h] - want)) < 1e-4, (arch, h, k)


@pytest.mark.parametrize("arch", ARCHS)
def test_fast_path_equals_reference(models, arch):
    m = models[arch]
    rgb, rot, trans, K, reset = inputs(seed=5)
    depth = guide(m, rgb)
    ref, ref_state = stream(m, rgb, rot, trans, K, reset, depth)
    fast, fast_state = stream(FastModel(m), rgb, rot, trans, K, reset, depth)
    for a, b in zip(fast, ref):
        for key, maps in b.levels.items():
            for x, y in zip(a.levels[key], maps):
                torch.testing.assert_close(x, y, rtol=1e-4, atol=1e-4)
    assert fast_state.components.keys() == ref_state.components.keys()
    for x, y in zip(fast_state.flatten(), ref_state.flatten()):
        torch.testing.assert_close(x, y, rtol=1e-4, atol=1e-4)
