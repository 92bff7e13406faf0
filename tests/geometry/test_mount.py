"""The camera mount (cosemdepth.geometry.mount) against rotations written out by hand: each preset on a body
yawed 90 degrees in NED, pitched mounts, the lever arm, Kalibr's T_cam_imu, a gimbal, and the model's motion."""

import numpy as np
import pytest

from cosemdepth.data.poses import relative_camera_motions
from cosemdepth.errors import ConfigError
from cosemdepth.geometry.mount import OPTICAL_FROM_CAMERA_FRD, camera_poses, optical_to_camera_frd, parse_mount

S = np.sqrt(0.5)
YAW90 = np.array([[S, 0.0, 0.0, S]])  # body FRD -> NED: the nose east, the right wing south, the belly down


def rotation(q):
    w, x, y, z = np.asarray(q, dtype=float).reshape(4)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def optical_in_ned(spec, q_body=YAW90, p_body=np.zeros((1, 3))):
    mount = parse_mount(spec)
    q, p = camera_poses(q_body, p_body, mount.R_body_optical, mount.lever_arm)
    return rotation(q[0]), p[0]


def test_the_optical_frame_is_right_down_forward_of_the_camera():
    # x = r, y = d, z = f: the rows of M pick right, down, forward out of (f, r, d)
    np.testing.assert_array_equal(OPTICAL_FROM_CAMERA_FRD @ [1, 0, 0], [0, 0, 1])
    np.testing.assert_array_equal(OPTICAL_FROM_CAMERA_FRD @ [0, 1, 0], [1, 0, 0])
    np.testing.assert_array_equal(OPTICAL_FROM_CAMERA_FRD @ [0, 0, 1], [0, 1, 0])


def test_forward_camera_on_a_body_yawed_90_degrees():
    """Looking east (z), the image's right is south (x = -north), its down is down (y)."""
    r, _ = optical_in_ned("forward")
    np.testing.assert_allclose(r[:, 0], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(r[:, 1], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(r[:, 2], [0, 1, 0], atol=1e-12)


def test_down_camera_on_a_body_yawed_90_degrees():
    """Looking down (z = +down), the image's top toward the nose (east): y (image down) = west, x (image right) =
    the right wing = south. R_ned_optical = diag(-1, -1, 1)."""
    r, _ = optical_in_ned("down")
    np.testing.assert_allclose(r, np.diag([-1.0, -1.0, 1.0]), atol=1e-12)
    r2, _ = optical_in_ned("0,-90,0")
    np.testing.assert_array_equal(r, r2)


def test_pitched_down_30_degrees_on_a_level_body_facing_north():
    r, _ = optical_in_ned("0,-30,0", q_body=np.array([[1.0, 0, 0, 0]]))
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    np.testing.assert_allclose(r[:, 2], [c, 0, s], atol=1e-12)  # forward and 30 degrees below the horizon
    np.testing.assert_allclose(r[:, 0], [0, 1, 0], atol=1e-12)  # image right = east
    np.testing.assert_allclose(r[:, 1], [-s, 0, c], atol=1e-12)  # image down: down and back


def test_a_camera_yawed_right_and_rolled():
    """R,P,Y = 0,0,90 looks out of the right wing; 90,0,0 is the forward camera rolled: image right = body down."""
    r, _ = optical_in_ned("0,0,90", q_body=np.array([[1.0, 0, 0, 0]]))
    np.testing.assert_allclose(r[:, 2], [0, 1, 0], atol=1e-12)
    r, _ = optical_in_ned("90,0,0", q_body=np.array([[1.0, 0, 0, 0]]))
    np.testing.assert_allclose(r[:, 0], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(r[:, 2], [1, 0, 0], atol=1e-12)


def test_the_lever_arm_is_in_body_axes():
    _, p = optical_in_ned("down@0.5,0,0.1", p_body=np.array([[10.0, 20.0, -30.0]]))
    np.testing.assert_allclose(p, [10.0, 20.5, -29.9], atol=1e-12)  # 0.5 m ahead of the nose = east


def test_kalibr_camchain_t_cam_imu_and_t_body_cam(tmp_path):
    """A down camera 0.1 m ahead of and 0.05 m below the IMU: T_cam_imu = [R^T, -R^T lever] with R the hand-made
    R_body_optical of the down mount."""
    r_body_opt = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=float)  # columns: right, back, down
    lever = np.array([0.1, 0.0, 0.05])
    t_cam_imu = np.eye(4)
    t_cam_imu[:3, :3] = r_body_opt.T
    t_cam_imu[:3, 3] = -r_body_opt.T @ lever
    (tmp_path / "camchain.yaml").write_text(
        "cam0:\n  camera_model: pinhole\n  intrinsics: [400, 400, 320, 240]\n  T_cam_imu:\n"
        + "".join(f"  - [{', '.join(f'{v:.10f}' for v in row)}]\n" for row in t_cam_imu)
        + "  timeshift_cam_imu: 0.0\n"
    )
    mount = parse_mount(str(tmp_path / "camchain.yaml"))
    np.testing.assert_allclose(mount.R_body_optical, r_body_opt, atol=1e-9)
    np.testing.assert_allclose(mount.R_body_optical, parse_mount("down").R_body_optical, atol=1e-9)
    np.testing.assert_allclose(mount.lever_arm, lever, atol=1e-9)
    t_body_cam = np.eye(4)
    t_body_cam[:3, :3], t_body_cam[:3, 3] = r_body_opt, lever
    (tmp_path / "t.yaml").write_text(f"T_body_cam: {t_body_cam.tolist()}\n")
    mount = parse_mount(str(tmp_path / "t.yaml"))
    np.testing.assert_allclose(mount.R_body_optical, r_body_opt, atol=1e-12)
    np.testing.assert_allclose(mount.lever_arm, lever, atol=1e-12)


@pytest.mark.parametrize(
    "spec, message",
    [
        ("sideways", "not forward, down, R,P,Y"),
        ("0,-30", "not forward, down, R,P,Y"),
        ("0,-400,0", "roll, pitch, yaw must be degrees in"),
        ("down@1,2", "the lever arm after '@' must be X,Y,Z"),
        ("", "expected forward, down"),
    ],
)
def test_bad_specs_are_one_line_errors_naming_the_option(spec, message):
    with pytest.raises(ConfigError, match=f"^--camera-mount.*{message}"):
        parse_mount(spec)


def test_bad_calibration_files_are_refused(tmp_path):
    (tmp_path / "scaled.yaml").write_text(f"T_body_cam: {(np.eye(4) * [2, 1, 1, 1]).tolist()}\n")
    with pytest.raises(ConfigError, match="is not a rotation"):
        parse_mount(str(tmp_path / "scaled.yaml"))
    (tmp_path / "other.yaml").write_text("cam0: {intrinsics: [1, 2, 3, 4]}\n")
    with pytest.raises(ConfigError, match=r"has no cam0\.T_cam_imu"):
        parse_mount(str(tmp_path / "other.yaml"))
    with pytest.raises(ConfigError, match="has its own lever arm"):
        parse_mount(str(tmp_path / "other.yaml") + "@1,0,0")


def test_a_gimbal_replaces_the_mount_s_rotation_and_keeps_the_lever_arm():
    mount = parse_mount("down@1,0,0")
    level = np.array([[1.0, 0, 0, 0]])  # gimbal at rest: camera FRD = body FRD
    q, p = camera_poses(YAW90, np.zeros((1, 3)), mount.R_body_optical, mount.lever_arm, gimbal_q=level)
    forward, _ = optical_in_ned("forward")
    np.testing.assert_allclose(rotation(q[0]), forward, atol=1e-12)
    np.testing.assert_allclose(p[0], [0, 1, 0], atol=1e-12)


def test_optical_to_camera_frd_gives_the_camera_s_forward_right_down():
    r, _ = optical_in_ned("down")
    q_opt = camera_poses(YAW90, np.zeros((1, 3)), parse_mount("down").R_body_optical)[0]
    r_frd = rotation(optical_to_camera_frd(q_opt)[0])
    np.testing.assert_allclose(r_frd[:, 0], r[:, 2], atol=1e-12)  # forward = optical z
    np.testing.assert_allclose(r_frd[:, 1], r[:, 0], atol=1e-12)  # right = optical x
    np.testing.assert_allclose(r_frd[:, 2], r[:, 1], atol=1e-12)  # down = optical y


def test_the_model_s_motion_from_a_body_flying_north():
    """A level body flying 1 m north: the forward camera moves 1 m along its z (X_prev = R X_curr + t, t = (0, 0,
    1)); the down camera moves toward its image's top: t = (0, -1, 0)."""
    q_body = np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]])
    p_body = np.array([[0.0, 0, -20], [1.0, 0, -20]])
    for spec, t_expected in (("forward", [0, 0, 1]), ("down", [0, -1, 0])):
        mount = parse_mount(spec)
        q, p = camera_poses(q_body, p_body, mount.R_body_optical, mount.lever_arm)
        rot, trans = relative_camera_motions(q, p, "opencv")
        np.testing.assert_allclose(trans[1], t_expected, atol=1e-12)
        np.testing.assert_allclose(rot[1], [1, 0, 0, 0], atol=1e-12)
