"""``model.infer`` (whole sequence) against ``model.step`` (frame by frame), the five-line API."""

import numpy as np
import pytest
import torch

from cosemdepth import build_model, load_model, save_model


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    old = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny tensors: more threads only cost time on a busy machine
    yield
    torch.set_num_threads(old)


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return build_model(levels=3).eval()


def inputs(b=2, t=5, h=32, w=48, seed=1):
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(b, t, 3, h, w, generator=g)
    q = torch.nn.functional.normalize(
        torch.tensor([1.0, 0.0, 0.0, 0.0]) + 0.02 * torch.randn(b, t, 4, generator=g), dim=-1
    )
    tr = torch.tensor([0.0, 0.0, 1.0]) + 0.1 * torch.randn(b, t, 3, generator=g)
    K = torch.tensor([w / 2, h / 2, w / 2, h / 2]).expand(b, 4).contiguous()
    return rgb, q, tr, K


def by_steps(model, rgb, q, tr, K, reset):
    state, depth, sem = None, [], []
    with torch.no_grad():
        for k in range(rgb.shape[1]):
            out, state = model.step(rgb[:, k], q[:, k], tr[:, k], K, reset[:, k], state)
            depth.append(out.depth)
            sem.append(out.semantic)
    return torch.stack(depth, 1), torch.stack(sem, 1)


def test_infer_equals_step_by_step(model):
    rgb, q, tr, K = inputs()
    reset = torch.zeros(2, 5, dtype=torch.bool)
    reset[:, 0] = True
    d, s = by_steps(model, rgb, q, tr, K, reset)
    out = model.infer(rgb, (q, tr), K)
    assert out.depth.shape == (2, 5, 1, 32, 48) and out.semantic.shape == (2, 5, 7, 32, 48)
    torch.testing.assert_close(out.depth, d, rtol=0, atol=0)
    torch.testing.assert_close(out.semantic, s, rtol=0, atol=0)
    # class labels of every frame of every sample: the class axis is reduced, not the time axis
    assert out.labels.shape == (2, 5, 32, 48)
    for k in range(5):
        torch.testing.assert_close(out.labels[:, k], s[:, k].argmax(1), rtol=0, atol=0)
    # frame 0 is a reset: the initial depth of 1000 m everywhere (design 5.4), whatever the motion given for it
    assert torch.all(out.depth[:, 0] == 1000.0)


def test_infer_single_sequence_numpy_and_packed_motions(model):
    rgb, q, tr, K = inputs(b=1)
    ref = model.infer(rgb, (q, tr), K)
    packed = np.concatenate([q[0].numpy(), tr[0].numpy()], axis=-1)  # [T, 7] = qw qx qy qz tx ty tz
    out = model.infer(rgb[0].numpy(), packed, K[0].numpy())
    assert out.depth.shape == (5, 1, 32, 48)
    torch.testing.assert_close(out.depth, ref.depth[0], rtol=0, atol=0)
    torch.testing.assert_close(out.labels, ref.semantic[0].argmax(1), rtol=0, atol=0)


def test_infer_with_a_reset_in_the_middle(model):
    rgb, q, tr, K = inputs(b=1, t=6)
    reset = torch.tensor([False, False, False, True, False, False])
    out = model.infer(rgb[0], (q[0], tr[0]), K[0], reset=reset)
    # the frames after the reset are those of a fresh sequence starting there
    fresh = model.infer(rgb[0, 3:], (q[0, 3:], tr[0, 3:]), K[0])
    torch.testing.assert_close(out.depth[3:], fresh.depth, rtol=0, atol=0)
    full = torch.zeros(1, 6, dtype=torch.bool)
    full[0, 0] = full[0, 3] = True
    d, _ = by_steps(model, rgb, q, tr, K, full)
    torch.testing.assert_close(out.depth, d[0], rtol=0, atol=0)


@pytest.mark.parametrize("bad", [[0.0, 0.0, 0.0, 0.0], [float("nan"), 0.0, 0.0, 1.0], [float("inf"), 0.0, 0.0, 0.0]])
def test_a_zero_or_non_finite_quaternion_is_refused_naming_the_sample(model, bad):
    rgb, q, tr, K = inputs(b=2, t=3)
    rot = q[:, 1].clone()
    rot[1] = torch.tensor(bad)
    with pytest.raises(ValueError, match=r"^argument rot: sample 1 is not a rotation quaternion .*zero or non-finite"):
        model.step(rgb[:, 1], rot, tr[:, 1], K, torch.tensor([False, False]))
    model.step(rgb[:, 1], rot, tr[:, 1], K, torch.tensor([False, True]))  # a reset ignores the motion: accepted
    seq = q.clone()
    seq[1, 2] = torch.tensor(bad)
    with pytest.raises(ValueError, match=r"argument rot: sample 1 is .* \(frame 2 of the sequence\)$"):
        model.infer(rgb, (seq, tr), K)
    seq = q.clone()
    seq[:, 0] = torch.tensor(bad)
    assert model.infer(rgb, (seq, tr), K).depth.shape == (2, 3, 1, 32, 48)  # frame 0's motion is ignored
    with pytest.raises(ValueError, match="argument trans: sample 0 is not a finite translation"):
        model.step(rgb[:, 1], q[:, 1], torch.full((2, 3), float("nan")), K, torch.tensor([False, False]))


def test_the_five_lines_on_a_saved_model(model, tmp_path):
    save_model(model, tmp_path / "m")
    rgb, q, tr, K = inputs(b=1, t=3)
    loaded = load_model(tmp_path / "m", mode="reference")  # bit-identical to `model`; the default fast path:
    state = None  # tests/inference/test_fast_engine.py
    for k in range(3):
        out, state = loaded.step(rgb[:, k], q[:, k], tr[:, k], K, torch.tensor([k == 0]), state)
    ref = model.infer(rgb, (q, tr), K)
    torch.testing.assert_close(out.depth, ref.depth[:, 2], rtol=0, atol=0)
    torch.testing.assert_close(out.labels, ref.semantic[:, 2].argmax(1), rtol=0, atol=0)
