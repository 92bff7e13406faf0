import pytest
import torch
import torch.nn.functional as F

from cosemdepth.inference import FastEngine, FastModel
from cosemdepth.inference.int8 import QTensor, QuantConv, Range, activation_qmax, has_int8, quantize, quantize_weight
from cosemdepth.models import build_model
from cosemdepth.ops.padding import Conv2dSame


def sequence(b=2, t=4, h=32, w=48, seed=0):
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(b * t, 3, h // 8, w // 8, generator=g)
    rgb = F.interpolate(coarse, size=(h, w), mode="bilinear").view(b, t, 3, h, w)
    q = F.normalize(torch.tensor([1.0, 0, 0, 0]) + 0.01 * torch.randn(b, t, 4, generator=g), dim=-1)
    tr = torch.tensor([0.05, -0.02, 1.0]) + 0.1 * torch.randn(b, t, 3, generator=g)
    K = torch.tensor([w / 2, h / 2, w / 2, h / 2]).expand(b, 4).contiguous()
    return rgb, q, tr, K


def tame(model, scale=0.1):
    """Damp the depth refiners' last layer of an untrained model (well-conditioned recurrence, as test_fast_engine)."""
    with torch.no_grad():
        for lvl in model.depth_decoder.levels:
            lvl.refiner.convs[-1].weight.mul_(scale)
    return model


def resets(b, t, extra=()):
    r = torch.zeros(b, t, dtype=torch.bool)
    r[:, 0] = True
    for i, k in extra:
        r[i, k] = True
    return r


pytestmark = pytest.mark.skipif(not has_int8(), reason="this PyTorch build has no oneDNN quantized convolution")


def frames(b=2, t=4, seed=0, extra=((1, 2),)):
    rgb, q, tr, K = sequence(b=b, t=t, seed=seed)
    rs = resets(b, t, extra=extra)
    return [(rgb[:, k], q[:, k], tr[:, k], K, rs[:, k]) for k in range(t)]


def test_range_qparams_hand_computed():
    assert Range(-1.0, 3.0).qparams() == pytest.approx((4 / 255, 64))  # round(1 / (4/255)) = round(63.75)
    assert Range(0.5, 2.0).qparams() == pytest.approx((2 / 255, 0))  # 0 always representable
    assert Range(-1.0, 3.0).qparams(127) == pytest.approx((4 / 127, 32))  # round(31.75): 7-bit activations
    with pytest.raises(RuntimeError, match="no data"):
        Range().qparams()


def test_activation_qmax_is_the_largest_input_whose_convolution_is_exact():
    """Where 8-bit activations would overflow the kernel's 16-bit pair sums (x86 without VNNI), 7 bits are used;
    either way a convolution at the chosen maximum gives the exact integer result."""
    qmax = activation_qmax()
    assert qmax in (127, 255)
    x = torch.full((1, 16, 3, 3), qmax, dtype=torch.uint8).contiguous(memory_format=torch.channels_last)
    w = torch.full((1, 16, 3, 3), 127, dtype=torch.int8)
    one = torch.ones(1)
    packed = torch.ops.onednn.qconv_prepack(w, one, 1.0, 0, [1, 1], [0, 0], [1, 1], 1, list(x.shape))
    y = torch.ops.onednn.qconv2d_pointwise(
        x,
        1.0,
        0,
        packed,
        one,
        torch.zeros(1, dtype=torch.int32),
        None,
        [1, 1],
        [0, 0],
        [1, 1],
        1,
        1e5,
        0,
        None,
        "none",
        [],
        "",
    )
    assert int(y.flatten()[0]) == round(qmax * 127 * 144 / 1e5)


def test_weight_quantisation_round_trip_within_half_a_step():
    w = torch.randn(5, 3, 3, 3)
    w[2] = 0.0
    q, s = quantize_weight(w)
    assert q.dtype == torch.int8 and q.abs().max() <= 127
    assert torch.all(q[2] == 0) and s[2] == 1.0
    assert torch.all((q.float() * s.view(-1, 1, 1, 1) - w).abs() <= s.view(-1, 1, 1, 1) / 2 + 1e-7)
    assert torch.allclose(q.float().abs().amax(dim=(1, 2, 3))[[0, 1, 3, 4]], torch.tensor(127.0))


def test_quant_conv_equals_the_float_conv_of_its_quantised_operands_up_to_output_rounding():
    torch.manual_seed(0)
    conv = Conv2dSame(8, 6, 3)
    x = F.leaky_relu(torch.randn(1, 8, 9, 11), 0.1)
    xr, yr = Range(), Range()
    xr.update(x)
    yr.update(conv(x))
    qc = QuantConv(conv, xr, yr)
    out = qc(x.clone())
    assert isinstance(out, QTensor) and out.q.dtype == torch.uint8
    xq = (quantize(x.clone(), qc.x_scale, qc.x_zp).q.float() - qc.x_zp) * qc.x_scale
    wq = qc.qw.float() * qc.w_scales.view(-1, 1, 1, 1)
    expect = F.leaky_relu(F.conv2d(xq, wq, conv.bias, padding=1), 0.1)
    # two roundings: the convolution's output to y_scale, the LeakyReLU's requantisation to out_scale
    bound = 0.5 * qc.y_scale + 0.5 * qc.out_scale + 1e-5
    assert (out.dequantize() - expect).abs().max() <= bound
    # padding is a real zero, not the zero point: the border pixels obey the same bound (checked above) and
    # the result is close to the plain float convolution on the scale of its range
    assert (out.dequantize() - F.leaky_relu(conv(x), 0.1)).abs().max() < 0.05 * (yr.hi - yr.lo)


def test_int8_engine_calibrates_on_the_first_frames_then_switches():
    torch.manual_seed(5)
    m = tame(build_model().eval())
    fp32 = FastEngine(m)
    eng = FastEngine(m, dtype="int8", calibration_frames=2)
    assert not eng.calibrated
    fs = frames(t=4)
    s8 = s32 = None
    for k, f in enumerate(fs):
        o8, s8 = eng.step(*f, state=s8)
        o32, s32 = fp32.step(*f, state=s32)
        if k < 2:  # calibration frames run the float32 refiners: the fp32 engine's results exactly
            assert torch.equal(o8.depth, o32.depth) and torch.equal(o8.semantic, o32.semantic)
    assert eng.calibrated
    assert type(eng.ops["semantic"][0].refiner.hidden[0]).__name__ == "QuantConv"
    assert type(eng.ops["depth"][0].refiner.hidden[0]).__name__ == "PackedConv"  # INT8_KEEP_FLOAT


def test_int8_step_contract_reset_logic_and_closeness():
    torch.manual_seed(5)
    m = tame(build_model().eval())
    fp32 = FastEngine(m)
    eng = FastEngine(m, dtype=torch.int8, calibration=frames(t=4, seed=1), int8_keep_float={})
    assert eng.calibrated and type(eng.ops["depth"][0].refiner.hidden[0]).__name__ == "QuantConv"
    fs = frames(t=4, seed=0, extra=((1, 2),))
    s8 = s32 = None
    for k, f in enumerate(fs):
        o8, s8 = eng.step(*f, state=s8)
        o32, s32 = fp32.step(*f, state=s32)
        assert o8.depth.dtype == torch.float32 and o8.semantic.dtype == torch.float32
        assert o8.depth.shape == o32.depth.shape and o8.semantic.shape == o32.semantic.shape
        assert list(s8.components) == list(s32.components)
        assert [t.shape for t in s8.flatten()] == [t.shape for t in s32.flatten()]
        reset = f[4]
        # a resetting sample of the temporal (depth) decoder outputs the init and the reset state, as in fp32,
        # whatever the precision of the refiners (the semantic decoder is stateless: it always refines)
        for i in torch.nonzero(reset).flatten().tolist():
            assert torch.equal(o8.depth[i], o32.depth[i]) and torch.all(o8.depth[i] == 1000.0)
            for a, b in zip(s8.flatten(), s32.flatten()):
                assert torch.equal(a[i], b[i])
        if k > 0 and not reset.all():
            live = ~reset
            agree = (o8.semantic[live].argmax(1) == o32.semantic[live].argmax(1)).float().mean()
            assert agree > 0.9, (k, agree)
            d8, d32 = o8.levels["parallax"][0][live], o32.levels["parallax"][0][live]
            assert ((d8 - d32).abs() / d32.abs().clamp_min(1e-6)).median() < 0.1, k
    # not silently float: int8 differs from fp32 on a frame that refines
    assert not torch.equal(o8.semantic, o32.semantic)


def test_int8_engine_bad_arguments():
    m = build_model().eval()
    with pytest.raises(ValueError, match="calibration sequence is empty"):
        FastEngine(m, dtype="int8", calibration=[])
    with pytest.raises(ValueError, match="calibration_frames"):
        FastEngine(m, dtype="int8", calibration_frames=0)
    with pytest.raises(
        ValueError, match=r"^dtype must be one of \[.*'fp32', 'int8'\] \(or the torch dtypes\), got 'int4'"
    ):
        FastEngine(m, dtype="int4")
    with pytest.raises(ValueError, match=r"^int8_float_dtype must be one of .*'fp32'\] .*got 'int8'"):
        FastEngine(m, dtype="int8", int8_float_dtype="int8")


def test_int8_through_the_fast_model():
    torch.manual_seed(5)
    m = tame(build_model().eval())
    fm = FastModel(m, "int8", calibration=frames(t=3, seed=1))
    assert fm.dtype == "int8" and fm.engine.int8 and fm.engine.calibrated
    out, state = fm.step(*frames(t=1, extra=())[0])
    assert out.depth.dtype == torch.float32


def test_int8_chains_quantised_convolutions_and_runs_kept_refiners_in_the_chosen_float_dtype(monkeypatch, bf16_cpu):
    import cosemdepth.inference.int8 as int8

    torch.manual_seed(6)
    m = tame(build_model(levels=3).eval())
    eng = FastEngine(m, dtype="int8", calibration=frames(t=3, seed=1), int8_float_dtype="bf16")
    for ref in (o.refiner for o in eng.ops["semantic"]):
        q = [c for c in ref.hidden if isinstance(c, QuantConv)]
        assert len(q) == 6
        assert all((b.x_scale, b.x_zp) == (a.out_scale, a.out_zp) for a, b in zip(q, q[1:]))
    # the depth levels 1-2 in the chosen float dtype; 3 (1/8 resolution) and coarser in float32 (FLOAT32_FROM_LEVEL)
    for lvl, o in zip(eng.decoders["depth"].levels, eng.ops["depth"]):
        want = torch.float32 if lvl.level >= 3 else torch.bfloat16
        assert [c.dtype for c in o.refiner.hidden] == [want] * 6, lvl.level
    # one quantisation per semantic refiner (its input), none between its convolutions
    calls = []
    real = int8.quantize
    monkeypatch.setattr(int8, "quantize", lambda *a: calls.append(1) or real(*a))
    f = frames(t=2, seed=2, extra=())
    _, s = eng.step(*f[0])
    calls.clear()
    eng.step(*f[1], state=s)
    assert len(calls) == len(eng.ops["semantic"])
    f32 = FastEngine(m, dtype="int8", calibration=frames(t=3, seed=1), int8_float_dtype="fp32")
    assert all(c.dtype == torch.float32 for o in f32.ops["depth"] for c in o.refiner.hidden)
    every = FastEngine(m, dtype="int8", calibration=frames(t=3, seed=1), int8_float_dtype="bf16", float32_levels={})
    assert all(c.dtype == torch.bfloat16 for o in every.ops["depth"] for c in o.refiner.hidden)


def test_equalization_scales_hand_computed():
    from cosemdepth.inference.int8 import equalization_scales

    w = torch.zeros(2, 3, 3, 3)
    w[0, 0, 1, 1], w[1, 1, 0, 0], w[0, 2, 2, 2] = -1.0, 4.0, 2.0  # max |w[:, c]| = 1, 4, 2
    s = equalization_scales(torch.tensor([4.0, 1.0, 0.0]), w, alpha=0.5)
    assert torch.allclose(s, torch.tensor([2.0, 0.5, 1.0]))  # sqrt(4 / 1), sqrt(1 / 4), dead channel -> 1
    s = equalization_scales(torch.tensor([4.0, 1.0, 3.0]), w, alpha=1.0)
    assert torch.allclose(s, torch.tensor([4.0, 1.0, 3.0]))  # alpha 1: every channel's range becomes 1


def test_equalized_chain_computes_the_same_function_with_even_channel_ranges():
    from cosemdepth.inference.int8 import ChannelRange, equalize_chain

    torch.manual_seed(3)
    convs = [Conv2dSame(5, 8, 3), Conv2dSame(8, 6, 3), Conv2dSame(6, 2, 3)]
    # channels of very different scales, as the refiners' concatenated input
    x = torch.randn(2, 5, 10, 12) * torch.tensor([100.0, 1.0, 0.01, 10.0, 0.1]).view(1, -1, 1, 1)

    def chain(cs, x):
        for c in cs[:-1]:
            x = F.leaky_relu(c(x), 0.1)
        return cs[-1](x)

    xr, yr = [ChannelRange(), ChannelRange()], [ChannelRange(), ChannelRange()]
    h = x
    with torch.no_grad():
        for k, c in enumerate(convs[:-1]):
            xr[k].update(h)
            y = c(h)
            yr[k].update(y)
            h = F.leaky_relu(y, 0.1)
        expect = chain(convs, x)
        w0, hi0 = convs[0].weight.clone(), xr[0].hi.clone()
        eq, xr2, yr2, in_mult = equalize_chain(convs, xr, yr, [True, True], alpha=0.5)
        got = chain(eq, x * in_mult)
    assert torch.allclose(got, expect, rtol=1e-4, atol=1e-4 * expect.abs().max())
    assert torch.equal(convs[0].weight, w0) and torch.equal(xr[0].hi, hi0)  # the inputs are left untouched
    # the predicted ranges are those of the equalised activations
    x2 = x * in_mult
    assert torch.allclose(xr2[0].hi, x2.amax(dim=(0, 2, 3)), rtol=1e-5)
    assert torch.allclose(yr2[0].lo, eq[0](x2).amin(dim=(0, 2, 3)).detach(), rtol=1e-4, atol=1e-5)

    # alpha 0.5: the input channels' ranges become sqrt(|x_c| max|w[:, c]|): their spread about the square root of
    # the 1e4 before (the weights' per-channel maxima of a fresh layer are within a factor ~2 of each other)
    def spread(r):
        return (r.absmax().max() / r.absmax().min()).item()

    w_spread = (lambda m: (m.max() / m.min()).item())(convs[0].weight.abs().amax(dim=(0, 2, 3)))
    assert spread(xr[0]) > 1e3
    assert spread(xr2[0]) <= (spread(xr[0]) * w_spread) ** 0.5 * 1.001
