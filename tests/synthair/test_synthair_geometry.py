"""Geometric consistency of SynthAir: the ground-truth depth and the CSV motions explain the image motion.

An independent check, written here from design 2 alone: for each pixel of frame t, back-project with its depth
(f = W/2, c = W/2), move into frame t-1 with X_prev = R X_curr + t (design 2.2), project and sample frame t-1
bilinearly. The warped frame must match frame t far better than frame t-1 itself does, on every climate.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from synthair_helpers import bilinear_sample

from cosemdepth.data.midair.splits import read_csv
from cosemdepth.synthair.climate import CLIMATES
from cosemdepth.synthair.writer import SynthConfig, generate

SIZE = 192


def _rotation(q):
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _depth(path: Path) -> np.ndarray:
    raw = np.asarray(Image.open(path)).astype(np.uint16)
    return 512.0 / raw.view(np.float16).astype(np.float64)  # Mid-Air: z = 512 / disparity at any size


def _rgb(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float64) / 255.0


def _warp(prev_rgb, prev_depth, cur_depth, q, t):
    """Frame t-1 resampled at the pixels of frame t; also the in-view mask and the co-visibility mask."""
    h, w = cur_depth.shape
    f = w / 2
    jj, ii = np.meshgrid(np.arange(w), np.arange(h))
    x_cur = np.stack([(jj + 0.5 - w / 2) / f * cur_depth, (ii + 0.5 - h / 2) / f * cur_depth, cur_depth], -1)
    x_prev = x_cur @ _rotation(q).T + t
    u = f * x_prev[..., 0] / x_prev[..., 2] + w / 2 - 0.5  # column of frame t-1 (pixel centres at integers)
    v = f * x_prev[..., 1] / x_prev[..., 2] + h / 2 - 0.5
    in_view = (x_prev[..., 2] > 0) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    seen = bilinear_sample(prev_depth, u, v)
    covisible = in_view & (np.abs(seen - x_prev[..., 2]) < 0.03 * x_prev[..., 2])
    return bilinear_sample(prev_rgb, u, v), in_view, covisible


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, world):
    out = tmp_path_factory.mktemp("synthair-geometry") / "ds"
    generate(SynthConfig(out=out, trajectories=1, frames=20, size=SIZE, seed=0), progress=False)
    return out


@pytest.mark.parametrize("climate", CLIMATES)
def test_warping_with_ground_truth_depth_and_motion_explains_the_next_frame(dataset, climate):
    csvs = list((dataset / "splits").rglob(f"SynthAir/{climate}/*.csv"))
    assert len(csvs) == 1
    rows = read_csv(csvs[0])
    assert len(rows) == 4
    warped_err, still_err, co_warped, co_still = [], [], [], []
    for prev, cur in zip(rows[:-1], rows[1:]):
        prev_rgb, cur_rgb = _rgb(dataset / prev["camera_l"]), _rgb(dataset / cur["camera_l"])
        prev_depth, cur_depth = _depth(dataset / prev["disp"]), _depth(dataset / cur["disp"])
        q = np.array([cur["qw"], cur["qx"], cur["qy"], cur["qz"]])
        t = np.array([cur["tx"], cur["ty"], cur["tz"]])
        warped, in_view, covisible = _warp(prev_rgb, prev_depth, cur_depth, q, t)
        assert in_view.mean() > 0.5
        err = np.abs(warped - cur_rgb).mean(-1)
        still = np.abs(prev_rgb - cur_rgb).mean(-1)
        warped_err.append(err[in_view].mean())
        still_err.append(still[in_view].mean())
        co_warped.append(err[covisible].mean())
        co_still.append(still[covisible].mean())
    # on all in-view pixels (occlusion boundaries included) and, stricter, on the surfaces seen in both frames
    assert np.mean(still_err) > 3.0 * np.mean(warped_err), (np.mean(still_err), np.mean(warped_err))
    assert np.mean(co_still) > 3.5 * np.mean(co_warped), (np.mean(co_still), np.mean(co_warped))


def test_a_wrong_motion_does_not_explain_the_next_frame(dataset):
    """The check above has teeth: the same warp with the translation reversed is much worse."""
    rows = read_csv(next((dataset / "splits").rglob("SynthAir/sunny/*.csv")))
    prev, cur = rows[1], rows[2]
    prev_rgb, cur_rgb = _rgb(dataset / prev["camera_l"]), _rgb(dataset / cur["camera_l"])
    prev_depth, cur_depth = _depth(dataset / prev["disp"]), _depth(dataset / cur["disp"])
    q = np.array([cur["qw"], cur["qx"], cur["qy"], cur["qz"]])
    t = np.array([cur["tx"], cur["ty"], cur["tz"]])
    good, in_good, _ = _warp(prev_rgb, prev_depth, cur_depth, q, t)
    bad, in_bad, _ = _warp(prev_rgb, prev_depth, cur_depth, q, -t)
    both = in_good & in_bad
    e_good = np.abs(good - cur_rgb).mean(-1)[both].mean()
    e_bad = np.abs(bad - cur_rgb).mean(-1)[both].mean()
    assert e_bad > 2.0 * e_good
