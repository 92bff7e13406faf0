"""The streaming paths on every device this machine has (the CPU; CUDA too where present, which is what
``scripts/gpu_check.sh`` runs): the fast engine and the static-buffer streamer (a CUDA graph on GPU) stream like the
reference modules on the CPU, and the reduced precisions of the device stay close to float32."""

import copy

import pytest
import torch

from cosemdepth.export.check import synthetic_sequence
from cosemdepth.inference import FastModel
from cosemdepth.inference.graphs import make_streamer
from cosemdepth.models import build_model
from cosemdepth.models.config import ModelConfig

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
B, T, H, W = 1, 4, 32, 32


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(3)
    m = build_model(ModelConfig(levels=3)).eval()
    with torch.no_grad():  # well-conditioned depth (see tests/inference/test_fast_engine.py::tame)
        for lvl in m.depth_decoder.levels:
            lvl.refiner.convs[-1].weight.mul_(0.1)
    return m


@pytest.fixture(scope="module")
def reference(model):
    """The reference modules' outputs on the CPU in float32, streamed over the sequence (frame 0 resets)."""
    rgb, q, tr, K = synthetic_sequence(B, T, H, W, seed=2)
    outs, state = [], None
    with torch.no_grad():
        for k in range(T):
            out, state = model.step(rgb[:, k], q[:, k], tr[:, k], K, torch.tensor([k == 0]), state)
            outs.append((out.depth.clone(), out.semantic.clone()))
    return (rgb, q, tr, K), outs


def _no_tf32():
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("path", ["fast", "static"])
def test_fp32_paths_stream_like_the_reference_on_the_cpu(model, reference, device, path):
    _no_tf32()
    (rgb, q, tr, K), ref = reference
    m = copy.deepcopy(model).to(device)
    if path == "fast":
        step = FastModel(m, dtype=torch.float32).step
    else:
        streamer = make_streamer(m, B, H, W, device=device)
        assert streamer.use_graph == (device == "cuda")
        step = lambda *a: (streamer.step(*a[:5]), None)  # noqa: E731
    state = None
    with torch.no_grad():
        for k in range(T):
            args = [t.to(device) for t in (rgb[:, k], q[:, k], tr[:, k], K, torch.tensor([k == 0]))]
            out, state = step(*args, state)
            torch.testing.assert_close(out.depth.cpu(), ref[k][0], rtol=1e-3, atol=1e-3)
            torch.testing.assert_close(out.semantic.cpu(), ref[k][1], rtol=0, atol=1e-4)


@pytest.mark.parametrize(
    "device,dtype",
    [(d, t) for d in DEVICES for t in ((torch.bfloat16,) if d == "cpu" else (torch.float16, torch.bfloat16))],
)
def test_reduced_precision_stays_close_to_fp32(model, reference, device, dtype):
    from cosemdepth.devices import bf16_convolutions

    (rgb, q, tr, K), ref = reference
    if dtype == torch.bfloat16 and not bf16_convolutions(device):  # e.g. an AVX2-only CPU: refused in one line
        with pytest.raises(ValueError, match="bfloat16 needs bfloat16 convolutions"):
            FastModel(copy.deepcopy(model).to(device), dtype=dtype)
        return
    m = FastModel(copy.deepcopy(model).to(device), dtype=dtype)
    with torch.no_grad():  # one reset frame and one step from the reference's state: no compounding
        out, _ = m.step(*(t.to(device) for t in (rgb[:, 0], q[:, 0], tr[:, 0], K, torch.tensor([True]))))
        torch.testing.assert_close(out.semantic.float().cpu(), ref[0][1], rtol=0, atol=0.02)
