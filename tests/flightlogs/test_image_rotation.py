"""The camera's rotation between two frames from the images alone: frames rendered independently (a textured sphere
seen through a pinhole camera at two attitudes), rotation vectors against hand-computed matrices, phase correlation
against a known shift."""

from __future__ import annotations

import numpy as np
import pytest
from _rotation_signals import render_sphere

from cosemdepth.data.quaternion import qfrom_matrix, qmul
from cosemdepth.flightlogs.image_rotation import frame_rotation, matrix_to_rotvec, phase_correlation, rotvec_to_matrix

SIZE, F = (72, 96), 48.0  # a 90-degree horizontal field of view


def test_rotation_vectors_and_matrices():
    rz90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 degrees about z
    np.testing.assert_allclose(rotvec_to_matrix(np.array([0.0, 0.0, np.pi / 2])), rz90, atol=1e-12)
    np.testing.assert_allclose(matrix_to_rotvec(rz90), [0.0, 0.0, np.pi / 2], atol=1e-12)
    rng = np.random.default_rng(0)
    v = rng.normal(size=(20, 3))
    v *= (rng.uniform(0, 3.0, 20) / np.linalg.norm(v, axis=1))[:, None]
    np.testing.assert_allclose(matrix_to_rotvec(rotvec_to_matrix(v)), v, atol=1e-9)
    np.testing.assert_allclose(matrix_to_rotvec(rotvec_to_matrix(np.array([np.pi, 0, 0]))), [np.pi, 0, 0], atol=1e-9)


def test_phase_correlation_finds_a_circular_shift():
    img = np.random.default_rng(1).random((64, 80))
    b = np.roll(img, (-3, 5), axis=(0, 1))  # b(x) = img(x - (5, -3))
    dx, dy = phase_correlation(img, b)
    assert (round(dx), round(dy)) == (-5, 3)


@pytest.mark.parametrize(
    "rotvec",
    [
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 0.05],  # roll only: invisible to a global shift
        [0.0, 0.1, 0.0],  # a pan of about 5 pixels
        [-0.04, 0.02, -0.03],
        [0.003, -0.002, 0.001],
    ],
)
def test_the_rotation_between_two_rendered_frames(rotvec):
    rng = np.random.default_rng(2)
    q_prev = qfrom_matrix(rotvec_to_matrix(rng.normal(size=3)))
    q_rel = qfrom_matrix(rotvec_to_matrix(np.array(rotvec)))
    q_curr = qmul(q_prev, q_rel)  # R_curr = R_prev R, so X_prev = R X_curr
    got = frame_rotation(render_sphere(q_prev, SIZE, F), render_sphere(q_curr, SIZE, F), F)
    assert got.ok and got.overlap > 0.8
    np.testing.assert_allclose(got.rotvec, rotvec, atol=1e-3)


def test_a_frame_without_texture_determines_nothing():
    flat = np.full(SIZE, 0.5)
    assert not frame_rotation(flat, flat, F).ok
    stripes = np.tile(np.sin(np.arange(SIZE[1]) / 3.0), (SIZE[0], 1))  # rotation about the stripes' axis unseen
    assert not frame_rotation(stripes, stripes, F).ok


def test_unrelated_frames_determine_nothing():
    rng = np.random.default_rng(4)
    a, b = rng.random(SIZE), rng.random(SIZE)  # noise on a blank sky, say
    assert not frame_rotation(a, b, F).ok
