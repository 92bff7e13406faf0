"""The pictures of predictions (``render/figures.py``): sizes, panel order and captions, the depth colour bar
and its range, the class legend, upscaling, and the same frame in the picture and in the video."""

import sys
from pathlib import Path

import numpy as np
import pytest

from cosemdepth.measures.classes import class_info
from cosemdepth.render.figures import (
    FlightFigure,
    FlightPictures,
    FrameMaps,
    auto_depth_range,
    depth_ticks,
    nice_ceil,
    panel_scale,
)
from cosemdepth.render.visualize import VideoWriter, colorize_depth

NAMES, PALETTE = class_info(7, "synthair")
ALL = ("rgb", "depth", "gt_depth", "labels", "gt_labels")


def maps(h=128, w=128, depth=None, seed=0, keys=ALL, title=""):
    rng = np.random.default_rng(seed)
    d = rng.uniform(2.0, 70.0, (h, w)).astype(np.float32) if depth is None else depth
    lab = rng.integers(0, 7, (h, w)).astype(np.uint8)
    full = dict(
        rgb=rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
        depth=d,
        gt_depth=d * 1.1,
        labels=lab,
        gt_labels=(lab + 1) % 7,
    )
    return FrameMaps(**{k: full[k] for k in keys}, title=title)


def figure(m, rng=(0.0, 40.0), **kw):
    return FlightFigure(m.keys(), m.rgb.shape[:2], depth_range=rng, class_names=NAMES, palette=PALETTE, **kw)


def test_nice_numbers_and_ticks_by_hand():
    assert [nice_ceil(x) for x in (0.7, 1.0, 13.0, 31.0, 44.9, 61.0, 80.0, 81.0)] == [0.8, 1, 15, 40, 50, 80, 80, 100]
    assert depth_ticks(0, 60) == [0, 10, 20, 30, 40, 50, 60]
    assert depth_ticks(0, 25) == [0, 5, 10, 15, 20, 25]
    assert depth_ticks(0, 15) == [0, 2.5, 5, 7.5, 10, 12.5, 15]
    assert depth_ticks(0, 80) == [0, 20, 40, 60, 80]
    assert depth_ticks(0, 70)[-1] == 70  # the far end is always labelled


def test_auto_depth_range_by_hand():
    # 0.5, 1.5, ..., 99.5 m: the ones <= 80 m are 0.5 .. 79.5, their 90th percentile 71.6 -> 80
    d = np.arange(100, dtype=np.float32) + 0.5
    assert auto_depth_range([d]) == (0.0, 80.0)
    # half the image is sky (20 km): left out; the ground 10..29 m -> 90th percentile 27.1 -> 30
    ground = np.repeat(np.arange(10, 30, dtype=np.float32), 5)
    assert auto_depth_range([np.concatenate([ground, np.full(100, 2e4, np.float32)])]) == (0.0, 30.0)
    # a high flight (everything beyond 80 m): all depths count
    assert auto_depth_range([np.full(50, 150.0), np.full(50, 170.0)]) == (0.0, 200.0)
    # nothing valid: the evaluation cap
    assert auto_depth_range([np.array([np.nan, 0.0, -1.0, np.inf])]) == (0.0, 80.0)


@pytest.mark.parametrize("h, w, k", [(8, 100000, 2), (100000, 8, 2), (8, 8192, 8), (16, 200000, 1), (8, 2**20, 1)])
def test_a_map_of_an_extreme_aspect_ratio_is_upscaled_less(h, w, k):
    """48x (384 / 8) would make a 100000x8 map's panel 4.8 million pixels long: 15 GB of canvas for one picture.
    The factor is the largest whose panel keeps to MAX_UPSCALED_PANEL (2048^2) pixels, and never below 1."""
    from cosemdepth.render.figures import MAX_UPSCALED_PANEL

    assert panel_scale(h, w) == k
    assert h * w * k * k <= MAX_UPSCALED_PANEL or k == 1
    assert k == 1 or h * w * (k + 1) ** 2 > MAX_UPSCALED_PANEL  # the largest such factor
    if (
        h > w and h * w <= 800_000
    ):  # draw a tall one: every panel at k x the map, the colour bar and legend under panels 16 px wide
        m = maps(h, w)
        f = figure(m)
        img = f.frame(m)
        assert f.panel_size == (h * k, w * k) and img.shape == (*f.frame_size, 3)
        x0, y0, x1, y1 = f.colorbar_box
        assert x1 > x0 and y1 > y0


@pytest.mark.parametrize("h, w, k", [(128, 128, 3), (32, 64, 12), (96, 128, 4), (384, 384, 1), (500, 700, 1)])
def test_every_panel_is_at_least_384_px_and_the_frame_size_adds_up(h, w, k):
    assert panel_scale(h, w) == k
    for keys in (ALL, ("rgb", "depth", "labels"), ("rgb", "labels"), ("rgb", "depth")):
        m = maps(h, w, keys=keys)
        f = figure(m)
        img = f.frame(m)
        assert f.panel_size == (h * k, w * k) and min(f.panel_size) >= 384
        assert img.shape == (*f.frame_size, 3) and img.dtype == np.uint8
        assert img.shape[1] == len(keys) * w * k + (len(keys) - 1) * 4
        assert img.shape[0] == f.caption_height + h * k + 4 + f.footer_height
        assert f.metadata()["frame_size"] == list(img.shape[:2])


def test_panel_order_and_captions_do_not_depend_on_the_order_given():
    f = FlightFigure(["gt_labels", "labels", "rgb", "gt_depth", "depth"], (32, 32), class_names=NAMES, palette=PALETTE)
    assert f.metadata()["panels"] == [
        "RGB",
        "predicted depth",
        "ground-truth depth",
        "predicted labels",
        "ground-truth labels",
    ]
    m = maps(32, 32)
    # the caption strip of a one-frame picture and of a multi-row strip are the same pixels
    assert np.array_equal(f.frame(m)[: f.caption_height], f.rows([m, m, m])[: f.caption_height])
    assert np.array_equal(f.frame(m)[-f.footer_height :], f.rows([m, m])[-f.footer_height :])
    assert f.rows([m, m, m]).shape == (*f.rows_size(3), 3)


def test_labels_are_upscaled_nearest_and_depth_bilinearly_on_the_flight_range():
    m = maps(128, 128)
    f = figure(m, rng=(0.0, 40.0))
    img = f.frame(m)
    boxes = dict(zip(f.metadata()["panels"], f.metadata()["panel_boxes"]))
    x0, y0, x1, y1 = boxes["predicted labels"]
    assert np.array_equal(img[y0:y1, x0:x1], np.kron(PALETTE[m.labels], np.ones((3, 3, 1), np.uint8)))
    x0, y0, x1, y1 = boxes["ground-truth labels"]
    assert np.array_equal(img[y0:y1, x0:x1], np.kron(PALETTE[m.gt_labels], np.ones((3, 3, 1), np.uint8)))
    x0, y0, x1, y1 = boxes["predicted depth"]
    panel = img[y0:y1, x0:x1].astype(int)
    # bilinear x3: the centre of each 3 x 3 block is the pixel itself (colours clipped to the 0..40 m range)
    assert np.abs(panel[1::3, 1::3] - colorize_depth(m.depth, 0.0, 40.0)).max() <= 1
    # and the pixels between two centres lie between their colours
    a, b = panel[1::3, 1::3][:, :-1], panel[1::3, 1::3][:, 1:]
    mid = panel[1::3, 2::3][:, :-1]
    assert ((mid >= np.minimum(a, b) - 1) & (mid <= np.maximum(a, b) + 1)).all()


def test_colour_bar_spans_the_range_in_the_metadata():
    m = maps(64, 64, depth=np.full((64, 64), 12.0, np.float32))
    f = figure(m, rng=(0.0, 30.0))
    img = f.frame(m)
    meta = f.metadata()
    assert meta["depth_range_m"] == [0.0, 30.0] and meta["depth_ticks_m"] == [0, 5, 10, 15, 20, 25, 30]
    x0, y0, x1, y1 = meta["colorbar_box"]
    assert x1 - x0 > 200 and y1 - y0 >= 10
    row = img[(y0 + y1) // 2, x0:x1].astype(int)
    depths = np.linspace(0.0, 30.0, x1 - x0)  # column j shows 30 * j / (n - 1) m
    assert np.abs(row - colorize_depth(depths, 0.0, 30.0)).max() <= 1
    # the 12 m panel has the colour the bar shows at 12 m
    x0p, y0p, x1p, y1p = dict(zip(meta["panels"], meta["panel_boxes"]))["predicted depth"]
    j = int(round(12.0 / 30.0 * (x1 - x0 - 1)))
    assert np.abs(img[y0p + 100, x0p + 100].astype(int) - row[j]).max() <= 4
    # outside the bar the footer is the background: the bar is exactly its box
    assert np.abs(img[y0 - 1, x0:x1].astype(int) - row).max() > 50


def test_the_legend_lists_exactly_the_classes_with_their_colours():
    for n, ds in ((7, "synthair"), (9, "topair"), (12, "aeroscapes"), (5, None)):
        names, palette = class_info(n, ds)
        for keys in (ALL, ("rgb", "labels")):
            m = maps(48, 48, keys=keys)
            m.labels = m.labels % n
            if m.gt_labels is not None:
                m.gt_labels = m.gt_labels % n
            f = FlightFigure(m.keys(), (48, 48), class_names=names, palette=palette)
            img = f.frame(m)
            assert [i for i, _ in f.legend_boxes] == list(range(n)) and f.metadata()["classes"] == list(names)
            for i, (x0, y0, x1, y1) in f.legend_boxes:
                assert y0 >= f.frame_size[0] - f.footer_height and y1 <= f.frame_size[0]
                assert np.array_equal(img[(y0 + y1) // 2, (x0 + x1) // 2], palette[i])
            # swatches do not overlap
            bx = [b for _, b in f.legend_boxes]
            for a in range(n):
                for b in range(a + 1, n):
                    p, q = bx[a], bx[b]
                    assert p[2] <= q[0] or q[2] <= p[0] or p[3] <= q[1] or q[3] <= p[1]
    # a depth-only figure has no legend, a labels-only figure no colour bar
    f = FlightFigure(("rgb", "depth"), (32, 32))
    assert f.legend_boxes == [] and "classes" not in f.metadata() and f.colorbar_box is not None
    f = FlightFigure(("rgb", "labels"), (32, 32), class_names=NAMES, palette=PALETTE)
    assert f.colorbar_box is None and "depth_range_m" not in f.metadata()


def test_flight_pictures_fix_the_range_from_the_first_frames_and_keep_the_order():
    got = []
    pics = FlightPictures(lambda ctx, img: got.append((ctx, img)), class_names=NAMES, palette=PALETTE, warmup=3)
    ground = np.tile(np.linspace(5.0, 22.0, 32, dtype=np.float32), (32, 1))
    for k in range(5):
        m = maps(32, 32, depth=ground + k)
        m.gt_depth = ground.copy()
        m.gt_depth[:4] = 2e4  # sky
        pics.add(m, k)
        assert len(got) == (0 if k < 2 else k + 1)  # held until the third frame, then drawn as they come
    fig = pics.finish()
    assert [c for c, _ in got] == [0, 1, 2, 3, 4]
    # from the ground truth: 90th percentile of the ground (sky left out) 20.3 m -> 25 m
    assert fig.depth_range == (0.0, 25.0) and all(img.shape == (*fig.frame_size, 3) for _, img in got)
    # a given range is used at once; a frame without ground truth draws an empty panel in its place
    got.clear()
    pics = FlightPictures(lambda ctx, img: got.append(img), class_names=NAMES, palette=PALETTE, depth_range=(0.0, 50.0))
    pics.add(maps(32, 32))
    m = maps(32, 32)
    m.gt_labels = None
    pics.add(m)
    assert len(got) == 2 and got[0].shape == got[1].shape and pics.finish().depth_range == (0.0, 50.0)


def test_a_video_frame_is_the_picture(tmp_path):
    imageio = pytest.importorskip("imageio.v3")
    m = maps(128, 128, title="frame 7")
    f = figure(m)
    img = f.frame(m)
    w = VideoWriter(tmp_path / "v", fps=4, fmt="mp4")
    for _ in range(3):
        w.write(img)
    path = w.close()
    frame = imageio.imread(path, index=1)
    assert frame.shape == img.shape == (*f.frame_size, 3)
    cap = slice(0, f.caption_height)
    # H.264 is lossy: the caption strip (text on a flat background) within a few levels on average
    assert np.abs(frame[cap].astype(int) - img[cap]).mean() < 3
    assert np.abs(frame.astype(int) - img).mean() < 12


# ---------------------------------------------------------------------------------------------------- the commands

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))  # the commands' test helpers
from _outputs import SIZE, _one_thread, model_dir, tiny_midair  # noqa: E402 (some are pytest fixtures)


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    return tiny_midair(tmp_path_factory.mktemp("d") / "flight", trajectories=(0,), frames=28)  # 6 rows


def _read(path):
    from PIL import Image

    return np.array(Image.open(path))


def _bar_depths(img, box, rng):
    """The depths the colour bar of ``img`` shows, column by column, read back through the colour map."""
    from cosemdepth.render.visualize import _lut

    x0, y0, x1, y1 = box
    row = img[(y0 + y1) // 2, x0:x1].astype(int)
    lut = _lut("turbo").astype(int)
    idx = np.abs(row[:, None, :] - lut[None]).sum(-1).argmin(1)  # nearest colour of the map
    return rng[0] + (1.0 - idx / 255.0) * (rng[1] - rng[0])


def test_predict_pictures_video_and_metadata_agree(model_dir, flight, tmp_path):
    import json

    import imageio.v3 as iio

    from cosemdepth.cli.main import main

    out = tmp_path / "pred"
    assert (
        main(
            [
                "predict",
                "--model",
                str(model_dir),
                "--dataset",
                "synthair",
                "--root",
                str(flight),
                "--size",
                str(SIZE),
                "--out",
                str(out),
                "--no-progress",
            ]
        )
        == 0
    )
    man = json.loads((out / "predictions.json").read_text())
    traj = man["trajectories"][0]
    pics = traj["pictures"]
    assert pics["panels"] == ["RGB", "predicted depth", "ground-truth depth", "predicted labels", "ground-truth labels"]
    assert pics["classes"] == list(NAMES) == man["class_names"]
    frames = [f for f in man["frames"] if f["trajectory"] == traj["name"]]
    video = iio.imread(out / traj["video"])  # every frame
    assert video.shape == (len(frames), *pics["frame_size"], 3)
    # the range: chosen from the first frames' ground truth as auto_depth_range does, and on the colour bar
    from cosemdepth.data import open_dataset

    ds = open_dataset("synthair", flight, split="test", seq_len=1, size=SIZE)
    gts = [ds[i]["depth"][0, 0].numpy() for i in range(min(len(ds), 8))]
    assert pics["depth_range_m"] == list(auto_depth_range(gts))
    cap = pics["panel_boxes"][0][1]  # caption strip height
    for k, f in enumerate(frames):
        png = _read(out / f["files"]["side_by_side"])
        assert png.shape == video[k].shape
        assert np.abs(video[k][:cap].astype(int) - png[:cap]).mean() < 3  # the same captions
        assert np.abs(video[k].astype(int) - png).mean() < 12  # the same picture, up to H.264
        bar = _bar_depths(png, pics["colorbar_box"], pics["depth_range_m"])
        near, far = pics["depth_range_m"]
        assert np.abs(bar - np.linspace(near, far, len(bar))).max() <= (far - near) / 255 + 1e-6


def test_demo_strip_and_video_share_the_layout(model_dir, flight, tmp_path):
    import json

    import imageio.v3 as iio

    from cosemdepth.cli.main import main

    out = tmp_path / "report"
    assert (
        main(
            [
                "demo",
                "--out",
                str(out),
                "--model",
                str(model_dir),
                "--data-root",
                str(flight),
                "--size",
                str(SIZE),
                "--no-progress",
            ]
        )
        == 0
    )
    m = json.loads((out / "metrics.json").read_text())
    pics = m["pictures"]
    assert pics["panels"] == ["RGB", "predicted depth", "ground-truth depth", "predicted labels", "ground-truth labels"]
    assert pics["panel_size"] == [384, 384] and pics["classes"] == list(NAMES)
    strip = _read(out / "qualitative.png")
    video = iio.imread(out / "flight.mp4")
    h, w = pics["frame_size"]
    assert video.shape[1:] == (h, w, 3) and video.shape[0] == 6
    cap = pics["panel_boxes"][0][1]
    footer = h - pics["panel_boxes"][0][3] - 4
    rows = 4  # QUALITATIVE_FRAMES of the 5 evaluated frames
    assert strip.shape == (cap + rows * (384 + 4) + footer, w, 3)
    # the same captions (panel order) and the same footer (colour bar and legend) in the strip and the video
    for frame in video:
        assert np.abs(frame[:cap].astype(int) - strip[:cap]).mean() < 3
        assert np.abs(frame[h - footer :].astype(int) - strip[-footer:]).mean() < 3
    y0 = pics["colorbar_box"][1] - h  # the colour bar, counted from the bottom
    box = [
        pics["colorbar_box"][0],
        strip.shape[0] + y0,
        pics["colorbar_box"][2],
        strip.shape[0] + y0 + pics["colorbar_box"][3] - pics["colorbar_box"][1],
    ]
    near, far = pics["depth_range_m"]
    bar = _bar_depths(strip, box, (near, far))
    assert np.abs(bar - np.linspace(near, far, len(bar))).max() <= (far - near) / 255 + 1e-6
    report = (out / "report.md").read_text()
    assert f"from {near:g} m (red) to {far:g} m (dark blue)" in report
