"""PX4 ULog: the project's writer (written from the format specification) and pyulog agree, and read_log reads the
analytic flight back, from vehicle_odometry or from vehicle_attitude + vehicle_local_position, with PX4's validity
rules (NaN, xy_valid/z_valid, pose_frame)."""

import numpy as np
import pytest
import pyulog
from flightlog_helpers import (
    BOOT,
    angle_between,
    angles,
    euler_matrix,
    position,
    quaternion_matrix,
    sample_times,
    truth_quaternions,
)

from cosemdepth.errors import DatasetError
from cosemdepth.flightlogs import read_log
from cosemdepth.flightlogs.ulog_writer import PX4_FORMATS, Topic, write_ulog


def topic(name, ticks, **data):
    return Topic(name, PX4_FORMATS[name], {"timestamp": ticks + 400, "timestamp_sample": ticks, **data})


def flight_topics(odometry=True, attitude=True, local=True):
    """vehicle_attitude at 200 Hz, vehicle_local_position at 50 Hz, vehicle_odometry at 100 Hz, microseconds."""
    out = []
    if attitude:
        t = sample_times(200, 0.0013, 1e-6)
        out.append(topic("vehicle_attitude", t, q=truth_quaternions(t * 1e-6 - BOOT)))
    if local:
        t = sample_times(50, 0.0071, 1e-6)
        p = position(t * 1e-6 - BOOT)
        ones = np.ones(len(t))
        out.append(topic("vehicle_local_position", t, x=p[:, 0], y=p[:, 1], z=p[:, 2], xy_valid=ones, z_valid=ones))
    if odometry:
        t = sample_times(100, 0.0049, 1e-6)
        tau = t * 1e-6 - BOOT
        out.append(
            topic("vehicle_odometry", t, position=position(tau), q=truth_quaternions(tau), pose_frame=np.ones(len(t)))
        )
    return out


def test_pyulog_reads_what_the_writer_wrote(tmp_path):
    topics = flight_topics()
    path = tmp_path / "f.ulg"
    write_ulog(path, topics, start_us=12_000_000, info={"sys_name": "PX4"}, parameters={"MPC_XY_VEL_MAX": 12.0})
    log = pyulog.ULog(str(path))
    assert not log.file_corruption
    assert log.start_timestamp == 12_000_000
    assert log.msg_info_dict["sys_name"] == "PX4"
    assert log.initial_parameters["MPC_XY_VEL_MAX"] == pytest.approx(12.0)
    data = {d.name: d.data for d in log.data_list}
    for t in topics:
        d = data[t.name]
        np.testing.assert_array_equal(d["timestamp_sample"], t.data["timestamp_sample"])
        np.testing.assert_array_equal(d["timestamp"], t.data["timestamp"])
    att = next(t for t in topics if t.name == "vehicle_attitude")
    q = np.stack([data["vehicle_attitude"][f"q[{i}]"] for i in range(4)], 1)
    np.testing.assert_array_equal(q, att.data["q"].astype(np.float32))
    assert "_padding0" not in data["vehicle_attitude"]  # declared in the format, not logged


def test_read_log_prefers_vehicle_odometry_and_reads_the_flight_back(tmp_path):
    path = tmp_path / "flight.log"  # the name says nothing: the content does
    write_ulog(path, flight_topics(), start_us=12_000_000)
    log = read_log(path)
    assert log.format == "ulog" and log.position_resolution_m == 0.0
    assert log.used["attitude"].startswith("vehicle_odometry.q (")
    assert "NED world" in log.used["attitude"] and "timestamp_sample" in log.used["attitude"]
    tau = log.attitude.t - BOOT
    assert len(log.attitude) == len(sample_times(100, 0.0049, 1e-6))
    assert angle_between(quaternion_matrix(log.attitude.v), euler_matrix(*angles(tau))).max() < 1e-4  # float32
    np.testing.assert_allclose(log.position.v, position(log.position.t - BOOT), atol=2e-5)


def test_without_odometry_attitude_and_local_position_are_used_with_their_validity(tmp_path):
    topics = flight_topics(odometry=False)
    local = next(t for t in topics if t.name == "vehicle_local_position")
    local.data["xy_valid"] = local.data["xy_valid"].copy()
    local.data["xy_valid"][10:20] = 0  # an estimator without a horizontal fix for a while
    att = next(t for t in topics if t.name == "vehicle_attitude")
    att.data["q"] = att.data["q"].copy()
    att.data["q"][5] = np.nan  # PX4's "no estimate"
    att.data["q"][6] = 0.0
    path = tmp_path / "f.ulg"
    write_ulog(path, topics, start_us=12_000_000)
    log = read_log(path)
    assert log.used["attitude"].startswith("vehicle_attitude.q (")
    assert log.used["position"].startswith("vehicle_local_position.x/y/z where xy_valid and z_valid (")
    assert len(log.attitude) == len(att.data["q"]) - 2
    assert len(log.position) == len(local.data["x"]) - 10
    assert not np.isin(log.position.t, local.data["timestamp_sample"][10:20] * 1e-6).any()
    assert angle_between(quaternion_matrix(log.attitude.v), euler_matrix(*angles(log.attitude.t - BOOT))).max() < 1e-4


def test_times_are_the_sample_times_not_the_publication_times(tmp_path):
    path = tmp_path / "f.ulg"
    write_ulog(path, flight_topics(odometry=False), start_us=0)
    log = read_log(path)
    t = sample_times(200, 0.0013, 1e-6)
    np.testing.assert_array_equal(log.attitude.t, t * 1e-6)  # timestamp is 400 us later


def test_a_frd_odometry_frame_is_read_and_said(tmp_path):
    t = sample_times(100, 0.0, 1e-6)
    tau = t * 1e-6 - BOOT
    frd = 2 * np.ones(len(t))
    topics = [topic("vehicle_odometry", t, position=position(tau), q=truth_quaternions(tau), pose_frame=frd)]
    path = tmp_path / "f.ulg"
    write_ulog(path, topics, start_us=0)
    log = read_log(path)
    assert "FRD world" in log.used["position"]
    assert len(log.position) == len(t)


def test_a_hand_made_yaw_of_90_degrees_turns_the_nose_east(tmp_path):
    t = np.arange(10) * 10_000 + 1_000_000
    q = np.tile([np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)], (10, 1))  # 90 degrees about NED z (down): clockwise from above
    write_ulog(tmp_path / "f.ulg", [topic("vehicle_attitude", t, q=q)], start_us=0)
    log = read_log(tmp_path / "f.ulg")
    forward_ned = quaternion_matrix(log.attitude.v[:1])[0] @ [1, 0, 0]
    np.testing.assert_allclose(forward_ned, [0, 1, 0], atol=1e-7)
    assert log.position is None


def test_a_log_without_attitude_is_refused_naming_the_file(tmp_path):
    path = tmp_path / "f.ulg"
    write_ulog(path, flight_topics(odometry=False, attitude=False), start_us=0)
    with pytest.raises(DatasetError, match=rf"^{path}: the PX4 log has no attitude .*vehicle_local_position$"):
        read_log(path)
