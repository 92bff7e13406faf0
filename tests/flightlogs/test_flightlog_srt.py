"""DJI subtitles: the common layouts (written here by hand in each model's layout) give positions in metres from
the first fix (checked against the WGS84 radii of curvature), the printed resolution, and attitude where the file
has angles (aircraft F.PRY, gimbal G.PRY / gb_*)."""

import math

import numpy as np
import pytest
from flightlog_helpers import quaternion_matrix

from cosemdepth.errors import DatasetError
from cosemdepth.flightlogs import read_log
from cosemdepth.flightlogs.srt_writer import srt_text

A, E2 = 6378137.0, 6.69437999014e-3  # WGS84


def metres(lat0, dlat, dlon):
    """North and east metres of small steps (degrees) at latitude lat0: meridian and prime-vertical radii."""
    s2 = math.sin(math.radians(lat0)) ** 2
    m = A * (1 - E2) / (1 - E2 * s2) ** 1.5
    n = A / math.sqrt(1 - E2 * s2)
    return m * math.radians(dlat), n * math.cos(math.radians(lat0)) * math.radians(dlon)


MAVIC3 = """1
00:00:00,000 --> 00:00:00,033
<font size="28">FrameCnt: 1, DiffTime: 33ms
2025-05-01 09:30:12.101
[iso: 100] [shutter: 1/1000.0] [fnum: 1.7] [ev: 0] [color_md: default] [focal_len: 24.00] [latitude: 46.500000] [longitude: 6.600000] [rel_alt: 30.000 abs_alt: 500.000] [ct: 5300] </font>

2
00:00:00,033 --> 00:00:00,067
<font size="28">FrameCnt: 2, DiffTime: 34ms
2025-05-01 09:30:12.134
[iso: 100] [shutter: 1/1000.0] [fnum: 1.7] [ev: 0] [color_md: default] [focal_len: 24.00] [latitude: 46.500010] [longitude: 6.600010] [rel_alt: 32.000 abs_alt: 502.000] [ct: 5300] </font>
"""

MAVIC2 = """1
00:00:00,000 --> 00:00:00,033
<font size="36">SrtCnt : 1, DiffTime : 33ms
2019-06-02 11:00:00,000,000
[iso : 100] [shutter : 1/500.0] [fnum : 280] [ev : 0] [ct : 5000] [color_md : default] [focal_len : 240] [latitude : 51.200000] [longtitude : 4.400000] [altitude: 30.000000] </font>

2
00:00:00,033 --> 00:00:00,067
<font size="36">SrtCnt : 2, DiffTime : 34ms
2019-06-02 11:00:00,033,333
[iso : 100] [shutter : 1/500.0] [fnum : 280] [ev : 0] [ct : 5000] [color_md : default] [focal_len : 240] [latitude : 51.200000] [longtitude : 4.400020] [altitude: 30.500000] </font>
"""

MAVIC_PRO = """1
00:00:00,000 --> 00:00:01,000
HOME(120.0000,-30.0000) 2017.07.01 10:00:00
GPS(120.0000,-30.0000,15) BAROMETER:10.0
ISO:100 Shutter:60 EV:0 Fnum:2.2 

2
00:00:01,000 --> 00:00:02,000
HOME(120.0000,-30.0000) 2017.07.01 10:00:01
GPS(120.0001,-30.0000,15) BAROMETER:11.5
ISO:100 Shutter:60 EV:0 Fnum:2.2 
"""

M300 = """1
00:00:00,000 --> 00:00:01,000
2022.06.01 16:00:00
GPS(40.0000,-3.0000,12.0M) BAROMETER:10.0M

2
00:00:01,000 --> 00:00:02,000
2022.06.01 16:00:01
GPS(40.0001,-3.0000,12.0M) BAROMETER:10.4M
"""

P4RTK = """1
00:00:00,000 --> 00:00:01,000
F/5.6, SS 400, ISO 100, EV 0, GPS (10.000000, 50.000000, 18), HOME (10.000000, 50.000000, 100.00m), D 0.00m, H 40.00m, H.S 0.00m/s, V.S 0.00m/s, F.PRY (0.0°, 0.0°, 90.0°), G.PRY (-90.0°, 0.0°, 90.0°)

2
00:00:01,000 --> 00:00:02,000
F/5.6, SS 400, ISO 100, EV 0, GPS (10.000000, 50.000010, 18), HOME (10.000000, 50.000000, 100.00m), D 1.10m, H 41.00m, H.S 1.00m/s, V.S 1.00m/s, F.PRY (0.0°, 0.0°, 90.0°), G.PRY (-90.0°, 0.0°, 90.0°)
"""


def write(tmp_path, text, name="DJI_0001.SRT"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_mavic3_positions_and_resolution(tmp_path):
    log = read_log(write(tmp_path, MAVIC3), require_attitude=False)
    assert log.format == "srt" and log.attitude is None and log.utc_offset_s is None
    np.testing.assert_allclose(log.position.t, [0.0, 0.033])
    n, e = metres(46.5, 1e-5, 1e-5)
    np.testing.assert_allclose(log.position.v, [[0, 0, 0], [n, e, -2.0]], atol=1e-4)
    assert log.position_resolution_m == pytest.approx(1e-6 * 111_320, rel=1e-9)  # 6 decimals of a degree
    assert "altitude from abs_alt" in log.used["position"]
    assert "2025-05-01 09:30:12.101" in log.used["clock"]


def test_mavic2_longtitude_spelling(tmp_path):
    log = read_log(write(tmp_path, MAVIC2), require_attitude=False)
    n, e = metres(51.2, 0.0, 2e-5)
    np.testing.assert_allclose(log.position.v[1], [0, e, -0.5], atol=1e-4)


def test_mavic_pro_writes_longitude_first_once_a_second(tmp_path):
    log = read_log(write(tmp_path, MAVIC_PRO), require_attitude=False)
    assert "GPS(longitude, latitude, ...)" in log.used["position"] and "from BAROMETER" in log.used["position"]
    n, e = metres(-30.0, 0.0, 1e-4)
    np.testing.assert_allclose(log.position.v[1], [0, e, -1.5], atol=1e-4)
    assert log.position_resolution_m == pytest.approx(1e-4 * 111_320, rel=1e-9)  # 11 m: 4 decimals


def test_matrice_300_writes_latitude_first(tmp_path):
    log = read_log(write(tmp_path, M300), require_attitude=False)
    assert "GPS(latitude, longitude, ...)" in log.used["position"]
    n, e = metres(40.0, 1e-4, 0.0)
    np.testing.assert_allclose(log.position.v[1], [n, 0, 0], atol=1e-4)  # altitude from the GPS(... M) value


def test_p4_rtk_aircraft_and_gimbal_attitude(tmp_path):
    """F.PRY (pitch 0, roll 0, yaw 90): the nose east; G.PRY (pitch -90, yaw 90): the camera looks straight down
    with the image's top toward the nose: relative to the body, the 'down' mount."""
    log = read_log(write(tmp_path, P4RTK))
    r_body = quaternion_matrix(log.attitude.v)[0]
    np.testing.assert_allclose(r_body @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    r_rel = quaternion_matrix(log.gimbal.v)[0]  # camera FRD -> body FRD
    np.testing.assert_allclose(r_rel @ [1, 0, 0], [0, 0, 1], atol=1e-9)  # camera forward = body down
    np.testing.assert_allclose(r_rel @ [0, 0, -1], [1, 0, 0], atol=1e-9)  # image top = body front
    n, _ = metres(50.0, 1e-5, 0.0)
    np.testing.assert_allclose(log.position.v[1], [n, 0, -1.0], atol=1e-4)  # longitude first, H for the height
    assert "from H" in log.used["position"]


def test_mavic3t_gimbal_angles_are_the_camera_s_attitude(tmp_path):
    text = srt_text(
        np.array([0.0, 0.04]),
        np.array([46.5, 46.5]),
        np.array([6.6, 6.6]),
        np.array([10.0, 10.0]),
        np.array([500.0, 500.0]),
        np.array([[180.0, -30.0, 0.0], [180.0, -30.0, 0.0]]),  # yaw, pitch, roll: facing south, 30 degrees down
    )
    log = read_log(write(tmp_path, text))
    r = quaternion_matrix(log.attitude.v)[0]
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(r @ [1, 0, 0], [-c, 0, s], atol=1e-9)  # looking south and down
    np.testing.assert_allclose(log.gimbal.v, [[1, 0, 0, 0], [1, 0, 0, 0]])
    assert "the camera's own attitude" in log.used["attitude"]


def test_no_attitude_is_refused_unless_positions_alone_are_asked_for(tmp_path):
    path = write(tmp_path, MAVIC3)
    with pytest.raises(DatasetError, match=rf"^{path}: this DJI subtitle file has no attitude"):
        read_log(path)


def test_no_fix_is_dropped_and_a_cut_last_line_is_not_misread(tmp_path):
    no_fix = MAVIC3.replace("[latitude: 46.500000] [longitude: 6.600000]", "[latitude: 0.000000] [longitude: 0.000000]")
    log = read_log(write(tmp_path, no_fix), require_attitude=False)
    np.testing.assert_allclose(log.position.t, [0.033])
    cut = MAVIC3[: MAVIC3.rindex("[longitude") + len("[longitude: 6.6")]  # the file ends inside a number
    log = read_log(write(tmp_path, cut, "cut.SRT"), require_attitude=False)
    np.testing.assert_allclose(log.position.t, [0.0])  # the cut subtitle has no complete position
