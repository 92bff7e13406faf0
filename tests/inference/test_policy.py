"""Baseline-aware streaming (:mod:`cosemdepth.inference.policy`) on hand-made motions, with a stand-in model whose
depth is known: a fronto-parallel plane at 20 m (or any depth a test chooses per frame).

Expectations are worked out by hand: which frames are estimated, held or reset; the motion the network is given
(composed from the reference frame); the state it continues from; the depth a held frame carries (a plane seen from a
camera turned by theta about its y axis is 20 / cos(theta) m away along the optical axis at the image centre).
"""

from __future__ import annotations

import math

import pytest
import torch

from cosemdepth.errors import ConfigError
from cosemdepth.inference.policy import BASELINE, EVERY_FRAME, Streamer, StreamPolicy, policy_info
from cosemdepth.models import StepOutput, StreamState

N = 33  # odd: pixel (16, 16) lies on the optical axis
K = torch.tensor([[32.0, 32.0, 16.5, 16.5]])  # fx fy cx cy, pixel centres at +0.5
ONE = torch.tensor([[1.0, 0.0, 0.0, 0.0]])
ZERO = torch.zeros(1, 3)
C = N // 2


class PlaneModel:
    """Depth ``depths[k]`` everywhere for the k-th call of its depth decoder (default 20 m); the depth decoder's state
    holds the index of the frame it ran on (the frame's RGB value) and, as a model's does, passes through unchanged
    when only the other decoders run. Records what every step was given."""

    decoders = ("depth", "semantic")

    def __init__(self, depths=None):
        self.depths = list(depths or [])
        self.runs = 0
        self.calls = []  # (frame, ran depth, trans, state's frame)
        self.resets = []  # the reset flag each call was given

    def step(self, rgb, rot, trans, intrinsics, reset, state, decoders=None):
        frame = int(rgb[0, 0, 0, 0])
        run = decoders is None or "depth" in decoders
        self.calls.append((frame, run, trans[0].tolist(), None if state is None else int(state.features[0][0])))
        self.resets.append(bool(reset[0]))
        depth = None
        if run:
            d = self.depths[self.runs] if self.runs < len(self.depths) else 20.0
            self.runs += 1
            depth = torch.full((1, 1, N, N), float(d))
        probs = torch.full((1, 2, N, N), 0.5)
        new = StreamState(feat=(torch.full((1,), float(frame)),)) if run or state is None else state
        return StepOutput(heads={"semantic": probs} if depth is None else {"depth": depth, "semantic": probs}), new


def run(model, motions, policy=BASELINE, min_baseline=1.0, **kw):
    """Stream frames 0, 1, ... with ``motions[k] = (rot, trans)`` from frame k-1 to frame k (frame 0 a reset)."""
    s = Streamer(model, StreamPolicy(mode=policy, min_baseline=min_baseline if policy == BASELINE else None, **kw))
    state, outs = None, []
    for k, (q, t) in enumerate(motions):
        rgb = torch.full((1, 3, N, N), float(k))
        out, state = s.step(rgb, q, t, K, torch.tensor([k == 0]), state)
        outs.append(out)
    return outs


def fwd(z):
    return ONE, torch.tensor([[0.0, 0.0, z]])


def side(x):
    return ONE, torch.tensor([[x, 0.0, 0.0]])


def yaw(deg):
    h = math.radians(deg) / 2
    return torch.tensor([[math.cos(h), 0.0, math.sin(h), 0.0]]), ZERO


def test_hover_frames_are_held_with_the_reference_depth_and_the_next_estimate_uses_the_reference_state():
    model = PlaneModel()
    outs = run(model, [fwd(0), fwd(2.0), fwd(0), fwd(0), fwd(0), fwd(2.0)])
    assert [o.status[0] for o in outs] == ["reset", "estimated", "held", "held", "held", "estimated"]
    # the depth decoder ran on the reset and the two estimates only; the last one against frame 1, the reference
    assert [(f, ran) for f, ran, _, _ in model.calls] == [
        (0, True),
        (1, True),
        (2, False),
        (3, False),
        (4, False),
        (5, True),
    ]
    assert model.calls[5][2] == pytest.approx([0, 0, 2.0]) and model.calls[5][3] == 1
    for o in outs[2:5]:  # no motion: the reference's depth exactly, with its mask
        assert torch.equal(o.depth, outs[1].depth) and torch.equal(o.valid, outs[1].valid)
        assert float(o.baseline[0]) == 0.0
    assert not outs[0].valid.any()  # a reset has no depth
    assert outs[1].valid.any() and outs[5].valid.any()
    assert float(outs[1].baseline[0]) == pytest.approx(2.0) and float(outs[5].baseline[0]) == pytest.approx(2.0)


def test_pure_yaw_is_held_and_the_carried_depth_is_the_plane_seen_from_the_turned_camera():
    outs = run(PlaneModel(), [fwd(0), side(2.0), yaw(10), yaw(10)])  # sideways: the whole view is well conditioned
    assert [o.status[0] for o in outs] == ["reset", "estimated", "held", "held"]
    # the first held frame is turned 10 degrees from the reference, the second 20 (the motions are composed)
    for o, theta in ((outs[2], 10), (outs[3], 20)):
        assert bool(o.valid[0, 0, C, C])
        # the carried depth comes from the reference pixel that lands nearest: within half a pixel of the depth's
        # slope (20 sin / (f cos^2) = 0.24 m per pixel at 20 degrees)
        assert float(o.depth[0, 0, C, C]) == pytest.approx(20.0 / math.cos(math.radians(theta)), abs=0.12)
        assert float(o.baseline[0]) == 0.0
    # the part of the view the reference did not see (one side, after a 20 degree turn) has no depth
    assert not outs[3].valid[0, 0, :, -1].any() or not outs[3].valid[0, 0, :, 0].any()
    assert (outs[3].depth[outs[3].valid] > 0).all()


def test_slow_flight_estimates_once_the_baseline_is_reached_against_the_reference():
    model = PlaneModel()
    outs = run(model, [fwd(0)] + [fwd(0.4)] * 6)
    # after the reset, 0.4 and 0.8 m are too little (no depth yet: reset); 1.2 m is an estimate and the new
    # reference; then 0.4, 0.8 m from it are held and 1.2 m is the next estimate
    assert [o.status[0] for o in outs] == ["reset", "reset", "reset", "estimated", "held", "held", "estimated"]
    assert [f for f, ran, _, _ in model.calls if ran] == [0, 3, 6]
    assert model.calls[3][2] == pytest.approx([0, 0, 1.2], abs=1e-6) and model.calls[3][3] == 0
    assert model.calls[6][2] == pytest.approx([0, 0, 1.2], abs=1e-6) and model.calls[6][3] == 3
    assert [round(float(o.baseline[0]), 5) for o in outs] == [0.0, 0.4, 0.8, 1.2, 0.4, 0.8, 1.2]
    assert not outs[1].valid.any() and not outs[2].valid.any()
    # held after forward motion: the plane 0.4 m nearer (the small translation is applied to the carried depth)
    assert float(outs[4].depth[0, 0, C, C]) == pytest.approx(20.0 - 0.4, rel=1e-4)


def test_every_frame_policy_estimates_a_hover_frame_and_marks_all_of_it_invalid():
    model = PlaneModel()
    outs = run(model, [fwd(0), fwd(2.0), fwd(0)], policy=EVERY_FRAME)
    assert [o.status[0] for o in outs] == ["reset", "estimated", "estimated"]
    assert all(ran for _, ran, _, _ in model.calls)
    assert outs[1].valid.any() and not outs[2].valid.any()  # no translation, no parallax: nothing valid


def test_an_estimate_far_from_the_carried_reference_depth_is_invalid():
    # frame 2's estimate says 50 m where the reference said 20 m (2.5 x, beyond exp(max_log_ratio) = 2 x)
    outs = run(PlaneModel([20.0, 20.0, 50.0]), [fwd(0), fwd(2.0), fwd(2.0)], max_log_ratio=math.log(2.0))
    assert outs[1].valid[0, 0, C + 8, C + 8] and not outs[2].valid[0, 0, C + 8, C + 8]
    # where the reference had no estimate, nothing contradicts the new one
    outs = run(PlaneModel([20.0, 20.0, 21.0]), [fwd(0), fwd(2.0), fwd(2.0)])
    assert outs[2].valid[0, 0, C + 8, C + 8]


def test_the_focus_of_expansion_is_invalid_in_forward_flight():
    outs = run(PlaneModel(), [fwd(0), fwd(2.0)])
    v = outs[1].valid[0, 0]
    assert not v[C, C] and v[0, 0] and v[-1, -1]


def test_a_one_frame_flight_has_no_valid_depth():
    (out,) = run(PlaneModel(), [fwd(0)])
    assert out.status == ["reset"] and not out.valid.any() and out.valid.shape == (1, 1, N, N)


def test_a_model_without_training_motion_needs_a_min_baseline_and_none_chooses_every_frame():
    with pytest.raises(ConfigError, match="--min-baseline"):
        Streamer(PlaneModel(), BASELINE)
    assert Streamer(PlaneModel(), None).policy.mode == EVERY_FRAME
    s = Streamer(PlaneModel(), None, min_baseline=0.5)
    assert policy_info(s)["mode"] == BASELINE and policy_info(s)["min_baseline_m"] == 0.5
    with pytest.raises(ConfigError):
        StreamPolicy(mode="sometimes")


def test_a_held_frame_turned_away_from_the_reference_re_anchors_and_the_next_estimate_starts_from_it():
    """33 px at f = 32 px: 27.3 degrees either side. Yawing 2 degrees a frame, the held frames see 0.96 and 0.92 of
    the reference's view (at least the default min_overlap, 0.9: held against it), the third (6 degrees, 0.88) re-anchors: the
    network restarts on it (reset) and it becomes the reference with its held depth; the next estimate is made
    against it, with the motion from it and its state."""
    model = PlaneModel()
    motions = [fwd(0), side(2.0), yaw(2), yaw(2), yaw(2), yaw(2), side(2.0)]
    outs = run(model, motions)
    assert [o.status[0] for o in outs] == ["reset", "estimated", "held", "held", "held", "held", "estimated"]
    assert [(f, ran, r) for (f, ran, _, _), r in zip(model.calls, model.resets)] == [
        (0, True, True),
        (1, True, False),
        (2, False, False),
        (3, False, False),
        (4, True, True),  # the re-anchor: the network's state restarts on frame 4
        (5, False, False),
        (6, True, False),
    ]
    # frame 6 against frame 4: its state, and the motion from it (2 degrees of yaw, then 2 m sideways)
    c, s = math.cos(math.radians(2)), math.sin(math.radians(2))
    assert model.calls[6][3] == 4 and model.calls[6][2] == pytest.approx([2 * c, 0.0, -2 * s], abs=1e-5)
    # the held depth: the plane seen from the turned camera, 20 / cos(theta) on the optical axis (6 and 8 degrees:
    # the re-anchored frame's own carried depth is carried on)
    for o, theta in ((outs[4], 6), (outs[5], 8)):
        assert bool(o.valid[0, 0, C, C])
        assert float(o.depth[0, 0, C, C]) == pytest.approx(20.0 / math.cos(math.radians(theta)), abs=0.06)
    assert float(outs[6].baseline[0]) == pytest.approx(2.0)


def test_without_re_anchoring_the_estimate_after_a_turn_is_made_against_the_old_reference():
    model = PlaneModel()
    run(model, [fwd(0), side(2.0), yaw(2), yaw(2), yaw(2), yaw(2), side(2.0)], min_overlap=0.0)
    assert model.resets == [True] + [False] * 6
    assert model.calls[6][3] == 1  # frame 1's state, turned 8 degrees away


def test_a_hover_that_wobbles_keeps_its_reference():
    """Small rotations back and forth (0.5 degree) while hovering stay far above min_overlap: no re-anchor, the
    estimate after the hover continues from the reference's state (the network's own depth chain)."""
    model = PlaneModel()
    outs = run(model, [fwd(0), fwd(2.0), yaw(0.5), yaw(-0.5), yaw(0.5), yaw(-0.5), fwd(2.0)])
    assert [o.status[0] for o in outs] == ["reset", "estimated"] + ["held"] * 4 + ["estimated"]
    assert model.resets == [True] + [False] * 6
    assert model.calls[6][3] == 1


def test_re_anchoring_before_the_first_estimate_keeps_the_frames_without_depth():
    # a turn in place right after a reset: the re-anchored frames have no depth (status reset, nothing valid) until
    # the camera moves; the estimate is then made against the last re-anchored frame
    model = PlaneModel()
    outs = run(model, [fwd(0), yaw(10), yaw(10), side(2.0)])
    assert [o.status[0] for o in outs] == ["reset", "reset", "reset", "estimated"]
    assert model.resets == [True, True, True, False] and model.calls[3][3] == 2
    assert not outs[1].valid.any() and not outs[2].valid.any() and outs[3].valid.any()


def test_every_frame_never_re_anchors_and_min_overlap_is_checked():
    model = PlaneModel()
    run(model, [fwd(0), side(2.0), yaw(30), side(2.0)], policy=EVERY_FRAME)
    assert model.resets == [True, False, False, False]
    assert policy_info(Streamer(PlaneModel(), EVERY_FRAME))["min_overlap"] is None
    s = Streamer(PlaneModel(), StreamPolicy(min_baseline=1.0, min_overlap=0.8))
    assert policy_info(s)["min_overlap"] == 0.8
    for bad in (-0.1, 1.5, float("nan"), "0.9"):
        with pytest.raises(ConfigError, match="min_overlap"):
            StreamPolicy(min_overlap=bad)


def test_pixels_without_a_source_are_invalid_in_estimated_and_held_frames():
    """An undistorted image's pixels without a source pixel (``source_valid`` False) are never valid: not where the
    frame is estimated, not where a held frame carries the reference's depth."""
    source = torch.ones(1, 1, N, N, dtype=torch.bool)
    source[..., :, :5] = False
    model = PlaneModel()
    s = Streamer(model, StreamPolicy(mode=BASELINE, min_baseline=1.0))
    plain = run(PlaneModel(), [fwd(0), side(2.0), yaw(5)])
    state, outs = None, []
    for k, (q, t) in enumerate([fwd(0), side(2.0), yaw(5)]):
        out, state = s.step(
            torch.full((1, 3, N, N), float(k)), q, t, K, torch.tensor([k == 0]), state, source_valid=source
        )
        outs.append(out)
    assert [o.status[0] for o in outs] == ["reset", "estimated", "held"]
    for o, p in zip(outs, plain):
        assert not o.valid[..., :, :5].any()
        assert torch.equal(o.valid, p.valid & source) and torch.equal(o.depth, p.depth)
    assert outs[1].valid[..., :, 5:].any() and outs[2].valid[..., :, 5:].any()
