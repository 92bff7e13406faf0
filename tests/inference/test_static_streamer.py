import pytest
import torch

from cosemdepth.inference import FastEngine
from cosemdepth.inference.graphs import StaticStreamer, make_streamer
from cosemdepth.models import build_model


def sequence(b, t, h, w, seed=0):
    g = torch.Generator().manual_seed(seed)
    rgb = torch.nn.functional.interpolate(
        torch.rand(b * t, 3, h // 8, w // 8, generator=g), size=(h, w), mode="bilinear"
    )
    q = torch.nn.functional.normalize(torch.tensor([1.0, 0, 0, 0]) + 0.01 * torch.randn(b, t, 4, generator=g), dim=-1)
    tr = torch.tensor([0.05, -0.02, 1.0]) + 0.1 * torch.randn(b, t, 3, generator=g)
    return rgb.view(b, t, 3, h, w), q, tr, torch.tensor([w / 2, h / 2, w / 2, h / 2]).expand(b, 4).contiguous()


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(7)
    m = build_model().eval()
    with torch.no_grad():  # well-conditioned depth (see tests/inference/test_fast_engine.py::tame)
        for lvl in m.depth_decoder.levels:
            lvl.refiner.convs[-1].weight.mul_(0.1)
    return m


def test_static_buffer_program_streams_like_model_step(model):
    b, t, h, w = 2, 5, 32, 48
    rgb, q, tr, K = sequence(b, t, h, w)
    reset = torch.zeros(b, t, dtype=torch.bool)
    reset[:, 0] = True
    reset[0, 3] = True  # one sample restarts mid-way
    streamer = make_streamer(model, b, h, w)
    assert streamer.graph is None and not streamer.use_graph  # CPU: the same program, run eagerly
    state = None
    with torch.no_grad():
        for k in range(t):
            ref, state = model.step(rgb[:, k], q[:, k], tr[:, k], K, reset[:, k], state)
            out = streamer.step(rgb[:, k], q[:, k], tr[:, k], K, reset[:, k])
            torch.testing.assert_close(out.depth, ref.depth, rtol=1e-3, atol=1e-3)
            torch.testing.assert_close(out.semantic, ref.semantic, rtol=0, atol=1e-5)
    assert torch.all(out.depth[0] != 1000.0)
    kept = streamer.current_state()
    for a, s in zip(kept.flatten(), state.flatten()):
        torch.testing.assert_close(a, s, rtol=1e-3, atol=1e-3)
    # the buffers are persistent: the state tensors are the same objects after every call
    ptrs = [t.data_ptr() for t in streamer.state.flatten()]
    streamer.step(rgb[:, 0], q[:, 0], tr[:, 0], K, torch.zeros(b, dtype=torch.bool))
    assert ptrs == [t.data_ptr() for t in streamer.state.flatten()]


def test_static_streamer_contract(model):
    with pytest.raises(ValueError, match="static=True"):
        StaticStreamer(FastEngine(model), 1, 32, 32)
    with pytest.raises(ValueError, match="CUDA"):
        make_streamer(model, 1, 32, 32, use_graph=True)
    s = make_streamer(model, 1, 32, 32)
    rgb, q, tr, K = sequence(1, 1, 32, 32)
    with pytest.raises(ValueError, match="first frame must reset"):
        s.step(rgb[:, 0], q[:, 0], tr[:, 0], K, torch.tensor([False]))
    with pytest.raises(ValueError, match="fixed at construction"):
        s.step(torch.zeros(1, 3, 32, 40), q[:, 0], tr[:, 0], K, torch.tensor([True]))
    out = s.step(rgb[:, 0], q[:, 0], tr[:, 0], K, torch.tensor([True]))
    assert torch.all(out.depth == 1000.0)
