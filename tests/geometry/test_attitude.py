"""Numpy attitude maths (cosemdepth.geometry.attitude) against hand-computed rotations: aerospace Z-Y-X angles,
quaternion <-> matrix for every branch (180 degree turns included), Euler round trips at gimbal lock, slerp."""

import numpy as np
import pytest

from cosemdepth.geometry.attitude import (
    euler_to_matrix,
    euler_to_quat,
    matrix_to_quat,
    quat_multiply,
    quat_to_euler,
    quat_to_matrix,
    slerp,
)


def test_euler_angles_on_an_frd_body_in_ned_by_hand():
    # yaw 90: nose east; pitch +30: nose up (NED z negative); roll +90: right wing down
    np.testing.assert_allclose(euler_to_matrix(0, 0, np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    np.testing.assert_allclose(euler_to_matrix(0, np.pi / 6, 0) @ [1, 0, 0], [c, 0, -s], atol=1e-15)
    np.testing.assert_allclose(euler_to_matrix(np.pi / 2, 0, 0) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    # Z-Y-X: yaw 90 then pitch 30 about the new y (the right wing, pointing south): the nose east and up
    np.testing.assert_allclose(euler_to_matrix(0, np.pi / 6, np.pi / 2) @ [1, 0, 0], [0, c, -s], atol=1e-15)


def test_quaternions_and_matrices_agree_on_random_and_half_turns():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    half_turns = np.array([[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, np.sqrt(0.5), np.sqrt(0.5), 0]])
    q = np.concatenate([q, half_turns])
    back = matrix_to_quat(quat_to_matrix(q))
    np.testing.assert_allclose(np.abs(np.sum(back * q, axis=1)), 1.0, atol=1e-12)
    assert np.all(back[:, 0] >= 0)
    np.testing.assert_allclose(
        quat_to_matrix(euler_to_quat(0.3, -0.2, 2.5)), euler_to_matrix(0.3, -0.2, 2.5), atol=1e-15
    )


def test_quaternion_product_is_the_matrix_product():
    a, b = euler_to_quat(0.1, 0.2, 0.3), euler_to_quat(-0.5, 0.4, 1.9)
    np.testing.assert_allclose(quat_to_matrix(quat_multiply(a, b)), quat_to_matrix(a) @ quat_to_matrix(b), atol=1e-15)


@pytest.mark.parametrize("rpy", [(0.3, -0.2, 2.5), (-3.0, 1.2, -0.4), (0.7, np.pi / 2, 0.2), (0.1, -np.pi / 2, -2.0)])
def test_euler_round_trip_gives_the_same_rotation_even_at_gimbal_lock(rpy):
    q = euler_to_quat(*rpy)
    back = euler_to_quat(*quat_to_euler(q))
    np.testing.assert_allclose(quat_to_matrix(back), quat_to_matrix(q), atol=1e-9)


def test_slerp_by_hand():
    def yaw(deg):
        return np.array([np.cos(np.radians(deg) / 2), 0, 0, np.sin(np.radians(deg) / 2)])

    np.testing.assert_allclose(slerp(yaw(10), yaw(50), 0.25), yaw(20), atol=1e-15)
    np.testing.assert_allclose(np.abs(slerp(yaw(170), -yaw(-170), 0.5) @ yaw(180)), 1.0, atol=1e-12)  # short arc
    np.testing.assert_allclose(slerp(yaw(1), yaw(1 + 1e-6), 0.5), yaw(1 + 5e-7), atol=1e-12)  # nearly equal
