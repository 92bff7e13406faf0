"""Fuzz tests of read_log on damaged flight logs of every format.

Allowed outcomes (tests/fuzzing.py): a FlightLog whose series pass the invariant checks below (and, when the file
is unchanged, hold the written samples), or a CosemdepthError naming the file.
"""

from __future__ import annotations

import numpy as np
import pytest
from fuzzing import fuzz_settings, mutate_bytes, outcome, text_file_bytes, write
from hypothesis import example, given
from hypothesis import strategies as st

from cosemdepth.flightlogs import read_log
from cosemdepth.flightlogs.dataflash_writer import DataflashWriter
from cosemdepth.flightlogs.srt_writer import srt_text
from cosemdepth.flightlogs.tlog_writer import TlogWriter
from cosemdepth.flightlogs.ulog_writer import PX4_FORMATS, Topic, ulog_bytes

N = 12


def _ulog() -> bytes:
    t = 1_000_000 + 10_000 * np.arange(N)
    q = np.tile([np.cos(0.2), 0, 0, np.sin(0.2)], (N, 1))
    ones = np.ones(N)
    topics = [
        Topic("vehicle_attitude", PX4_FORMATS["vehicle_attitude"], {"timestamp": t, "timestamp_sample": t, "q": q}),
        Topic(
            "vehicle_local_position",
            PX4_FORMATS["vehicle_local_position"],
            {"timestamp": t + 3, "x": np.arange(N), "y": ones, "z": -ones, "xy_valid": ones, "z_valid": ones},
        ),
    ]
    return ulog_bytes(topics, start_us=999_000)


def _dataflash() -> bytes:
    w = DataflashWriter()
    for k in range(N):
        w.add("ATT", 1_000_000 + 20_000 * k, Roll=1.0, Pitch=-2.0, Yaw=10.0 * k)
        w.add("XKF1", 1_000_007 + 20_000 * k, C=0, Roll=1.0, Pitch=-2.0, Yaw=10.0 * k, PN=k, PE=2.0, PD=-3.0)
    return w.to_bytes()


def _tlog() -> bytes:
    w = TlogWriter()
    for k in range(N):
        ms = 1000 + 20 * k
        w.add(1_790_000_000_000_000 + ms * 1000, "ATTITUDE", time_boot_ms=ms, roll=0.1, pitch=0.2, yaw=0.1 * k)
        w.add(1_790_000_000_000_100 + ms * 1000, "LOCAL_POSITION_NED", time_boot_ms=ms + 1, x=float(k), y=1.0, z=-2.0)
    return w.to_bytes()


def _srt() -> str:
    t = np.arange(N) / 25
    lat, lon = 46.5 + 1e-5 * np.arange(N), np.full(N, 6.6)
    gimbal = np.tile([90.0, -30.0, 0.0], (N, 1))
    return srt_text(t, lat, lon, np.full(N, 10.0), np.full(N, 500.0), gimbal)


VALID = {"ulog": _ulog(), "dataflash": _dataflash(), "tlog": _tlog()}
SRT = _srt()


def check(log, fmt: str, data: bytes) -> None:
    """Invariants of any FlightLog, and the written samples when ``data`` is the valid file."""
    a = log.attitude
    assert a is not None and len(a) >= 1 and a.v.shape == (len(a), 4)
    assert np.isfinite(a.v).all() and (np.diff(a.t) > 0).all() and np.isfinite(a.t).all()
    np.testing.assert_allclose(np.linalg.norm(a.v, axis=1), 1.0, atol=1e-9)
    if log.position is not None:
        p = log.position
        assert p.v.shape == (len(p), 3) and np.isfinite(p.v).all() and (np.diff(p.t) > 0).all()
    assert log.position_resolution_m >= 0 and isinstance(log.used, dict)
    if fmt == "srt" and data == SRT.encode():
        assert len(a) == N and len(log.position) == N
    elif fmt != "srt" and data == VALID[fmt]:
        assert len(a) == N and len(log.position) == N


@pytest.mark.parametrize("fmt", ["ulog", "dataflash", "tlog"])
@fuzz_settings(max_examples=25)
@given(data=st.data())
def test_damaged_binary_logs(tmp_path_factory, fmt, data):
    raw = data.draw(st.one_of(st.just(VALID[fmt]), mutate_bytes(VALID[fmt])))
    path = write(tmp_path_factory.mktemp("fuzz") / "log.bin", raw)
    outcome(lambda: read_log(path), [path], lambda log: check(log, fmt, raw))


@fuzz_settings(max_examples=25)
@given(raw=text_file_bytes(SRT, separators=" \n[]:"))
@example(raw=SRT.encode())
def test_damaged_subtitles(tmp_path_factory, raw):
    path = write(tmp_path_factory.mktemp("fuzz") / "DJI_0001.SRT", raw)
    outcome(lambda: read_log(path), [path], lambda log: check(log, "srt", raw))
