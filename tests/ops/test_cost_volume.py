import pytest
import torch

from cosemdepth.geometry.warp import sample_bilinear
from cosemdepth.ops.cost_volume import (
    parallax_sweep_cost_volume,
    spatial_cost_volume,
    spatial_cost_volume_fast,
)


def test_sncv_hand_computed_single_channel():
    # one channel, one group, radius 1: corr_d(p) = f(p) f(p + d), zero outside, LeakyReLU(0.1)
    f = torch.tensor([[1.0, 2.0], [3.0, -4.0]]).view(1, 1, 2, 2)
    out = spatial_cost_volume_fast(f, groups=1, radius=1).view(3, 3, 2, 2)
    expected = torch.zeros(3, 3, 2, 2)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            for y in range(2):
                for x in range(2):
                    yy, xx = y + dy, x + dx
                    if 0 <= yy < 2 and 0 <= xx < 2:
                        v = f[0, 0, y, x] * f[0, 0, yy, xx]
                        expected[dy + 1, dx + 1, y, x] = v if v > 0 else 0.1 * v
    torch.testing.assert_close(out, expected)
    assert out[1, 1, 1, 1] == 16.0  # centre offset: f^2
    assert out[2, 2, 0, 0] == pytest.approx(-0.4)  # 1 * -4 through the LeakyReLU


@pytest.mark.parametrize(
    "shape, groups, radius",
    [((2, 16, 9, 13), 1, 3), ((1, 32, 6, 5), 2, 3), ((1, 24, 2, 3), 4, 3), ((1, 8, 1, 1), 2, 3), ((2, 6, 7, 4), 3, 1)],
)
def test_sncv_fast_equals_reference(shape, groups, radius):
    x = torch.randn(shape)
    ref = spatial_cost_volume(x, groups, radius)
    fast = spatial_cost_volume_fast(x.contiguous(memory_format=torch.channels_last), groups, radius)
    assert fast.shape == ref.shape
    torch.testing.assert_close(fast, ref, rtol=1e-5, atol=1e-6)


def _grid_points(b, s, h, w, shift=(0.0, 0.0)):
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij")
    pts = torch.stack([xs + shift[0], ys + shift[1]])  # [2,H,W]
    return pts.expand(b, s, 2, h, w).clone()


@pytest.mark.parametrize("h, w", [(5, 6), (40, 30)])  # below / above PSCV_LOOP_MIN_PIXELS: product form / loop
def test_pscv_identity_warp_is_group_mean_of_products(h, w):
    b, c, k = 1, 8, 2
    f, prev = torch.randn(b, c, h, w), torch.randn(b, c + 1, h, w)
    with torch.no_grad():
        pscv, warped_para = parallax_sweep_cost_volume(f, prev, _grid_points(b, 3, h, w), k)
    expected = (f * prev[:, :c]).view(b, k, c // k, h, w).mean(2)  # [B,K,H,W], same for all 3 hypotheses
    torch.testing.assert_close(pscv.view(b, k, 3, h, w), expected.unsqueeze(2).expand(b, k, 3, h, w))
    torch.testing.assert_close(warped_para, prev[:, c:].expand(b, 3, h, w))


@pytest.mark.parametrize("h, w", [(7, 9), (36, 30)])  # product form / channel loop
@pytest.mark.parametrize("layout", [torch.contiguous_format, torch.channels_last])
def test_pscv_equals_per_hypothesis_warps_on_fractional_points(h, w, layout):
    b, c, s, k = 2, 16, 9, 2
    g = torch.Generator().manual_seed(3)
    f, prev = torch.randn(b, c, h, w, generator=g), torch.randn(b, c + 1, h, w, generator=g)
    pts = _grid_points(b, s, h, w) + 3 * torch.randn(b, s, 2, h, w, generator=g)  # some fall outside: border clamp
    with torch.no_grad():
        pscv, para = parallax_sweep_cost_volume(f.contiguous(memory_format=layout), prev, pts, k)
    for i in range(s):  # one hypothesis at a time, each warped on its own
        warped = sample_bilinear(prev, pts[:, i])
        expect = (f * warped[:, :c]).view(b, k, c // k, h, w).mean(2)
        torch.testing.assert_close(pscv.view(b, k, s, h, w)[:, :, i], expect, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(para[:, i], warped[:, c])


def test_sncv_reference_hand_computed_with_groups():
    """Two groups of two channels, radius 1: corr[o, g](p) = mean over the group's channels of f(p) f(p + d_o)."""
    g = torch.Generator().manual_seed(0)
    f = torch.randn(1, 4, 3, 4, generator=g, dtype=torch.float64)
    out = spatial_cost_volume(f, groups=2, radius=1, negative_slope=1.0).view(3, 3, 2, 3, 4)  # slope 1: no activation
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            for grp in range(2):
                for y in range(3):
                    for x in range(4):
                        yy, xx = y + dy, x + dx
                        want = 0.0
                        if 0 <= yy < 3 and 0 <= xx < 4:
                            want = sum(float(f[0, c, y, x] * f[0, c, yy, xx]) for c in (2 * grp, 2 * grp + 1)) / 2
                        assert float(out[dy + 1, dx + 1, grp, y, x]) == pytest.approx(want, abs=1e-12)


@pytest.mark.parametrize("shape, groups, radius", [((2, 4, 5, 6), 2, 1), ((1, 6, 4, 3), 3, 2), ((1, 2, 1, 2), 1, 3)])
def test_sncv_backward_matches_finite_differences(shape, groups, radius):
    """The hand-written backward (window columns + fold) against torch's numerical gradient, in float64."""
    x = torch.randn(shape, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: spatial_cost_volume(t, groups, radius), (x,))


@pytest.mark.parametrize("groups", [1, 2])
def test_pscv_backward_matches_finite_differences(groups):
    """The hand-written backward of the correlation (and the sampler's through it) against torch's numerical
    gradient in float64, for the features, the previous block (parallax channel included) and the points."""
    g = torch.Generator().manual_seed(1)
    b, c, h, w, s = 1, 4, 4, 5, 3
    f = torch.randn(b, c, h, w, generator=g, dtype=torch.float64, requires_grad=True)
    prev = torch.randn(b, c + 1, h, w, generator=g, dtype=torch.float64, requires_grad=True)
    pts = _grid_points(b, s, h, w).double() + 0.37 + 0.2 * torch.rand(b, s, 2, h, w, generator=g, dtype=torch.float64)
    pts.requires_grad_()
    assert torch.autograd.gradcheck(lambda *t: parallax_sweep_cost_volume(*t, groups), (f, prev, pts))


def test_pscv_equals_the_product_and_group_mean():
    """The channel loop against the plain product + group mean (the float16 option's and the export's form), on
    fractional points, values and gradients."""
    g = torch.Generator().manual_seed(2)
    b, c, h, w, s, k = 2, 8, 6, 7, 9, 2
    f = torch.randn(b, c, h, w, generator=g, requires_grad=True)
    prev = torch.randn(b, c + 1, h, w, generator=g, requires_grad=True)
    pts = _grid_points(b, s, h, w) + 2 * torch.randn(b, s, 2, h, w, generator=g)
    pscv, para = parallax_sweep_cost_volume(f, prev, pts, k)
    warped = torch.nn.functional.grid_sample(  # the sampler by hand: positions in pixels -> [-1, 1], border clamp
        prev,
        torch.stack([pts[:, :, 0] * 2 / (w - 1) - 1, pts[:, :, 1] * 2 / (h - 1) - 1], -1).flatten(1, 2),
        mode="bilinear",
        padding_mode="border",
        align_corners=True,
    ).view(b, c + 1, s, h, w)
    want = (f.unsqueeze(2) * warped[:, :c]).view(b, k, c // k, s, h, w).mean(2).reshape(b, k * s, h, w)
    torch.testing.assert_close(pscv, want, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(para, warped[:, c])
    wt = torch.randn(b, k * s, h, w, generator=g)
    got = torch.autograd.grad((pscv * wt).sum() + para.sum(), (f, prev))
    ref = torch.autograd.grad((want * wt).sum() + warped[:, c].sum(), (f, prev))
    for a, r in zip(got, ref):
        torch.testing.assert_close(a, r, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize(
    "shape, groups, radius", [((2, 16, 9, 13), 1, 3), ((1, 32, 6, 5), 2, 3), ((1, 8, 1, 1), 2, 3), ((2, 6, 7, 4), 3, 1)]
)
def test_sncv_export_form_equals_the_channel_loop(shape, groups, radius):
    """The form the ONNX export records (channels-last sums) is the same SNCV: same channels, same values."""
    from cosemdepth.ops.cost_volume import _sncv_channel_loop, _spatial_correlation_traceable

    x = torch.randn(shape, dtype=torch.float64)
    want = _sncv_channel_loop(x.contiguous(), groups, radius)
    torch.testing.assert_close(_spatial_correlation_traceable(x, groups, radius), want, rtol=1e-12, atol=1e-12)


def test_sncv_export_form_runs_in_onnxruntime_with_the_reference_values(tmp_path):
    ort = pytest.importorskip("onnxruntime")

    class Sncv(torch.nn.Module):
        def forward(self, f):
            return spatial_cost_volume(f, 2, 3)

    x = torch.randn(1, 8, 10, 12)
    path = tmp_path / "sncv.onnx"
    with torch.no_grad():
        torch.onnx.export(Sncv(), (x,), str(path), input_names=["f"], opset_version=17, dynamo=False)
    got = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, {"f": x.numpy()})[0]
    torch.testing.assert_close(torch.from_numpy(got), spatial_cost_volume(x, 2, 3), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("groups", [1, 2, 4])
def test_pscv_export_form_equals_the_product_form(groups):
    """The form the ONNX export records (channels-last warps and group means) is the same PSCV, out-of-image points
    (border clamping) included."""
    from cosemdepth.ops.cost_volume import _sweep_correlation_traceable

    g = torch.Generator().manual_seed(3)
    b, c, h, w, s = 2, 8, 5, 7, 3
    feat = torch.randn(b, c, h, w, generator=g, dtype=torch.float64)
    prev = torch.randn(b, c + 1, h, w, generator=g, dtype=torch.float64)
    pts = _grid_points(b, s, h, w).double() + 3 * torch.randn(b, s, 2, h, w, generator=g, dtype=torch.float64)
    want_corr, want_para = parallax_sweep_cost_volume(feat, prev, pts, groups)
    stacked = pts.permute(0, 2, 1, 3, 4).reshape(b, 2, s * h, w)
    corr, para = _sweep_correlation_traceable(feat, prev, stacked, groups)
    torch.testing.assert_close(corr, want_corr, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(para, want_para, rtol=1e-12, atol=1e-12)
