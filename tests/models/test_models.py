import copy

import pytest
import torch

from cosemdepth.decoders.depth.decoder import refiner_in_channels
from cosemdepth.models import DINL, Refiner, StreamState, build_model
from cosemdepth.models.config import ModelConfig


@pytest.mark.parametrize(
    "overrides, expected",
    [
        (dict(arch="cosemdepth"), 5_202_528),
        (dict(arch="m4depth"), 3_059_881),
        (dict(arch="m4semantic"), 2_611_495),
        (dict(arch="cosemdepth", levels=4), 3_833_904),
        (dict(arch="m4depth", levels=4), 2_189_828),
        (dict(arch="cosemdepth", levels=6), 7_207_184),
        (dict(arch="m4depth", levels=6), 4_492_238),
        (dict(arch="m4semantic", levels=6), 3_737_138),
        (dict(arch="cosemdepth", num_classes=9), 5_215_498),
        (dict(arch="m4semantic", num_classes=12), 2_643_920),
        (dict(arch="cosemdepth", dinl=False), 5_202_528 - 32),
    ],
)
def test_parameter_counts_match_the_original(overrides, expected):
    assert build_model(**overrides).num_parameters() == expected


def test_refiner_parameter_formula_and_level_channels():
    for c_in, c_out in [(64, 5), (122, 5), (238, 5), (27, 11)]:
        assert sum(p.numel() for p in Refiner(c_in, c_out).parameters()) == 1152 * c_in + 336_848 + 145 * c_out
    cfg = ModelConfig()
    assert [refiner_in_channels(l, cfg) for l in range(1, 7)] == [64, 122, 122, 238, 238, 470]
    cfg = ModelConfig(sncv=False, time_recurrence=False, level_memory=False, feature_subdivision=False)
    assert [refiner_in_channels(l, cfg) for l in range(1, 4)] == [10, 10, 10]


def test_dinl_exactly_as_coded():
    x = torch.randn(2, 3, 4, 5, dtype=torch.float64)
    layer = DINL(3).double()
    with torch.no_grad():
        layer.weight.copy_(torch.tensor([1.0, 2.0, 3.0]))
        layer.bias.copy_(torch.tensor([0.5, 0.0, -1.0]))
    mu = x.mean(dim=(2, 3), keepdim=True)
    var = x.var(dim=(2, 3), unbiased=False, keepdim=True)
    z = (x - mu) / (var + 1e-12)  # the variance, not the std
    n = z / z.norm(dim=1, keepdim=True)
    expected = n * torch.tensor([1.0, 2.0, 3.0]).view(1, 3, 1, 1).double() + torch.tensor([0.5, 0, -1]).view(1, 3, 1, 1)
    torch.testing.assert_close(layer(x), expected)


def make_inputs(b=2, t=4, h=64, w=96, seed=0):
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(b, t, 3, h, w, generator=g)
    q = torch.tensor([1.0, 0.01, -0.02, 0.005]) + 0.01 * torch.randn(b, t, 4, generator=g)
    q = torch.nn.functional.normalize(q, dim=-1)
    tr = torch.tensor([0.05, -0.02, 1.0]) + 0.1 * torch.randn(b, t, 3, generator=g)
    K = torch.tensor([w / 2, h / 2, w / 2, h / 2]).expand(b, 4).contiguous()
    return rgb, q, tr, K


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(1)
    return build_model().eval()


def stream(model, rgb, q, tr, K, resets):
    state, outs = None, []
    with torch.no_grad():
        for k in range(rgb.shape[1]):
            out, state = model.step(rgb[:, k], q[:, k], tr[:, k], K, resets[:, k], state)
            outs.append(out)
    return outs, state


def test_streaming_equals_sequence_forward(model):
    rgb, q, tr, K = make_inputs(h=48, w=80)  # non-square
    with torch.no_grad():
        seq = model.forward_sequence(rgb, q, tr, K)
    resets = torch.zeros(2, 4, dtype=torch.bool)
    resets[:, 0] = True
    outs, _ = stream(model, rgb, q, tr, K, resets)
    for k, out in enumerate(outs):
        for j in range(5):
            assert torch.equal(out.levels["depth"][j], seq.depth[j][:, k])
            assert torch.equal(out.levels["parallax"][j], seq.maps("parallax")[j][:, k])
            assert torch.equal(out.levels["semantic"][j], seq.semantic[j][:, k])
        assert out.depth.shape == (2, 1, 48, 80) and out.semantic.shape == (2, 7, 48, 80)


def test_reset_frame_outputs_the_init_values(model):
    rgb, q, tr, K = make_inputs(t=1)
    with torch.no_grad():
        out, state = model.step(rgb[:, 0], q[:, 0], tr[:, 0], K, None, None)
    for j in range(5):
        assert torch.all(out.levels["depth"][j] == 1000.0)
        assert torch.all(out.levels["parallax"][j] == 2.0 ** (4 - j))
        assert torch.all(out.levels["depth_other"][j] == 0.0)
        assert torch.all(state.depths[j] == 1000.0)
    # the semantic decoder gives a real prediction on the first frame
    torch.testing.assert_close(out.semantic.sum(1), torch.ones(2, 64, 96))
    assert out.semantic.std() > 0


def test_per_sample_reset(model):
    """A reset in one sample of a batch restarts that sample alone: it then equals the same frames run as a batch of
    one. In float64: a batch of 2 and a batch of 1 may take convolution kernels that round differently in float32
    (on an AVX2-only CPU the recurrence made 4e-4 of that), which is not what this checks."""
    model = copy.deepcopy(model).double()
    rgb, q, tr, K = (x.double() for x in make_inputs(t=5))
    base = torch.zeros(2, 5, dtype=torch.bool)
    base[:, 0] = True
    resets = base.clone()
    resets[1, 2] = True  # sample 1 starts a new trajectory at frame 2
    plain, _ = stream(model, rgb, q, tr, K, base)
    mixed, _ = stream(model, rgb, q, tr, K, resets)
    fresh, _ = stream(model, rgb[1:, 2:], q[1:, 2:], tr[1:, 2:], K[1:], torch.tensor([[True, False, False]]))
    for k in range(5):
        assert torch.equal(mixed[k].depth[0], plain[k].depth[0])  # sample 0 continues unchanged
        assert torch.equal(mixed[k].semantic[0], plain[k].semantic[0])
    for k in range(2, 5):
        torch.testing.assert_close(mixed[k].depth[1:], fresh[k - 2].depth, rtol=1e-5, atol=1e-4)
        torch.testing.assert_close(mixed[k].semantic[1:], fresh[k - 2].semantic, rtol=1e-5, atol=1e-6)
    assert torch.all(mixed[2].depth[1] == 1000.0)
    assert not torch.allclose(mixed[3].depth[1], plain[3].depth[1])


def test_batch_one_reset_semantics_unchanged(model):
    # batch 1: the mask is the original's new_traj flag
    rgb, q, tr, K = make_inputs(b=1, t=3)
    r = torch.tensor([[True, False, True]])
    outs, _ = stream(model, rgb, q, tr, K, r)
    assert torch.all(outs[2].depth == 1000.0) and not torch.all(outs[1].depth == 1000.0)


def test_new_batch_size_or_resolution_needs_a_reset(model):
    rgb, q, tr, K = make_inputs(b=2, t=1)
    with torch.no_grad():
        _, state = model.step(rgb[:, 0], q[:, 0], tr[:, 0], K, None, None)
        rgb3, q3, tr3, K3 = make_inputs(b=3, t=1, h=32, w=32)
        with pytest.raises(ValueError, match="batch size or resolution"):
            model.step(rgb3[:, 0], q3[:, 0], tr3[:, 0], K3, torch.zeros(3, dtype=torch.bool), state)
        out, state = model.step(rgb3[:, 0], q3[:, 0], tr3[:, 0], K3, torch.ones(3, dtype=torch.bool), state)
        assert out.depth.shape == (3, 1, 32, 32) and state.batch_size == 3


def test_bad_argument_shapes_are_named(model):
    rgb, q, tr, K = make_inputs(t=1)
    with pytest.raises(ValueError, match="argument trans"):
        model.step(rgb[:, 0], q[:, 0], tr[:, 0, :2], K, None, None)
    with pytest.raises(ValueError, match="argument rgb"):
        model.step(rgb[:, 0, :2], q[:, 0], tr[:, 0], K, None, None)


@pytest.mark.parametrize("levels, classes, size", [(4, 3, (40, 56)), (6, 9, (64, 64)), (5, 12, (45, 80))])
def test_any_levels_classes_and_sizes(levels, classes, size):
    m = build_model(levels=levels, num_classes=classes).eval()
    h, w = size
    rgb, q, tr, K = make_inputs(b=1, t=3, h=h, w=w)
    with torch.no_grad():
        seq = m.forward_sequence(rgb, q, tr, K)
    assert len(seq.depth) == levels and seq.semantic[0].shape == (1, 3, classes, (h + 1) // 2, (w + 1) // 2)
    assert all(torch.isfinite(d).all() for d in seq.depth)
    out = m.infer(rgb[0], (q[0], tr[0]), K[0])
    assert out.depth.shape == (3, 1, h, w) and out.semantic.shape == (3, classes, h, w)


@pytest.mark.parametrize(
    "flag", ["dinl", "sncv", "time_recurrence", "feature_normalization", "feature_subdivision", "level_memory"]
)
def test_ablation_switches_run(flag):
    m = build_model(**{flag: False}).eval()
    rgb, q, tr, K = make_inputs(b=1, t=3, h=32, w=32)
    with torch.no_grad():
        seq = m.forward_sequence(rgb, q, tr, K)
    assert torch.isfinite(seq.depth[0]).all() and torch.isfinite(seq.semantic[0]).all()


def test_single_task_models():
    rgb, q, tr, K = make_inputs(b=1, t=2, h=32, w=32)
    d = build_model(arch="m4depth").eval()
    s = build_model(arch="m4semantic").eval()
    with torch.no_grad():
        od, st = d.step(rgb[:, 0], q[:, 0], tr[:, 0], K, None, None)
        os_, st2 = s.step(rgb[:, 0], q[:, 0], tr[:, 0], K, None, None)
    assert od.semantic is None and od.depth.shape == (1, 1, 32, 32) and len(st.features) == 5
    assert os_.depth is None and os_.semantic.shape == (1, 7, 32, 32) and st2 == StreamState()


def test_degenerate_inputs_give_no_nan(model):
    b, t, h, w = 2, 4, 32, 32
    rgb = torch.zeros(b, t, 3, h, w)  # constant image: zero-norm feature groups are possible
    rgb[1] = 0.5
    q = torch.tensor([1.0, 0, 0, 0]).expand(b, t, 4)
    tr = torch.zeros(b, t, 3)  # no motion at all: |delta| = 0 everywhere
    tr[1, :, 2] = 1000.0  # forward motion larger than any depth: d' <= t_z
    K = torch.tensor([16.0, 16, 16, 16]).expand(b, 4)
    with torch.no_grad():
        seq = model.forward_sequence(rgb, q, tr, K)
    for lst in (seq.depth, seq.maps("parallax"), seq.maps("depth_other"), seq.semantic):
        assert all(torch.isfinite(x).all() for x in lst)


def test_training_gradients_reach_the_encoder_and_stop_at_previous_depth():
    torch.manual_seed(0)
    m = build_model(levels=4)
    rgb, q, tr, K = make_inputs(b=1, t=3, h=32, w=32)
    seq = m.forward_sequence(rgb, q, tr, K)
    loss = sum(d[:, 1:].log().abs().mean() for d in seq.depth) + sum(
        s[:, 1:].mean() for s in seq.maps("semantic_logits")
    )
    loss.backward()
    grads = [p.grad for p in m.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert m.encoder.conv_s1[0].weight.grad.abs().sum() > 0
    # prev_d2para is stop-gradient: the previous frame's depth carries no gradient to the current loss
    m.zero_grad()
    rgb.requires_grad_(True)
    seq = m.forward_sequence(rgb, q, tr, K)
    seq.depth[0][:, 1].sum().backward()
    assert rgb.grad[:, 0].abs().sum() > 0  # through the previous features (PSCV)


def test_dinl_backward_matches_finite_differences_and_plain_ops():
    """DINL's hand-written backward against torch's numerical gradient (float64), and its float32 values and
    gradients against the plain ops of design 4.2 (the path ``export --check`` takes)."""
    g = torch.Generator().manual_seed(3)
    layer = DINL(4).double()
    with torch.no_grad():
        layer.weight.copy_(torch.tensor([1.0, -2.0, 0.5, 3.0]))
        layer.bias.copy_(torch.tensor([0.1, 0.0, -1.0, 2.0]))
    x = torch.randn(2, 4, 3, 5, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(layer, (x,))
    fused, plain = DINL(4), DINL(4)
    plain.spatial_mean = lambda t: t.mean(dim=(2, 3), keepdim=True)  # not the default: the plain ops run
    with torch.no_grad():
        for m in (fused, plain):
            m.weight.copy_(torch.tensor([1.0, -2.0, 0.5, 3.0]))
            m.bias.copy_(torch.tensor([0.1, 0.0, -1.0, 2.0]))
    x = torch.randn(2, 4, 16, 16, generator=g, requires_grad=True)
    wt = torch.randn(2, 4, 16, 16, generator=g)
    outs = []
    for m in (fused, plain):
        y = m(x)
        outs.append((y, *torch.autograd.grad((y * wt).sum(), (x, m.weight, m.bias))))
    for a, r in zip(*outs):
        torch.testing.assert_close(a, r, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("arch", ["cosemdepth", "m4semantic", "m4depth"])
def test_first_frame_skips_unwanted_work_and_changes_no_wanted_output_or_gradient(arch):
    """``forward_sequence(first_frame=1)`` (the trainer's): the stateless semantic decoder does not run on frame 0
    (its maps there are NaN), every output from frame 1 on and the gradient of a loss on them are those of the full
    run (float64, so summation order cannot hide a difference); the depth decoder runs every frame."""
    torch.manual_seed(3)
    m = build_model(arch=arch, levels=3).double().train()
    rgb, q, tr, K = (x.double() for x in make_inputs(b=2, t=3, h=32, w=32))
    calls = []
    if m.semantic_decoder is not None:
        m.semantic_decoder.levels[0].refiner.register_forward_hook(lambda mod, i, o: calls.append(o.shape[0]))
    grads, outs = [], []
    for first in (0, 1):
        calls.clear()
        m.zero_grad()
        seq = m.forward_sequence(rgb, q, tr, K, first_frame=first)
        maps = [*seq.depth, *seq.semantic] if arch != "m4depth" else list(seq.depth)
        loss = sum(x[:, 1:].square().mean() for x in maps)
        loss.backward()
        grads.append([p.grad.clone() for p in m.parameters()])
        outs.append([x[:, 1:] for x in maps])
        if m.semantic_decoder is not None:
            assert calls == [2 * (3 - first)]  # frames first..2 of both samples, one batched call
            assert bool(seq.semantic[0][:, :first].isnan().all()) and not bool(seq.semantic[0][:, first:].isnan().any())
        if m.depth_decoder is not None:
            assert torch.isfinite(seq.depth[0]).all()  # frame 0 too (the reset branch's constant)
    for a, b in zip(*outs):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=0)
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-15)
    with pytest.raises(ValueError, match="first_frame"):
        m.forward_sequence(rgb, q, tr, K, first_frame=3)
