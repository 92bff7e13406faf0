"""``cosemdepth predict --bag``: the depth equals ``predict --flight`` on the same images and poses; the output bag
reads back with rosbags; stamps, frame_ids and encodings are the inputs'; bad bags fail cleanly (exit 2, one line,
nothing in --out)."""

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "evaluation"))  # the commands' test helpers
from _bags import camera_info_msg, compressed_msg, frames, image_msg, pose_msg, trajectory, typestore, write_bag
from _outputs import (  # noqa: F401 (pytest fixtures)
    _one_thread,
    leftovers,  # (puts tests/data on the path)
    model_dir,
)

from cosemdepth.cli.main import main

N = 6  # images
BASE = 100.0  # seconds
K = (16.0, 16.0, 15.5, 15.5)  # ROS camera_info K of the 32x32 images: (fx, fy, cx, cy), centred
IMAGES = frames(N)


def image_stamps() -> list[int]:
    """25 Hz with +-3 ms jitter, in ns."""
    jitter = [3, -2, 1, -3, 2, 0]
    return [round((BASE + 0.04 * i + jitter[i] * 1e-3) * 1e9) for i in range(N)]


def pose_stamps(gap: tuple[float, float] | None = None) -> list[int]:
    """100 Hz from BASE - 0.02 s to past the last image (minus the ``gap`` interval)."""
    out = []
    for k in range(-2, 4 * N + 2):
        t = BASE + 0.01 * k
        if gap is None or not gap[0] < t < gap[1]:
            out.append(round(t * 1e9))
    return out


def make_bag(
    path: Path,
    kind: str = "mcap",
    *,
    compressed: bool = False,
    encoding: str = "rgb8",
    pose_type: str = "geometry_msgs/msg/PoseStamped",
    info: bool = True,
    distortion=(),
    gap=None,
) -> Path:
    ros1 = kind == "ros1"
    ts = typestore(ros1)
    msgs = []
    for ns in pose_stamps(gap):
        p, q = trajectory(ns / 1e9 - BASE)
        msgs.append(("/odom", pose_msg(ts, pose_type, ns, p, q, ros1), ns + 2_000_000))
    for i, ns in enumerate(image_stamps()):
        msg = compressed_msg(ts, ns, IMAGES[i], ros1) if compressed else image_msg(ts, ns, IMAGES[i], encoding, ros1)
        msgs.append(("/cam/image", msg, ns + 15_000_000))  # images arrive late, after later poses
    if info:
        msgs.append(("/cam/info", camera_info_msg(ts, image_stamps()[0], 32, 32, K, distortion, ros1), 1))
    return write_bag(path.with_suffix(".bag") if ros1 else path, msgs, kind)


def make_flight(folder: Path) -> tuple[Path, Path]:
    """The same images (PNG named by stamp) and poses (TUM) for ``predict --flight``."""
    from PIL import Image

    images = folder / "images"
    images.mkdir(parents=True)
    for ns, rgb in zip(image_stamps(), IMAGES):
        Image.fromarray(rgb).save(images / f"{ns / 1e9:.6f}.png")
    lines = []
    for ns in pose_stamps():
        p, q = trajectory(ns / 1e9 - BASE)
        lines.append(f"{ns / 1e9:.6f} " + " ".join(repr(float(v)) for v in (*p, q[1], q[2], q[3], q[0])))
    (folder / "poses.txt").write_text("\n".join(lines) + "\n")
    return images, folder / "poses.txt"


def predict(*argv) -> int:
    return main(["predict", *map(str, argv), "--no-progress", "--video", "none"])


def bag_args(bag, *extra):
    return ["--bag", bag, "--image-topic", "/cam/image", "--pose-topic", "/odom", *extra]


def read_bag(path: Path) -> dict[str, list]:
    from rosbags.highlevel import AnyReader

    out: dict[str, list] = {}
    with AnyReader([path]) as r:
        for c, t, raw in r.messages():
            out.setdefault(c.topic, []).append((t, r.deserialize(raw, c.msgtype)))
    return out


def image_array(msg) -> np.ndarray:
    dtype = {"32FC1": "<f4", "mono8": "u1", "rgb8": "u1"}[msg.encoding]
    ch = 3 if msg.encoding == "rgb8" else 1
    a = np.frombuffer(np.asarray(msg.data, np.uint8).tobytes(), dtype=dtype)
    return a.reshape(msg.height, msg.width, ch).squeeze(-1) if ch == 1 else a.reshape(msg.height, msg.width, 3)


@pytest.fixture(scope="module")
def flight_depth(model_dir, tmp_path_factory):
    """Depth of ``predict --flight`` (convention flu, intrinsics = the camera_info's + 0.5, output 16x16)."""
    tmp = tmp_path_factory.mktemp("flight")
    images, poses = make_flight(tmp / "flight")
    rc = predict(
        "--model",
        model_dir,
        "--flight",
        "--images",
        images,
        "--poses",
        poses,
        "--convention",
        "flu",
        "--intrinsics",
        16,
        16,
        16,
        16,
        "--size",
        16,
        "--out",
        tmp / "out",
    )
    assert rc == 0
    man = json.loads((tmp / "out" / "predictions.json").read_text())
    return [np.load(tmp / "out" / f["files"]["depth"]) for f in man["frames"]]


CASES = [
    ("mcap", False, "rgb8", "geometry_msgs/msg/PoseStamped"),
    ("sqlite3", True, "rgb8", "nav_msgs/msg/Odometry"),
    ("ros1", False, "bgr8", "geometry_msgs/msg/PoseWithCovarianceStamped"),
]


@pytest.mark.parametrize("kind,compressed,encoding,pose_type", CASES)
def test_bag_depth_equals_flight_depth_and_output_bag_reads_back(
    model_dir, flight_depth, tmp_path, capsys, kind, compressed, encoding, pose_type
):
    bag = make_bag(tmp_path / "in", kind, compressed=compressed, encoding=encoding, pose_type=pose_type)
    out = tmp_path / "out"
    assert (
        predict("--model", model_dir, *bag_args(bag, "--camera-info-topic", "/cam/info"), "--size", 16, "--out", out)
        == 0
    )
    assert f"bag: {N} of {N} images" in capsys.readouterr().out
    man = json.loads((out / "predictions.json").read_text())
    files = [np.load(out / f["files"]["depth"]) for f in man["frames"]]
    assert len(files) == N
    for a, b in zip(files, flight_depth):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-4)
    assert not np.allclose(files[1], files[2])  # the frames differ (the comparison is not vacuous)

    msgs = read_bag(out / "bag")
    assert sorted(msgs) == [
        "/cosemdepth/camera_info",
        "/cosemdepth/depth",
        "/cosemdepth/depth_status",
        "/cosemdepth/depth_valid",
        "/cosemdepth/labels",
        "/cosemdepth/labels_color",
    ]
    assert (out / "bag" / "bag.mcap").is_file()
    stamps = image_stamps()
    for topic, items in msgs.items():
        assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in items] == stamps, topic
        assert [t for t, _ in items] == stamps
        assert {m.header.frame_id for _, m in items} == {"cam"}
    masks = [
        np.array(__import__("PIL.Image", fromlist=["Image"]).open(out / f["files"]["depth_valid"])) == 255
        for f in man["frames"]
    ]
    for i, ((_, m), (_, v), (_, st)) in enumerate(
        zip(msgs["/cosemdepth/depth"], msgs["/cosemdepth/depth_valid"], msgs["/cosemdepth/depth_status"])
    ):
        assert m.encoding == "32FC1" and (m.height, m.width) == (16, 16)
        # REP 118: NaN where the depth is not an estimate (the mask predict wrote), the .npy's values elsewhere
        d = image_array(m)
        assert (np.isnan(d) == ~masks[i]).all() and (image_array(v) == 255 * masks[i]).all()
        np.testing.assert_array_equal(d[masks[i]], files[i][masks[i]])
        assert st.status[0].message == man["frames"][i]["status"]
    assert np.isnan(image_array(msgs["/cosemdepth/depth"][0][1])).all()  # the first frame: a reset
    labels = [
        np.array(__import__("PIL.Image", fromlist=["Image"]).open(out / f["files"]["labels"])) for f in man["frames"]
    ]
    palette = np.asarray(man["palette"], np.uint8)
    for i, ((_, lm), (_, cm)) in enumerate(zip(msgs["/cosemdepth/labels"], msgs["/cosemdepth/labels_color"])):
        assert lm.encoding == "mono8" and cm.encoding == "rgb8"
        np.testing.assert_array_equal(image_array(lm), labels[i])
        np.testing.assert_array_equal(image_array(cm), palette[labels[i]])
    info = msgs["/cosemdepth/camera_info"][0][1]
    assert (info.height, info.width) == (16, 16)
    # K scaled to 16x16: fx 16 -> 8; ROS cx 15.5 (32 px) -> (15.5 + 0.5) / 2 - 0.5 = 7.5
    np.testing.assert_allclose(info.k, [8, 0, 7.5, 0, 8, 7.5, 0, 0, 1])
    assert man["bag"]["messages"] == 6 * N


def man_run(out: Path) -> dict:
    return json.loads((out / "predictions.json").read_text())["run"]


def test_out_namespace_frame_skip_and_hfov(model_dir, tmp_path):
    bag = make_bag(tmp_path / "in", info=False)
    out = tmp_path / "out"
    assert (
        predict(
            "--model",
            model_dir,
            *bag_args(bag, "--hfov", 90, "--frame-skip", 2, "--out-namespace", "/uav1/cd"),
            "--out",
            out,
        )
        == 0
    )
    msgs = read_bag(out / "bag")
    assert sorted(msgs) == [
        "/uav1/cd/camera_info",
        "/uav1/cd/depth",
        "/uav1/cd/depth_status",
        "/uav1/cd/depth_valid",
        "/uav1/cd/labels",
        "/uav1/cd/labels_color",
    ]
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in msgs["/uav1/cd/depth"]]
    assert stamps == image_stamps()[::2]
    np.testing.assert_allclose(msgs["/uav1/cd/camera_info"][0][1].k, [16, 0, 15.5, 0, 16, 15.5, 0, 0, 1])
    run = man_run(out)
    assert (run["convention"], run["frame_skip"], run["hfov_deg"], run["pose_topic"]) == ("flu", 2, 90, "/odom")
    assert run["input_size"] == [32, 32] and run["intrinsics"] == [16.0, 16.0, 16.0, 16.0]  # hfov 90, 32 px
    # every output is named by its image's full stamp (10-digit seconds, 9-digit nanoseconds): sortable, unique
    man = json.loads((out / "predictions.json").read_text())
    want = [f"{ns // 10**9:010d}.{ns % 10**9:09d}" for ns in image_stamps()[::2]]  # e.g. 0000000100.003000000
    assert [f["files"]["depth"] for f in man["frames"]] == [f"cam_image/depth/image_{w}.npy" for w in want]
    assert [f["source"] for f in man["frames"]] == [f"{bag}:/cam/image@{w}" for w in want]
    assert sorted(p.name for p in (out / "cam_image" / "depth").iterdir()) == [f"image_{w}.npy" for w in want]


def test_gap_in_the_poses_fails_naming_the_stamp_or_is_skipped(model_dir, tmp_path, capsys):
    # poses missing in (100.095, 100.185): images 3 (100.117) and 4 (100.162) have no poses around them
    bag = make_bag(tmp_path / "in", gap=(BASE + 0.095, BASE + 0.185))
    out = tmp_path / "out"
    assert predict("--model", model_dir, *bag_args(bag, "--camera-info-topic", "/cam/info"), "--out", out) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert f"{bag}: topic /cam/image: no pose for the image at stamp 100.117000000" in err
    assert not out.exists() and not leftovers(tmp_path)
    assert (
        predict(
            "--model", model_dir, *bag_args(bag, "--camera-info-topic", "/cam/info", "--skip-unposed"), "--out", out
        )
        == 0
    )
    assert f"bag: {N - 2} of {N} images, 2 skipped without a pose" in capsys.readouterr().out
    msgs = read_bag(out / "bag")
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in msgs["/cosemdepth/depth"]]
    assert stamps == [s for i, s in enumerate(image_stamps()) if i not in (3, 4)]


def _corrupt_bag(tmp_path: Path) -> Path:
    bag = make_bag(tmp_path / "c")
    mcap = bag / "c.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    return bag


def _empty_bag(tmp_path: Path) -> Path:
    return write_bag(tmp_path / "e", [], "mcap")


def _garbage_ros1(tmp_path: Path) -> Path:
    p = tmp_path / "g.bag"
    p.write_bytes(b"#ROSBAG V2.0\n" + b"\x00garbage" * 50)
    return p


BAD = [
    ("unknown image topic", lambda t: make_bag(t / "in"), ["--image-topic", "/nope"], "topic '/nope' (--image-topic)"),
    (
        "unknown camera_info topic",
        lambda t: make_bag(t / "in", info=False),
        ["--camera-info-topic", "/cam/info"],
        "no topic '/cam/info' (--camera-info-topic)",
    ),
    (
        "wrong message type",
        lambda t: make_bag(t / "in"),
        ["--pose-topic", "/cam/image"],
        "topic /cam/image (--pose-topic) holds sensor_msgs/msg/Image",
    ),
    (
        "folding distortion",
        lambda t: make_bag(t / "in", distortion=(-0.6, 0, 0, 0, 0)),
        [],
        "topic /cam/info at stamp 100.003000000: the radtan coefficients [-0.6, 0, 0, 0, 0, 0, 0, 0] fold the image",
    ),
    ("empty bag", _empty_bag, [], "no topic '/cam/info' (--camera-info-topic); topics in the bag: none"),
    ("corrupt bag", _corrupt_bag, [], "cannot read the bag"),
    ("corrupt ROS 1 bag", _garbage_ros1, [], "cannot read the bag"),
    ("missing bag", lambda t: t / "missing", [], "bag not found"),
]


@pytest.mark.parametrize("what,make,extra,message", BAD, ids=[b[0] for b in BAD])
def test_bad_bags_fail_with_one_line_and_leave_nothing(model_dir, tmp_path, capsys, what, make, extra, message):
    bag = make(tmp_path)
    out = tmp_path / "out"
    args = bag_args(bag, "--camera-info-topic", "/cam/info")
    for i in range(0, len(extra), 2):  # override an option
        j = args.index(extra[i]) if extra[i] in args else None
        if j is None:
            args += extra[i : i + 2]
        else:
            args[j + 1] = extra[i + 1]
    assert predict("--model", model_dir, *args, "--out", out) == 2, what
    err = capsys.readouterr().err.strip()
    assert err.startswith("cosemdepth predict: error: ") and err.count("\n") == 0, err
    assert str(bag) in err and message in err, err
    assert not out.exists() and not leftovers(tmp_path)


def test_empty_image_topic_and_bad_arguments(model_dir, tmp_path, capsys):
    ts = typestore(False)
    p, q = trajectory(0)
    bag = write_bag(tmp_path / "in", [("/odom", pose_msg(ts, "geometry_msgs/msg/PoseStamped", 10**9, p, q), 1)])
    # a topic with a connection but no message: write one on another topic, declare the image topic
    from rosbags.rosbag2 import StoragePlugin, Writer

    shutil.rmtree(bag)
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=ts)
        c = w.add_connection("/odom", "geometry_msgs/msg/PoseStamped", typestore=ts)
        w.write(
            c,
            1,
            ts.serialize_cdr(pose_msg(ts, "geometry_msgs/msg/PoseStamped", 1, p, q), "geometry_msgs/msg/PoseStamped"),
        )
    out = tmp_path / "out"
    assert predict("--model", model_dir, *bag_args(bag, "--hfov", 90), "--out", out) == 2
    assert f"{bag}: topic /cam/image (--image-topic) holds no messages" in capsys.readouterr().err
    assert predict("--model", model_dir, *bag_args(bag), "--out", out) == 2
    assert "--bag needs --camera-info-topic T, or exactly one of" in capsys.readouterr().err
    assert predict("--model", model_dir, *bag_args(bag, "--hfov", 90, "--out-namespace", "/9x"), "--out", out) == 2
    assert "--out-namespace '/9x' is not a valid ROS namespace" in capsys.readouterr().err
    assert not out.exists() and not leftovers(tmp_path)


def test_jpeg_compressed_bag_decodes_like_a_jpeg_flight(model_dir, tmp_path, capsys):
    """CompressedImage JPEGs go through the dataset readers' decoder (the original's fast IDCT by default, or
    --jpeg-idct accurate): the bag's depth equals --flight's on the same JPEG bytes, for both IDCTs."""
    import io

    from PIL import Image

    jpegs = []
    for rgb in IMAGES:
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="JPEG", quality=85)
        jpegs.append(buf.getvalue())
    ts = typestore(False)
    msgs = []
    for ns in pose_stamps():
        p, q = trajectory(ns / 1e9 - BASE)
        msgs.append(("/odom", pose_msg(ts, "geometry_msgs/msg/PoseStamped", ns, p, q), ns))
    for ns, data in zip(image_stamps(), jpegs):
        hdr = ts.types["std_msgs/msg/Header"](
            stamp=ts.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9), frame_id="cam"
        )
        msgs.append(
            (
                "/cam/image",
                ts.types["sensor_msgs/msg/CompressedImage"](
                    header=hdr, format="jpeg", data=np.frombuffer(data, np.uint8)
                ),
                ns,
            )
        )
    bag = write_bag(tmp_path / "in", msgs, "mcap")
    images, poses = make_flight(tmp_path / "flight")
    for f in images.iterdir():
        f.unlink()
    for ns, data in zip(image_stamps(), jpegs):
        (images / f"{ns / 1e9:.6f}.jpg").write_bytes(data)
    depth = {}
    for idct in ("fast", "accurate"):
        for how, args in (
            ("bag", bag_args(bag, "--hfov", 90)),
            ("flight", ["--flight", "--images", images, "--poses", poses, "--hfov", 90, "--convention", "flu"]),
        ):
            out = tmp_path / f"{how}-{idct}"
            assert predict("--model", model_dir, *args, "--size", 16, "--jpeg-idct", idct, "--out", out) == 0
            man = json.loads((out / "predictions.json").read_text())
            depth[how, idct] = np.stack([np.load(out / f["files"]["depth"]) for f in man["frames"]])
        np.testing.assert_allclose(depth["bag", idct], depth["flight", idct], rtol=1e-5, atol=1e-4)
    assert not np.array_equal(depth["bag", "fast"], depth["bag", "accurate"])  # the IDCT choice reaches the bag


def test_a_bag_runs_at_the_model_s_focal_length_from_its_camera_info(tmp_path):
    from cosemdepth import build_model, save_model
    from cosemdepth.cli.main import build_parser
    from cosemdepth.cli.predict import options
    from cosemdepth.jobs.options import open_source
    from cosemdepth.operating_point import OperatingPoint

    model = save_model(
        build_model(arch="cosemdepth", levels=2), tmp_path / "m", operating_point=OperatingPoint((16, 16), (8.0, 8.0))
    )
    bag = make_bag(tmp_path / "in")
    argv = ["predict", "--model", model, *bag_args(bag, "--camera-info-topic", "/cam/info"), "--out", tmp_path / "o"]
    o = options(build_parser(only="predict").parse_args([str(a) for a in argv]))
    source = open_source(o.source, o.run, o.model.operating_point())
    try:
        # camera_info: fx = 16 px at 32x32 (cx 15.5 + 0.5 in our convention); the model's 8 px is the size 16x16
        ds = source.dataset
        assert ds.intrinsics.tolist() == [8.0, 8.0, 8.0, 8.0] and ds[0]["rgb"].shape[-2:] == (16, 16)
    finally:
        source.close()
