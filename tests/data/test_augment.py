"""Augmentations of design 9.3: involutions, geometric consistency on an analytic scene, colour values by hand."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cosemdepth.data.augment import (
    AugmentConfig,
    AugmentParams,
    adjust_brightness,
    adjust_contrast,
    adjust_hue,
    adjust_saturation,
    apply_params,
    augment_sample,
    draw_params,
    hflip,
    hsv_to_rgb,
    invert,
    resolve_augment,
    rgb_to_hsv,
    transpose,
    vflip,
)
from cosemdepth.errors import ConfigError

S = 32
# deliberately off-centre principal point and unequal focal lengths, so that intrinsics changes matter
K = (16.0, 14.0, 13.0, 19.0)


def rotation(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    w = np.cos(angle / 2)
    x, y, z = axis * np.sin(angle / 2)
    return np.array([w, x, y, z])


def rot_matrix(q) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def texture(p: np.ndarray) -> np.ndarray:
    """Smooth RGB texture of a point on the plane (previous-camera coordinates) -> [..., 3]."""
    x, y = p[..., 0], p[..., 1]
    return np.stack(
        [
            0.5 + 0.4 * np.sin(0.9 * x + 0.3 * y),
            0.5 + 0.4 * np.cos(0.5 * x - 0.8 * y),
            0.5 + 0.3 * np.sin(0.4 * x + 0.6 * y + 1.0),
        ],
        axis=-1,
    )


def render(q, t, k=K, size=S):
    """Image and z-depth of the plane z = 10 + 0.2 x + 0.1 y (previous-camera frame) seen by a camera whose points
    map to the previous camera by X_prev = R(q) X + t."""
    fx, fy, cx, cy = k
    i, j = np.mgrid[0:size, 0:size].astype(float)
    rays = np.stack([(j + 0.5 - cx) / fx, (i + 0.5 - cy) / fy, np.ones_like(i)], axis=-1)
    r = rot_matrix(q)
    n, h = np.array([-0.2, -0.1, 1.0]), 10.0
    lam = (h - n @ t) / ((rays @ r.T) @ n)
    points_prev = (lam[..., None] * rays) @ r.T + t
    return texture(points_prev), lam  # rays have z = 1, so lambda is the z-depth


def analytic_sample():
    q = rotation([0.1, 1.0, 0.2], 0.05)
    t = np.array([0.5, -0.3, 1.0])
    img0, d0 = render(np.array([1.0, 0, 0, 0]), np.zeros(3))
    img1, d1 = render(q, t)
    f32 = lambda a: torch.tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    return {
        "rgb": f32(np.stack([img0, img1])).permute(0, 3, 1, 2).contiguous(),
        "depth": f32(np.stack([d0, d1]))[:, None],
        "semantic": torch.arange(S * S).reshape(1, S, S).repeat(2, 1, 1),
        "rot": f32(np.stack([[1.0, 0, 0, 0], q])),
        "trans": f32(np.stack([np.zeros(3), t])),
        "intrinsics": f32(K),
        "reset": torch.tensor([True, False]),
    }


def warp_error(sample) -> tuple[float, float]:
    """Mean |I_1 - warp(I_0)| with frame 1's depth and motion, and the unwarped |I_1 - I_0|, on valid pixels."""
    fx, fy, cx, cy = sample["intrinsics"].double().tolist()
    h, w = sample["rgb"].shape[-2:]
    i, j = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    rays = torch.stack([(j + 0.5 - cx) / fx, (i + 0.5 - cy) / fy, torch.ones_like(i)], dim=-1)
    pts = rays * sample["depth"][1, 0].double()[..., None]
    r = torch.from_numpy(rot_matrix(sample["rot"][1].double().numpy()))
    prev = pts @ r.T + sample["trans"][1].double()
    jj = fx * prev[..., 0] / prev[..., 2] + cx - 0.5
    ii = fy * prev[..., 1] / prev[..., 2] + cy - 0.5
    valid = (jj >= 0) & (jj <= w - 1) & (ii >= 0) & (ii <= h - 1)
    grid = torch.stack([2 * jj / (w - 1) - 1, 2 * ii / (h - 1) - 1], dim=-1)[None]
    warped = F.grid_sample(sample["rgb"][:1].double(), grid, align_corners=True, padding_mode="border")[0]
    cur = sample["rgb"][1].double()
    assert valid.float().mean() > 0.6
    return (warped - cur).abs()[:, valid].mean().item(), (sample["rgb"][0].double() - cur).abs()[:, valid].mean().item()


def assert_same(a, b):
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k


@pytest.mark.parametrize("op", [vflip, hflip, transpose])
def test_each_geometric_op_twice_is_the_identity(op):
    s = analytic_sample()
    assert_same(op(op(s)), s)
    once = op(s)
    assert not torch.equal(once["rgb"], s["rgb"])


def test_analytic_scene_is_consistent_before_augmentation():
    warped, unwarped = warp_error(analytic_sample())
    assert warped < 0.01 and warped < 0.1 * unwarped


@pytest.mark.parametrize("flags", list(itertools.product([False, True], repeat=3)))
def test_every_symmetry_keeps_the_sample_geometrically_consistent(flags):
    s = analytic_sample()
    out = apply_params(s, AugmentParams(vflip=flags[0], hflip=flags[1], transpose=flags[2]))
    warped, unwarped = warp_error(out)
    assert warped < 0.01 and warped < 0.1 * unwarped
    if any(flags):
        # the motion/intrinsics changes matter: flipping the images alone breaks the consistency
        stale = dict(out, rot=s["rot"], trans=s["trans"], intrinsics=s["intrinsics"])
        assert warp_error(stale)[0] > 5 * warped
        # and so does the intrinsics change (off-centre principal point, fx != fy)
        assert warp_error(dict(out, intrinsics=s["intrinsics"]))[0] > 2 * warped


def test_flip_motion_and_intrinsics_formulas():
    s = analytic_sample()
    q, t = s["rot"][1], s["trans"][1]
    v = vflip(s)
    assert torch.equal(v["rot"][1], torch.stack([q[0], -q[1], q[2], -q[3]]))
    assert torch.equal(v["trans"][1], torch.stack([t[0], -t[1], t[2]]))
    assert v["intrinsics"].tolist() == [16.0, 14.0, 13.0, S - 19.0]
    hh = hflip(s)
    assert torch.equal(hh["rot"][1], torch.stack([q[0], q[1], -q[2], -q[3]]))
    assert torch.equal(hh["trans"][1], torch.stack([-t[0], t[1], t[2]]))
    assert hh["intrinsics"].tolist() == [16.0, 14.0, S - 13.0, 19.0]
    tr = transpose(s)
    assert torch.equal(tr["rot"][1], torch.stack([q[0], -q[2], -q[1], -q[3]]))
    assert torch.equal(tr["trans"][1], torch.stack([t[1], t[0], t[2]]))
    assert tr["intrinsics"].tolist() == [14.0, 16.0, 19.0, 13.0]  # fx<->fy and cx<->cy swapped (fix 15.11)
    assert torch.equal(tr["semantic"][0], s["semantic"][0].T)
    assert torch.equal(v["semantic"][0], s["semantic"][0].flip(0))


def test_samples_without_depth_or_labels_can_be_flipped():
    s = analytic_sample()
    del s["depth"], s["semantic"]
    out = apply_params(s, AugmentParams(vflip=True, hflip=True, transpose=True))
    assert "depth" not in out and out["rgb"].shape == s["rgb"].shape


def px(r, g, b):
    return torch.tensor([r, g, b], dtype=torch.float32).reshape(3, 1, 1)


def close(a, b):
    torch.testing.assert_close(a, b, rtol=0, atol=1e-6)


def test_brightness_is_additive_and_unclipped():
    close(adjust_brightness(px(0.9, 0.5, 0.0), 0.2), px(1.1, 0.7, 0.2))
    close(adjust_brightness(px(0.1, 0.5, 0.0), -0.2), px(-0.1, 0.3, -0.2))


def test_contrast_uses_per_frame_per_channel_means():
    x = torch.tensor([[[[0.0, 1.0]], [[0.2, 0.4]], [[0.5, 0.5]]], [[[0.2, 0.2]], [[0.0, 0.8]], [[1.0, 0.0]]]])
    out = adjust_contrast(x, 2.0)
    expected = torch.tensor([[[[-0.5, 1.5]], [[0.1, 0.5]], [[0.5, 0.5]]], [[[0.2, 0.2]], [[-0.4, 1.2]], [[1.5, -0.5]]]])
    close(out, expected)


def test_hsv_conversion_by_hand():
    hsv = rgb_to_hsv(px(0.8, 0.4, 0.2))
    close(hsv, px(0.2 / 3.6, 0.75, 0.8))  # h = (g - b) / (6 (max - min)), s = (max - min) / max, v = max
    close(hsv_to_rgb(hsv), px(0.8, 0.4, 0.2))
    close(rgb_to_hsv(px(0.3, 0.3, 0.3)), px(0.0, 0.0, 0.3))
    close(rgb_to_hsv(px(0.0, 0.0, 0.0)), px(0.0, 0.0, 0.0))
    close(rgb_to_hsv(px(0.2, 0.4, 0.8)), px(0.2 / 3.6 * -1 + 4 / 6, 0.75, 0.8))  # blue max: (r - g)/(6c) + 4/6


def test_saturation_by_hand():
    # halve S: V stays 0.8, min becomes V (1 - S/2) = 0.5, the middle channel keeps its relative position
    close(adjust_saturation(px(0.8, 0.4, 0.2), 0.5), px(0.8, 0.6, 0.5))
    # S * 3 = 2.25 is clipped to 1: fully saturated, same hue and value
    close(adjust_saturation(px(0.8, 0.4, 0.2), 3.0), px(0.8, 0.8 / 3, 0.0))
    close(adjust_saturation(px(0.3, 0.3, 0.3), 1.2), px(0.3, 0.3, 0.3))


def test_hue_by_hand():
    # a third of a turn permutes the channels: (r, g, b) -> (b, r, g)
    close(adjust_hue(px(0.8, 0.4, 0.2), 1 / 3), px(0.2, 0.8, 0.4))
    close(adjust_hue(px(0.8, 0.4, 0.2), -1 / 3), px(0.4, 0.2, 0.8))
    close(adjust_hue(px(0.5, 0.5, 0.5), 0.3), px(0.5, 0.5, 0.5))
    # a sixth of a turn: hue 0 (pure red) -> 1/6 (yellow)
    close(adjust_hue(px(0.6, 0.0, 0.0), 1 / 6), px(0.6, 0.6, 0.0))


def test_colour_adjustments_match_python_colorsys():
    """Hue and saturation on random pixels in [0, 1] against the standard library's HSV conversion (float64, one pixel
    at a time): an implementation independent of ours, with every hue sector and grey pixels present."""
    import colorsys

    g = torch.Generator().manual_seed(5)
    x = torch.rand(2, 3, 3, 16, 16, generator=g, dtype=torch.float64)
    x[0, 0, :, 0, :4] = 0.25  # grey pixels (hue undefined -> 0)
    pixels = x.movedim(-3, -1).reshape(-1, 3).tolist()
    for delta in (0.05, 1 / 3, -0.45, 0.999):
        want = [colorsys.hsv_to_rgb((h + delta) % 1.0, s, v) for h, s, v in (colorsys.rgb_to_hsv(*p) for p in pixels)]
        got = adjust_hue(x, delta).movedim(-3, -1).reshape(-1, 3)
        torch.testing.assert_close(got, torch.tensor(want, dtype=torch.float64), rtol=0, atol=1e-12)
    for factor in (0.0, 0.4, 1.7):
        want = [
            colorsys.hsv_to_rgb(h, min(s * factor, 1.0), v) for h, s, v in (colorsys.rgb_to_hsv(*p) for p in pixels)
        ]
        got = adjust_saturation(x, factor).movedim(-3, -1).reshape(-1, 3)
        torch.testing.assert_close(got, torch.tensor(want, dtype=torch.float64), rtol=0, atol=1e-12)


def test_hue_rotates_pixels_with_all_channels_negative_as_tf():
    # TF's hue kernel keeps max and min: a third of a turn still permutes (r, g, b) -> (b, r, g) when every channel
    # is <= 0 (after a negative brightness shift); an HSV round trip would have returned grey (V <= 0 -> S = 0)
    close(adjust_hue(px(-0.3, -0.1, -0.2), 1 / 3), px(-0.2, -0.3, -0.1))
    close(adjust_hue(px(0.0, -0.2, -0.1), -1 / 3), px(-0.2, -0.1, 0.0))
    # a sixth of a turn from hue 0 (max r, g = b = min): g rises to the max -> (max, max, min)
    close(adjust_hue(px(-0.1, -0.5, -0.5), 1 / 6), px(-0.1, -0.1, -0.5))


def test_saturation_turns_all_negative_pixels_grey_as_tf():
    # TF's saturation kernel: S = 0 when V <= 0, so the pixel becomes (V, V, V) whatever the factor (!= 1)
    close(adjust_saturation(px(-0.3, -0.1, -0.2), 1.2), px(-0.1, -0.1, -0.1))
    close(adjust_saturation(px(-0.3, -0.1, -0.2), 0.8), px(-0.1, -0.1, -0.1))


def test_inversion_and_full_pipeline_by_hand():
    close(invert(px(0.25, 1.2, -0.1)), px(0.75, -0.2, 1.1))
    s = {
        "rgb": px(0.7, 0.3, 0.1)[None].repeat(2, 1, 1, 1),
        "rot": torch.zeros(2, 4),
        "trans": torch.zeros(2, 3),
        "intrinsics": torch.zeros(4),
    }
    p = AugmentParams(brightness=0.1, contrast=1.5, saturation=0.5, hue=1 / 3, invert=True)
    out = apply_params(s, p)["rgb"]
    # brightness: (0.8, 0.4, 0.2); contrast on a 1x1 image is a no-op; saturation x0.5: (0.8, 0.6, 0.5);
    # hue +1/3: (0.5, 0.8, 0.6); inversion: (0.5, 0.2, 0.4)
    close(out[0], px(0.5, 0.2, 0.4))
    close(out[1], out[0])


def test_draws_are_per_sequence_seeded_and_follow_the_probabilities():
    cfg = AugmentConfig.train()
    a = draw_params(cfg, torch.Generator().manual_seed(5), square=True)
    b = draw_params(cfg, torch.Generator().manual_seed(5), square=True)
    assert a == b
    g = torch.Generator().manual_seed(0)
    draws = [draw_params(cfg, g, square=True) for _ in range(2000)]
    for name in ("vflip", "hflip", "transpose", "invert"):
        assert 0.45 < np.mean([getattr(d, name) for d in draws]) < 0.55
    assert all(-0.2 <= d.brightness <= 0.2 and 0.75 <= d.contrast <= 1.25 for d in draws)
    assert all(0.75 <= d.saturation <= 1.25 and -0.4 <= d.hue <= 0.4 for d in draws)
    assert min(d.hue for d in draws) < -0.35 and max(d.hue for d in draws) > 0.35
    assert not any(draw_params(cfg, g, square=False).transpose for _ in range(200))
    fine = [draw_params(AugmentConfig.finetune(), g, square=True) for _ in range(200)]
    assert not any(d.vflip or d.hflip or d.transpose for d in fine)
    assert all(0.8 <= d.contrast <= 1.2 and abs(d.hue) <= 0.2 for d in fine)


def test_augment_sample_applies_one_draw_to_all_frames():
    s = analytic_sample()
    s["rgb"] = s["rgb"][:1].repeat(3, 1, 1, 1)
    s["depth"] = s["depth"][:1].repeat(3, 1, 1, 1)
    s["semantic"] = s["semantic"][:1].repeat(3, 1, 1)
    s["rot"] = s["rot"][:1].repeat(3, 1)
    s["trans"] = s["trans"][:1].repeat(3, 1)
    for seed in range(5):
        out = augment_sample(s, AugmentConfig.train(), torch.Generator().manual_seed(seed))
        assert torch.equal(out["rgb"][0], out["rgb"][1]) and torch.equal(out["rgb"][0], out["rgb"][2])
        assert torch.equal(out["semantic"][0], out["semantic"][2])


def test_resolve_augment():
    assert resolve_augment(False) is None and resolve_augment(None) is None
    assert resolve_augment(True) == AugmentConfig()
    assert resolve_augment("finetune") == AugmentConfig.finetune()
    assert resolve_augment({"p_invert": 0.0}).p_invert == 0.0
    with pytest.raises(ConfigError):
        resolve_augment("sometimes")
    with pytest.raises(ConfigError):
        AugmentConfig(p_vflip=1.5)


# ------------------------------------------------------------------------------------------ fused colour pass


def _sequential(rgb: torch.Tensor, p: AugmentParams) -> torch.Tensor:
    """The colour operations one after the other: the reference the fused pass must reproduce."""
    if p.brightness != 0.0:
        rgb = adjust_brightness(rgb, p.brightness)
    if p.contrast != 1.0:
        rgb = adjust_contrast(rgb, p.contrast)
    if p.saturation != 1.0:
        rgb = adjust_saturation(rgb, p.saturation)
    if p.hue != 0.0:
        rgb = adjust_hue(rgb, p.hue)
    if p.invert:
        rgb = invert(rgb)
    return rgb


@pytest.mark.parametrize("on", list(itertools.product([False, True], repeat=5)))
def test_fused_colour_pass_equals_the_sequential_operations(on):
    """Every subset of (brightness, contrast, saturation, hue, inversion), on pixels in [-0.3, 1.3] (brightness and
    contrast leave [0, 1]): the fused pass is the sequential one within float32 rounding (2e-6)."""
    g = torch.Generator().manual_seed(sum(b << i for i, b in enumerate(on)))
    rgb = torch.rand(2, 3, 9, 7, generator=g) * 1.6 - 0.3
    rgb[0, :, 0, 0] = -0.2  # a pixel with every channel negative
    rgb[1, :, 1, 1] = 0.5  # a grey pixel (no hue)
    p = AugmentParams(
        brightness=0.13 if on[0] else 0.0,
        contrast=1.21 if on[1] else 1.0,
        saturation=0.8 if on[2] else 1.0,
        hue=-0.37 if on[3] else 0.0,
        invert=on[4],
    )
    out = apply_params({"rgb": rgb}, p)["rgb"]
    torch.testing.assert_close(out, _sequential(rgb, p), rtol=0, atol=2e-6)


def test_fused_affine_with_inversion_by_hand():
    # channel 0 = (0.2, 0.6): + 0.1 -> (0.3, 0.7), mean 0.5, contrast 2 -> (0.1, 0.9), inverted -> (0.9, 0.1);
    # channel 1: constant 0.6 after brightness, kept by contrast, inverted 0.4; channel 2: (0.1, 1.1) -> (-0.4, 1.6)
    x = torch.tensor([[[0.2, 0.6]], [[0.5, 0.5]], [[0.0, 1.0]]])
    out = apply_params({"rgb": x}, AugmentParams(brightness=0.1, contrast=2.0, invert=True))["rgb"]
    close(out, torch.tensor([[[0.9, 0.1]], [[0.4, 0.4]], [[1.4, -0.6]]]))
    # hue +1/3 alone turns red into green: (0.7, 0.3, 0.1) -> (0.1, 0.7, 0.3); inverted in the rebuild -> (0.9, 0.3, 0.7)
    close(apply_params({"rgb": px(0.7, 0.3, 0.1)}, AugmentParams(hue=1 / 3, invert=True))["rgb"], px(0.9, 0.3, 0.7))
    # no colour operation: the pixels are unchanged
    x = torch.rand(3, 4, 5)
    assert torch.equal(apply_params({"rgb": x}, AugmentParams())["rgb"], x)
