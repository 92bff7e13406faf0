"""MAVLink telemetry logs: packets packed with pymavlink's message classes behind 8-byte reception times are read
by pymavlink's mavutil and by read_log, which keeps the vehicle's own messages and its time_boot_ms clock."""

import struct

import numpy as np
import pymap3d
import pytest
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
from pymavlink import mavutil

from cosemdepth.errors import DatasetError
from cosemdepth.flightlogs import read_log
from cosemdepth.flightlogs.tlog_writer import TlogWriter

ORIGIN = (46.5, 6.6, 400.0)
#: Unix time of the boot (microseconds); the link delays every packet by 20 ms.
BOOT_UNIX_US = 1_790_000_000_000_000
DELAY_US = 20_000


def flight_tlog(path, local=True, global_=True, quaternion=False, system_time=True, intruder=True):
    w = TlogWriter()
    for ms in sample_times(50, 0.004, 1e-3):
        roll, pitch, yaw = angles(ms * 1e-3 - BOOT)
        rx = BOOT_UNIX_US + ms * 1000 + DELAY_US
        if quaternion:
            q = truth_quaternions(ms * 1e-3 - BOOT)[0]
            w.add(rx, "ATTITUDE_QUATERNION", time_boot_ms=ms, q1=q[0], q2=q[1], q3=q[2], q4=q[3])
        else:
            w.add(rx, "ATTITUDE", time_boot_ms=ms, roll=roll[()], pitch=pitch[()], yaw=yaw[()])
    for ms in sample_times(20, 0.013, 1e-3):
        x, y, z = position(ms * 1e-3 - BOOT)[0]
        rx = BOOT_UNIX_US + ms * 1000 + DELAY_US
        if local:
            w.add(rx, "LOCAL_POSITION_NED", time_boot_ms=ms, x=x, y=y, z=z)
        if global_:
            lat, lon, alt = pymap3d.ned2geodetic(x, y, z, *ORIGIN)
            w.add(
                rx,
                "GLOBAL_POSITION_INT",
                time_boot_ms=ms,
                lat=round(lat * 1e7),
                lon=round(lon * 1e7),
                alt=round(alt * 1e3),
            )
    for ms in sample_times(1, 0.1, 1e-3):
        w.add(BOOT_UNIX_US + ms * 1000 + DELAY_US, "HEARTBEAT", type=2, autopilot=3, mavlink_version=3)
        if system_time:
            w.add(
                BOOT_UNIX_US + ms * 1000 + DELAY_US,
                "SYSTEM_TIME",
                time_unix_usec=BOOT_UNIX_US + ms * 1000,
                time_boot_ms=ms,
            )
        if intruder:  # a companion computer (system 2) with its own, wrong, attitude
            w.add(BOOT_UNIX_US + ms * 1000, "ATTITUDE", system=2, time_boot_ms=ms + 7, roll=1.0, pitch=1.0, yaw=1.0)
            w.add(BOOT_UNIX_US + ms * 1000, "HEARTBEAT", system=255, component=190, type=6, autopilot=8)
    w.write(path)
    return path


def test_mavutil_reads_the_packets_and_their_reception_times(tmp_path):
    path = flight_tlog(tmp_path / "f.tlog")
    log = mavutil.mavlink_connection(str(path))
    got = []
    while (m := log.recv_match(type="ATTITUDE")) is not None:
        if m.get_srcSystem() == 1:
            got.append((m.time_boot_ms, m._timestamp, m.yaw))
    ms = sample_times(50, 0.004, 1e-3)
    assert [g[0] for g in got] == list(ms)
    np.testing.assert_allclose([g[1] for g in got], (BOOT_UNIX_US + ms * 1000 + DELAY_US) * 1e-6, atol=1e-6)
    np.testing.assert_allclose([g[2] for g in got], angles(ms * 1e-3 - BOOT)[2], atol=1e-6)  # float32 radians
    assert path.read_bytes()[8] == 0xFD  # MAVLink 2


def test_read_log_keeps_the_vehicle_and_reads_the_flight_back(tmp_path):
    log = read_log(flight_tlog(tmp_path / "f.bin"))
    assert log.format == "tlog"
    assert log.used["system"] == "system id 1 (of 2 systems in the log)"
    assert log.used["attitude"].startswith("ATTITUDE.roll/pitch/yaw (")
    assert log.used["position"].startswith("LOCAL_POSITION_NED.x/y/z (")
    ms = sample_times(50, 0.004, 1e-3)
    np.testing.assert_array_equal(log.attitude.t, ms * 1e-3)  # time_boot_ms, not the reception time
    assert angle_between(quaternion_matrix(log.attitude.v), euler_matrix(*angles(log.attitude.t - BOOT))).max() < 1e-4
    np.testing.assert_allclose(log.position.v, position(log.position.t - BOOT), atol=2e-5)
    assert log.used["utc"] == "SYSTEM_TIME.time_unix_usec"
    assert log.utc_offset_s == pytest.approx(BOOT_UNIX_US * 1e-6, abs=1e-6)


def test_attitude_quaternion_is_preferred(tmp_path):
    log = read_log(flight_tlog(tmp_path / "f.tlog", quaternion=True, intruder=False))
    assert log.used["attitude"].startswith("ATTITUDE_QUATERNION.q1..q4 (")
    assert angle_between(quaternion_matrix(log.attitude.v), euler_matrix(*angles(log.attitude.t - BOOT))).max() < 1e-4


def test_global_positions_only_are_metres_from_the_first_fix_with_their_resolution(tmp_path):
    log = read_log(flight_tlog(tmp_path / "f.tlog", local=False, system_time=False))
    assert log.used["position"].startswith("GLOBAL_POSITION_INT.lat/lon/alt (")
    truth = position(log.position.t - BOOT)
    np.testing.assert_allclose(log.position.v, truth - truth[0], atol=0.02)
    assert log.position_resolution_m == pytest.approx(1e-7 * 111_320, rel=1e-6)
    assert "reception times" in log.used["utc"]  # no SYSTEM_TIME: the link's delay is in the offset
    assert log.utc_offset_s == pytest.approx(BOOT_UNIX_US * 1e-6 + DELAY_US * 1e-6, abs=1e-6)


def test_a_log_without_attitude_is_refused_naming_the_file(tmp_path):
    w = TlogWriter()
    w.add(BOOT_UNIX_US, "HEARTBEAT", type=2, autopilot=3)
    w.add(BOOT_UNIX_US + 1000, "LOCAL_POSITION_NED", time_boot_ms=5, x=1.0)
    path = tmp_path / "f.tlog"
    w.write(path)
    with pytest.raises(DatasetError, match=rf"^{path}: the telemetry log has no attitude .*LOCAL_POSITION_NED$"):
        read_log(path)


def test_garbage_between_packets_is_skipped_and_noted(tmp_path):
    path = flight_tlog(tmp_path / "f.tlog", intruder=False)
    data = bytearray(path.read_bytes())
    good = read_log(path)
    junk = struct.pack(">Q", BOOT_UNIX_US) + b"\x00\x11\x22\x33" * 8  # a stamp followed by no packet
    cut = 36 * 40  # well inside the log, at no packet boundary in particular
    path.write_bytes(bytes(data[:cut]) + junk + bytes(data[cut:]))
    log = read_log(path)
    assert "damage" in log.used
    # what was read is the same flight: every sample read lies on the flight
    assert angle_between(quaternion_matrix(log.attitude.v), euler_matrix(*angles(log.attitude.t - BOOT))).max() < 1e-4
    assert len(log.attitude) >= len(good.attitude) - 3
