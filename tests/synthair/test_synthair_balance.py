"""Class balance, depth range and flight envelope of a small default-like SynthAir set.

The default set is 4 trajectories per climate (16 flights); here the same flights are shortened (64 camera
frames) and rendered small (32 px) so that the check runs in seconds. Pixel fractions do not depend on the size.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cosemdepth.data.midair.format import CLASSES_7, MIDAIR_TO_7
from cosemdepth.data.quaternion import qmatrix
from cosemdepth.synthair.climate import get_climate
from cosemdepth.synthair.render import SKY_DEPTH, render_frames
from cosemdepth.synthair.writer import SynthConfig, batch_size, plan_flights, rendered_frames

SIZE = 32


@pytest.fixture(scope="module")
def default_like(world):
    defaults = SynthConfig(out=Path("unused"))
    cfg = SynthConfig(out=Path("unused"), trajectories=defaults.trajectories, frames=64, size=SIZE, seed=0)
    flights = plan_flights(cfg, world)
    c = (np.arange(SIZE) + 0.5 - SIZE / 2) / (SIZE / 2)
    right, down = np.meshgrid(c, c)
    body = np.stack([np.ones_like(right), right, down], -1)
    counts = np.zeros(14)
    below_depths = []
    for climate, planned in flights.items():
        for p in planned.values():
            js = [4 * k for k in rendered_frames(cfg)]
            bs = batch_size(SIZE)
            for i in range(0, len(js), bs):
                sel = js[i : i + bs]
                frames = render_frames(
                    world,
                    get_climate(climate).with_sun_azimuth(p.sun_azimuth),
                    p.flight.attitude[sel],
                    p.flight.position[sel],
                    SIZE,
                    SIZE,
                )
                for j, f in zip(sel, frames):
                    counts += np.bincount(f.labels.ravel(), minlength=14)
                    down_comp = (body @ qmatrix(p.flight.attitude[j]).T)[..., 2]
                    below = down_comp > 0  # rays below the horizon
                    below_depths.append(f.depth[below])
    return flights, counts, np.concatenate(below_depths)


def test_every_class_is_present_and_the_big_ones_dominate(default_like):
    _, counts, _ = default_like
    frac = np.bincount(MIDAIR_TO_7, weights=counts, minlength=7) / counts.sum()
    report = dict(zip(CLASSES_7, np.round(frac, 4)))
    assert (frac >= 0.01).all(), report
    for name in ("sky", "trees", "land"):
        assert frac[CLASSES_7.index(name)] >= 0.10, report
    # only Mid-Air IDs that SynthAir draws
    assert set(np.flatnonzero(counts)) <= {0, 2, 3, 4, 5, 6, 8, 9, 10}


def test_depth_below_the_horizon_spans_1_to_300_metres(default_like):
    _, _, depths = default_like
    ground = depths[depths < SKY_DEPTH]
    assert ground.min() <= 1.0
    assert ground.max() >= 300.0
    assert (ground > 300).mean() > 0.01


def test_flights_are_smooth_low_altitude_forward_flights(world, default_like):
    import torch

    from cosemdepth.synthair.raymarch import surface_height

    flights, _, _ = default_like
    altitudes, rolls, yaw_ranges = [], [], []
    for planned in flights.values():
        for p in planned.values():
            f = p.flight
            pos, att = f.position, f.attitude
            np.testing.assert_allclose(np.linalg.norm(att, axis=1), 1.0, atol=1e-9)
            ground = world.terrain.surface_at(pos[:, 0], pos[:, 1])
            altitudes.append(-pos[:, 2] - ground)
            # never inside anything: the exact height field under the camera is below it
            s = surface_height(world, torch.tensor(pos[:, :2].T, dtype=torch.float32)).double().numpy()
            assert (-pos[:, 2] - s).min() > 0.2
            # smooth: bounded acceleration and angular rate (finite differences at 100 Hz)
            acc = np.diff(pos, 2, axis=0) * 100**2
            assert np.linalg.norm(acc, axis=1).max() < 20.0
            assert np.linalg.norm(f.angular_velocity, axis=1).max() < 2.5
            rot = qmatrix(att)  # body -> NED
            forward = rot[:, :, 0]
            vel = np.diff(pos, axis=0) * 100
            assert ((vel * forward[:-1]).sum(1) > 0).mean() > 0.95  # flying forwards
            assert np.abs(vel[:, 2]).max() < 10.0 and np.linalg.norm(vel[:, :2], axis=1).max() < 16.0
            pitch_down = np.degrees(np.arcsin(np.clip(forward[:, 2], -1, 1)))
            assert pitch_down.min() > 2.0 and pitch_down.max() < 75.0  # looking down, not at the feet
            rolls.append(np.degrees(np.arctan2(rot[:, 2, 1], rot[:, 2, 2])))
            yaw = np.unwrap(np.arctan2(forward[:, 1], forward[:, 0]))
            yaw_ranges.append(np.degrees(np.ptp(yaw)))
    alt = np.concatenate(altitudes)
    assert 5.0 < np.median(alt) < 60.0 and alt.max() < 100.0
    assert np.std(np.concatenate(rolls)) > 1.0 and max(yaw_ranges) > 5.0
