"""ArduPilot DataFlash: logs packed with pymavlink's own DataFlash structures (and one packed by hand with struct)
are read by pymavlink's mavutil and by read_log, back to the analytic flight within the format's precision."""

import struct

import numpy as np
import pytest
from flightlog_helpers import BOOT, angle_between, angles, euler_matrix, position, quaternion_matrix, sample_times
from pymavlink import mavutil

from cosemdepth.errors import DatasetError
from cosemdepth.flightlogs import read_log
from cosemdepth.flightlogs.dataflash_writer import DataflashWriter

ORIGIN = (46.5, 6.6, 400.0)


def flight_log(path, att=True, xkf1=True, pos=True, gps=False):
    """ATT at 50 Hz, XKF1 (cores 0 and 1) at 25 Hz, POS at 10 Hz, GPS at 5 Hz; TimeUS since boot."""
    import pymap3d

    w = DataflashWriter()
    if att:
        for us in sample_times(50, 0.003, 1e-6):
            r, p, y = np.degrees(angles(us * 1e-6 - BOOT))
            w.add("ATT", us, DesRoll=r, Roll=r, DesPitch=p, Pitch=p, DesYaw=y % 360, Yaw=y % 360)
    if xkf1:
        for us in sample_times(25, 0.011, 1e-6):
            r, p, y = np.degrees(angles(us * 1e-6 - BOOT))
            n, e, d = position(us * 1e-6 - BOOT)[0]
            w.add("XKF1", us, C=0, Roll=r, Pitch=p, Yaw=y % 360, PN=n, PE=e, PD=d)
            w.add("XKF1", us, C=1, Roll=0, Pitch=0, Yaw=0, PN=n + 50, PE=e, PD=d)  # the second core: not used
    if pos:
        for us in sample_times(10, 0.017, 1e-6):
            lat, lon, alt = pymap3d.ned2geodetic(*position(us * 1e-6 - BOOT)[0], *ORIGIN)
            w.add("POS", us, Lat=lat, Lng=lon, Alt=alt, RelHomeAlt=0, RelOriginAlt=0)
    if gps:
        # GPS week 2400, 100 s into it at boot + 12.5 s (TimeUS 12.5e6 at the flight's start)
        for k, us in enumerate(sample_times(5, 0.0, 1e-6)):
            ms = 100_000 + (us - 12_500_000) // 1000
            w.add("GPS", us, Status=3, GWk=2400, GMS=ms, NSats=12, Lat=ORIGIN[0], Lng=ORIGIN[1], Alt=ORIGIN[2])
    w.write(path)
    return path


def test_pymavlink_reads_the_records_as_written(tmp_path):
    path = flight_log(tmp_path / "f.bin")
    log = mavutil.mavlink_connection(str(path))
    atts = []
    while (m := log.recv_match(type="ATT")) is not None:
        atts.append((m.TimeUS, m.Roll, m.Pitch, m.Yaw))
    us = sample_times(50, 0.003, 1e-6)
    assert [a[0] for a in atts] == list(us)
    r, p, y = np.degrees(angles(us * 1e-6 - BOOT))
    np.testing.assert_allclose([a[1] for a in atts], r, atol=0.005 + 1e-9)  # centidegrees in the file
    np.testing.assert_allclose([a[3] for a in atts], y % 360, atol=0.005 + 1e-9)


def test_read_log_reads_att_and_the_first_ekf_core(tmp_path):
    log = read_log(flight_log(tmp_path / "log.dat"))
    assert log.format == "dataflash"
    assert log.used["attitude"].startswith("ATT.Roll/Pitch/Yaw (")
    assert log.used["position"].startswith("XKF1.PN/PE/PD (") and "core 0" in log.used["position"]
    assert angle_between(quaternion_matrix(log.attitude.v), euler_matrix(*angles(log.attitude.t - BOOT))).max() < 0.01
    np.testing.assert_allclose(log.position.v, position(log.position.t - BOOT), atol=2e-5)  # float32 metres
    assert log.position_resolution_m == 0.0
    assert log.utc_offset_s is None


def test_ekf_attitude_when_there_is_no_att(tmp_path):
    log = read_log(flight_log(tmp_path / "f.bin", att=False))
    assert log.used["attitude"].startswith("XKF1.Roll/Pitch/Yaw (")
    assert len(log.attitude) == len(sample_times(25, 0.011, 1e-6))
    assert angle_between(quaternion_matrix(log.attitude.v), euler_matrix(*angles(log.attitude.t - BOOT))).max() < 0.01


def test_positions_from_pos_only_are_metres_from_the_first_fix_with_their_resolution(tmp_path):
    log = read_log(flight_log(tmp_path / "f.bin", xkf1=False, gps=True))
    assert log.used["position"].startswith("POS.Lat/Lng/Alt (") and "first fix" in log.used["position"]
    truth = position(log.position.t - BOOT)
    np.testing.assert_allclose(log.position.v, truth - truth[0], atol=0.02)  # 1e-7 degrees: about 1 cm
    assert log.position_resolution_m == pytest.approx(1e-7 * 111_320, rel=1e-6)
    # UTC = GPS time - 18 s: week 2400, 100 s in, at TimeUS 12.5 s
    assert log.utc_offset_s == pytest.approx(315_964_800 + 2400 * 604_800 + 100 - 18 - 12.5, abs=1e-3)


def test_a_log_packed_by_hand_without_pymavlink(tmp_path):
    """FMT + ATT + XKF1 records packed with struct from the format's definition: Yaw 90 points the nose east,
    Pitch 10 lifts it (NED z negative)."""

    def fmt(type_id, length, name, chars, cols):
        body = struct.pack("<BB4s16s64s", type_id, length, name.encode(), chars.encode(), cols.encode())
        return b"\xa3\x95\x80" + body

    att_cols = "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF"
    data = fmt(128, 89, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")
    data += fmt(35, 3 + struct.calcsize("<QhhhhHHHHB"), "ATT", "QccccCCCCB", att_cols)
    data += fmt(
        37,
        3 + struct.calcsize("<QBhhHfffffffhhhi"),
        "XKF1",
        "QBccCfffffffccce",
        "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH",
    )
    for k in range(5):
        us = 1_000_000 + 20_000 * k
        data += b"\xa3\x95\x23" + struct.pack("<QhhhhHHHHB", us, 0, 0, 1000, 1000, 9000, 9000, 0, 0, 3)
        data += b"\xa3\x95\x25" + struct.pack(
            "<QBhhHfffffffhhhi", us + 5, 0, 0, 1000, 9000, 0, 0, 0, 0, k, 2.0, -3.0, 0, 0, 0, 0
        )
    path = tmp_path / "hand.bin"
    path.write_bytes(data)
    log = read_log(path)
    r = quaternion_matrix(log.attitude.v[:1])[0]
    c, s = np.cos(np.radians(10)), np.sin(np.radians(10))
    np.testing.assert_allclose(r @ [1, 0, 0], [0, c, -s], atol=1e-9)  # nose east, 10 degrees up
    np.testing.assert_allclose(r @ [0, 1, 0], [-1, 0, 0], atol=1e-9)  # the right wing points south
    np.testing.assert_allclose(log.attitude.t, 1.0 + 0.02 * np.arange(5))
    np.testing.assert_allclose(log.position.v, [[k, 2.0, -3.0] for k in range(5)])


def test_a_log_without_attitude_is_refused_naming_the_file(tmp_path):
    path = flight_log(tmp_path / "f.bin", att=False, xkf1=False)
    with pytest.raises(
        DatasetError, match=rf"^{path}: the ArduPilot log has no attitude \(ATT, XKF1 or NKF1\); messages found: POS$"
    ):
        read_log(path)
