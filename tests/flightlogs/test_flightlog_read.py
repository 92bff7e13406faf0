"""read_log on bad input (unknown, empty, random, truncated files, a wrong --log-format, a missing library) and
FlightLog.pose_at's interpolation and coverage, against hand-computed values."""

import sys

import numpy as np
import pytest
from flightlog_helpers import BOOT, angle_between, angles, euler_matrix, quaternion_matrix
from test_flightlog_dataflash import flight_log
from test_flightlog_tlog import flight_tlog
from test_flightlog_ulog import flight_topics

from cosemdepth.errors import ConfigError, DatasetError
from cosemdepth.flightlogs import FlightLog, Series, read_log
from cosemdepth.flightlogs.log import make_series
from cosemdepth.flightlogs.ulog_writer import write_ulog


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("logs")
    write_ulog(d / "a.ulg", flight_topics(), start_us=12_000_000)
    flight_log(d / "a.bin")
    flight_tlog(d / "a.tlog")
    return {"ulog": d / "a.ulg", "dataflash": d / "a.bin", "tlog": d / "a.tlog"}


def test_unknown_empty_and_random_files_are_one_line_errors_naming_the_file(tmp_path):
    empty = tmp_path / "e.ulg"
    empty.write_bytes(b"")
    with pytest.raises(DatasetError, match=rf"^{empty}: the flight log is empty$"):
        read_log(empty)
    rnd = tmp_path / "r.bin"
    rnd.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(DatasetError, match=rf"^{rnd}: not a flight log this reader knows \(.*\); it starts with "):
        read_log(rnd)
    text = tmp_path / "ardupilot.log"
    text.write_text("FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n")
    with pytest.raises(DatasetError, match="an ArduPilot text log"):
        read_log(text)
    with pytest.raises(DatasetError, match=rf"^{tmp_path / 'none.ulg'}: flight log not found$"):
        read_log(tmp_path / "none.ulg")


def test_the_format_comes_from_the_content_and_a_given_one_must_match(logs, tmp_path):
    for fmt, path in logs.items():
        renamed = tmp_path / f"{fmt}.txt"
        renamed.write_bytes(path.read_bytes())
        assert read_log(renamed).format == fmt
        assert read_log(renamed, format=fmt).format == fmt
    with pytest.raises(DatasetError, match=rf"^{logs['tlog']}: not a ulog log \(its content is that of a tlog log\)$"):
        read_log(logs["tlog"], format="ulog")
    with pytest.raises(ConfigError, match="^--log-format must be one of ulog, dataflash, tlog, srt, got 'px4'$"):
        read_log(logs["ulog"], format="px4")


@pytest.mark.parametrize("fmt", ["ulog", "dataflash", "tlog"])
@pytest.mark.parametrize("fraction", [0.0005, 0.01, 0.3, 0.77, 0.999])
def test_a_truncated_log_is_an_error_or_a_prefix_of_the_flight(logs, tmp_path, fmt, fraction):
    """Cut inside the header or the definitions: a DatasetError naming the file. Cut in the data (a battery that
    died in flight): what was logged before the cut (from the same message as the whole log's, unless the cut came
    before that message had what the reader needs), every sample still on the flight."""
    data = logs[fmt].read_bytes()
    cut = tmp_path / f"cut.{fmt}"
    cut.write_bytes(data[: max(1, int(len(data) * fraction))])
    full = read_log(logs[fmt])
    try:
        log = read_log(cut)
    except DatasetError as e:
        assert str(e).startswith(f"{cut}: ") and "\n" not in str(e)
        assert fraction < 0.05  # only cuts before the data section fail
        return
    assert log.attitude.t[-1] <= full.attitude.t[-1]
    n = len(log.attitude)
    if log.used["attitude"].split(" (")[0] == full.used["attitude"].split(" (")[0]:
        np.testing.assert_array_equal(log.attitude.t, full.attitude.t[:n])  # else an earlier message won the choice
    assert angle_between(quaternion_matrix(log.attitude.v), euler_matrix(*angles(log.attitude.t - BOOT))).max() < 0.01
    if fraction > 0.5:
        assert n > len(full.attitude) * (fraction - 0.2)


@pytest.mark.parametrize("fmt", ["ulog", "dataflash"])
def test_bytes_flipped_in_the_data_give_a_flight_or_an_error(logs, tmp_path, fmt):
    data = bytearray(logs[fmt].read_bytes())
    rng = np.random.default_rng(3)
    for i in rng.integers(len(data) // 3, len(data), 40):
        data[i] ^= 0xFF
    bad = tmp_path / f"bad.{fmt}"
    bad.write_bytes(bytes(data))
    try:
        log = read_log(bad)
    except DatasetError as e:
        assert str(e).startswith(f"{bad}: ")
        return
    assert len(log.attitude) > 0 and np.all(np.diff(log.attitude.t) > 0)


def test_a_missing_library_names_the_flight_extra(logs, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyulog", None)
    with pytest.raises(ConfigError, match=r"needs the Python package pyulog, .*pip install 'cosemdepth\[flight\]'"):
        read_log(logs["ulog"])


# ------------------------------------------------------------------------------------------------------------------
# Series and pose_at


def yaw_quaternion(deg):
    h = np.radians(deg) / 2
    return [np.cos(h), 0.0, 0.0, np.sin(h)]


def test_pose_at_slerps_attitude_and_interpolates_position_linearly(tmp_path):
    att = Series(np.array([0.0, 1.0, 2.0]), np.array([yaw_quaternion(0), yaw_quaternion(90), yaw_quaternion(-170)]))
    pos = Series(np.array([0.0, 2.0]), np.array([[0.0, 0.0, 0.0], [4.0, -2.0, 2.0]]))
    log = FlightLog(tmp_path / "x", "ulog", att, pos, 0.0)
    q, p, ok = log.pose_at(np.array([0.25, 1.5, 2.0]), max_gap=5)
    assert ok.all()
    np.testing.assert_allclose(q[0], yaw_quaternion(22.5), atol=1e-12)
    # from +90 to -170 the short way is through 180 (100 degrees): halfway is 140
    np.testing.assert_allclose(abs(np.dot(q[1], yaw_quaternion(140))), 1.0, atol=1e-12)
    np.testing.assert_allclose(p, [[0.5, -0.25, 0.25], [3.0, -1.5, 1.5], [4.0, -2.0, 2.0]])
    assert log.covered() == (0.0, 2.0)


def test_pose_at_says_which_times_are_not_covered(tmp_path):
    t = np.array([0.0, 0.01, 0.02, 0.5, 0.51])  # a 0.48 s gap in a 100 Hz series
    att = Series(t, np.tile([1.0, 0, 0, 0], (5, 1)))
    pos = Series(np.array([0.0, 0.6]), np.zeros((2, 3)))
    log = FlightLog(tmp_path / "x", "ulog", att, pos, 0.0)
    q, p, ok = log.pose_at(np.array([-0.01, 0.005, 0.3, 0.505, 0.55]))
    # default gaps: attitude max(0.1, 5 x 0.01) = 0.1 s; position max(0.1, 5 x 0.6) = 3 s
    assert ok.tolist() == [False, True, False, True, False]
    assert np.isnan(q[~ok]).all() and np.isnan(p[~ok]).all()
    _, _, ok = log.pose_at(np.array([0.3]), max_gap=1.0)
    assert ok.tolist() == [True]


def test_pose_at_without_positions_is_an_error(tmp_path):
    log = FlightLog(tmp_path / "x", "srt", Series(np.array([0.0]), np.array([[1.0, 0, 0, 0]])), None, 0.0)
    with pytest.raises(DatasetError, match="has no positions"):
        log.pose_at(np.array([0.0]))


def test_make_series_drops_duplicates_and_refuses_a_restarted_clock(tmp_path):
    s = make_series(tmp_path / "x", "ATT", [1.0, 2.0, 2.0, 1.9, 3.0, np.nan], np.arange(6.0))
    np.testing.assert_array_equal(s.t, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(s.v[:, 0], [0.0, 1.0, 4.0])
    with pytest.raises(DatasetError, match=r"the clock of ATT goes back by 9\.000 s at 1\.000 s"):
        make_series(tmp_path / "x", "ATT", [5.0, 10.0, 1.0], np.zeros(3))
