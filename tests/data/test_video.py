"""The video reader (cosemdepth.data.video) on files written by other tools: PyAV with exact (variable) frame
times, imageio-ffmpeg at a constant rate, ffmpeg's rotation metadata (checked against ffmpeg's own autorotated
decode), more than 8 bits per sample, and broken files."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from _videos import ffmpeg_frames, ffmpeg_vfr, pattern, with_rotation, write_imageio, write_pyav

from cosemdepth.data.video import is_video, open_video
from cosemdepth.errors import ConfigError, DatasetError

#: Variable frame intervals (seconds), as a phone or a drone writes when it drops or delays frames.
VFR_TIMES = np.round(np.cumsum([0.0, 0.04, 0.033, 0.05, 0.1, 0.021, 0.04, 0.04, 0.067, 0.04, 0.04, 0.033]), 3)


def close(a: np.ndarray, b: np.ndarray, tol: float = 4.0) -> bool:
    return a.shape == b.shape and float(np.abs(a.astype(float) - b.astype(float)).mean()) < tol


def test_pyav_variable_rate_times_are_kept_exactly_and_frames_come_in_order(tmp_path):
    frames = [pattern(k) for k in range(len(VFR_TIMES))]
    path = write_pyav(tmp_path / "vfr.mp4", frames, VFR_TIMES)
    video = open_video(path)
    assert video.size == (48, 64) and video.rotation == 0 and video.bits == 8
    assert video.count_hint == len(VFR_TIMES) and video.start_s == 0.0
    got = list(video.frames())
    assert [f.index for f in got] == list(range(len(VFR_TIMES)))
    assert [f.pts_s for f in got] == VFR_TIMES.tolist()  # ms multiples in a 1/1000 s time base: exact
    for f, img in zip(got, frames):
        assert f.image.dtype == np.uint8 and close(f.image, img)
    # every 3rd frame keeps its index and time; unpacking as a tuple
    skipped = [(i, t) for i, t, _ in video.frames(frame_skip=3)]
    assert skipped == [(i, VFR_TIMES[i]) for i in range(0, len(VFR_TIMES), 3)]


def test_creation_time_is_read_as_utc(tmp_path):
    tagged = write_pyav(tmp_path / "t.mp4", [pattern(0)], [0.0], metadata={"creation_time": "2026-12-07T10:00:50Z"})
    assert open_video(tagged).creation_time_utc == 1_796_637_650.0  # 2026-12-07 10:00:50 UTC
    assert open_video(write_pyav(tmp_path / "u.mp4", [pattern(0)], [0.0])).creation_time_utc is None


def test_imageio_ffmpeg_constant_rate_video(tmp_path):
    frames = [pattern(k, 40, 56) for k in range(9)]
    path = write_imageio(tmp_path / "cfr.mov", frames, fps=30)
    video = open_video(path)
    got = list(video.frames())
    assert len(got) == 9 and video.size == (40, 56)
    np.testing.assert_allclose([f.pts_s - got[0].pts_s for f in got], np.arange(9) / 30, atol=1e-9)
    for f, img in zip(got, frames):
        assert close(f.image, img)


def test_ffmpeg_command_line_variable_rate(tmp_path):
    path = ffmpeg_vfr(tmp_path / "vfr.mkv", "N*(N+3)*4", 10)  # frame N at 4 N (N + 3) ms
    assert [t for _, t, _ in open_video(path).frames()] == [n * (n + 3) * 4 / 1000 for n in range(10)]


def test_frames_sharing_a_presentation_time_are_an_error(tmp_path):
    path = ffmpeg_vfr(tmp_path / "dup.mp4", "floor(N/2)*40", 6)
    with pytest.raises(
        DatasetError, match=r"dup\.mp4: frame \d+ has presentation time [0-9.]+ s, not after the previous"
    ):
        list(open_video(path).frames())


@pytest.mark.parametrize("degrees", [90, 180, 270, -90])
def test_rotation_metadata_is_applied_as_ffmpeg_displays_it(tmp_path, degrees):
    frames = [pattern(k) for k in range(3)]
    plain = write_pyav(tmp_path / "plain.mp4", frames, [0.0, 0.04, 0.08])
    path = with_rotation(plain, tmp_path / f"rot{degrees}.mp4", degrees)
    video = open_video(path)
    assert video.rotation == degrees % 360
    displayed = (64, 48) if degrees % 180 else (48, 64)
    assert video.size == displayed
    reference = ffmpeg_frames(path, displayed)  # ffmpeg's command line applies the display matrix by default
    got = list(video.frames())
    assert len(got) == len(reference) == 3
    for f, ref in zip(got, reference):
        assert f.image.shape == (*displayed, 3)
        np.testing.assert_array_equal(f.image, ref)
    # the red corner moved where the rotation puts it (independent of ffmpeg): counter-clockwise quarter turns
    corner = {90: (slice(-10, None), slice(0, 6)), 180: (slice(-6, None), slice(-10, None))}
    corner[270] = corner[-90] = (slice(0, 10), slice(-6, None))
    rows, cols = corner[degrees]
    assert got[0].image[rows, cols, 0].mean() > 200 and got[0].image[rows, cols, 1].mean() < 60
    small = next(iter(video.frames(size=(16, 12) if degrees % 180 else (12, 16), gray=True)))
    assert small.image.shape == ((16, 12, 1) if degrees % 180 else (12, 16, 1))


def test_more_than_8_bits_per_sample_reads_as_uint16(tmp_path):
    frames = [pattern(k) for k in range(3)]
    path = write_pyav(tmp_path / "deep.mkv", frames, [0.0, 0.04, 0.08], pix_fmt="yuv444p10le")
    video = open_video(path)
    assert video.bits == 16
    f = next(iter(video.frames()))
    assert f.image.dtype == np.uint16
    assert close((f.image / 257.0), frames[0].astype(float), tol=4.0)


def test_decoding_streams_one_frame_at_a_time(tmp_path):
    h, w, n = 120, 160, 150
    rng = np.random.default_rng(0)
    frames = [(rng.random((h, w, 3)) * 255).astype(np.uint8) for _ in range(n)]
    path = write_pyav(tmp_path / "long.mp4", frames, np.arange(n) * 0.04, pix_fmt="yuv420p")
    video = open_video(path)
    tracemalloc.start()
    count = 0
    for f in video.frames():
        count += 1
        assert f.image.shape == (h, w, 3)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert count == n
    assert peak < 10 * h * w * 3  # a few frames alive at a time, never the whole video (150 frames)


def test_is_video_by_suffix():
    assert is_video("a/b.MP4") and is_video("x.mov") and is_video("x.mkv")
    assert not is_video("frames") and not is_video("x.png")


def _write_sample(tmp_path, **kw):
    return write_pyav(tmp_path / "ok.mp4", [pattern(k) for k in range(30)], np.arange(30) * 0.04, **kw)


def test_missing_and_non_video_files_are_one_line_errors(tmp_path):
    with pytest.raises(DatasetError, match=r"nothere\.mp4: video file not found"):
        open_video(tmp_path / "nothere.mp4")
    (tmp_path / "text.mp4").write_text("not a video\n")
    with pytest.raises(DatasetError, match=r"text\.mp4: cannot read the video \(Invalid data"):
        open_video(tmp_path / "text.mp4")
    (tmp_path / "empty.mkv").write_bytes(b"")
    with pytest.raises(DatasetError, match=r"empty\.mkv: cannot read the video"):
        open_video(tmp_path / "empty.mkv")


def test_a_file_without_a_video_stream(tmp_path):
    import av

    path = tmp_path / "sound.mkv"
    with av.open(str(path), "w") as c:
        s = c.add_stream("pcm_s16le", rate=8000)
        frame = av.AudioFrame.from_ndarray(np.zeros((1, 800), np.int16), format="s16", layout="mono")
        frame.sample_rate = 8000
        for p in s.encode(frame):
            c.mux(p)
        for p in s.encode():
            c.mux(p)
    with pytest.raises(DatasetError, match=r"sound\.mkv: no video stream in the file"):
        open_video(path)


def test_truncated_video_with_the_index_at_the_end(tmp_path):
    data = _write_sample(tmp_path).read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) // 2])  # the index (moov) is lost: nothing can be read
    with pytest.raises(DatasetError, match=r"cut\.mp4: cannot read the video"):
        open_video(cut)


def test_truncated_video_with_the_index_first_fails_while_decoding(tmp_path):
    src = _write_sample(tmp_path)
    import av

    fast = tmp_path / "fast.mp4"  # the index first (as cameras and streaming tools write): the data is cut
    with av.open(str(src)) as i, av.open(str(fast), "w", options={"movflags": "faststart"}) as o:
        s = o.add_stream_from_template(i.streams.video[0])
        for p in i.demux(i.streams.video[0]):
            if p.dts is not None:
                p.stream = s
                o.mux(p)
    data = fast.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    video = open_video(cut)
    assert video.count_hint == 30
    with pytest.raises(DatasetError, match=r"cut\.mp4: (decoded \d+ frames of the 30|cannot decode the video)"):
        list(video.frames())


def test_rotation_metadata_other_than_quarter_turns_is_refused(tmp_path):
    path = with_rotation(_write_sample(tmp_path), tmp_path / "tilted.mp4", 45)
    with pytest.raises(DatasetError, match=r"tilted\.mp4: rotation metadata of 45 degrees is not supported"):
        open_video(path)


def test_bad_frame_skip(tmp_path):
    video = open_video(_write_sample(tmp_path))
    with pytest.raises(ConfigError, match="frame_skip"):
        next(iter(video.frames(frame_skip=0)))
