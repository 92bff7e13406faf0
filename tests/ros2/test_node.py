"""``cosemdepth node`` on the wire, without ROS, on loopback only: a SynthAir flight replayed by ``cosemdepth replay``
into the node, its outputs read by an independent subscriber (Cyclone DDS's own API, ROS 2's type definitions
written by hand).

What is compared: the node processes the newest frame and drops older pending ones, so the frames it processed are
read from its output stamps; ``predict --bag`` runs on a bag holding exactly those images (and every pose), which
gives the same motion chain; each of the node's messages then has the bytes of the message ``predict --bag`` wrote
for that frame (the depth and label images, the validity, camera_info; padded to a multiple of 4 bytes
with zeros by the node), and its status the bag's status values followed by the node's. The replay is then restarted on the
second half of the flight: the node starts afresh (status reset, reason: a new image publisher) and its outputs equal
``predict --bag`` on the frames it processed after the restart. (The first replay is killed mid-flight.)
"""

import json

import numpy as np
import pytest
from _live import (
    IMAGE,
    INFO,
    ODOM,
    Subscriber,
    bag_messages,
    cosemdepth,
    flight_bag,
    stop,
    subset_bag,
    tiny_model,
)

from cosemdepth.cli.main import main

NS = "/cosemdepth"
T0, MS = 1_700_000_000 * 10**9, 1_000_000
BYTE_EQUAL = ("depth", "depth_valid", "labels", "labels_color", "camera_info")


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("live")
    model = tiny_model(tmp / "model")
    info = flight_bag(tmp / "flight")
    return tmp, model, tmp / "flight", info["stamps"]


def predict_bag(model, bag, out):
    import torch

    torch.set_num_threads(1)  # as the node (--threads 1): the same float summation order
    args = ["predict", "--model", model, "--bag", bag, "--image-topic", IMAGE, "--pose-topic", ODOM]
    args += ["--camera-info-topic", INFO, "--convention", "ned", "--out", out, "--video", "none", "--no-progress"]
    assert main([str(a) for a in args]) == 0
    return bag_messages(out / "bag")


def check_equal_to_predict(sub, got, model, bag, tmp, label):
    """The received outputs ``got`` (name -> samples) equal predict --bag on the frames they are of."""
    stamps = [
        (lambda h: h.stamp.sec * 10**9 + h.stamp.nanosec)(sub.decode("depth", r.data).header) for r in got["depth"]
    ]
    assert len(stamps) >= 3 and stamps == sorted(stamps)
    ref = predict_bag(model, subset_bag(bag, tmp / f"subset_{label}", stamps), tmp / f"predict_{label}")
    for name in BYTE_EQUAL:
        exp = ref[f"{NS}/{name}"]
        assert [s for s, _ in exp] == stamps and len(got[name]) == len(exp), name
        for r, (_, raw) in zip(got[name], exp):
            pad = r.data[len(raw) :]
            assert r.data[: len(raw)] == raw and len(pad) < 4 and pad == b"\x00" * len(pad), name
    for r, (_, raw) in zip(got["depth_status"], ref[f"{NS}/depth_status"]):
        mine, theirs = sub.decode("depth_status", r.data), sub.decode("depth_status", raw)
        assert mine.header == theirs.header
        a, b = mine.status[0], theirs.status[0]
        assert (a.level, a.name, a.message, a.hardware_id) == (b.level, b.name, b.message, b.hardware_id)
        assert a.values[:3] == b.values and [kv.key for kv in a.values[3:5]] == ["latency_ms", "stamp_age_ms"]
    # the depth as a ROS 2 subscriber decodes it: 32FC1 metres, NaN exactly where depth_valid is 0
    for d, v in zip(got["depth"], got["depth_valid"]):
        img, valid = sub.decode("depth", d.data), sub.decode("depth_valid", v.data)
        assert (img.encoding, valid.encoding) == ("32FC1", "mono8") and img.step == 4 * img.width
        depth = np.frombuffer(bytes(img.data), "<f4").reshape(img.height, img.width)
        mask = np.asarray(valid.data, np.uint8).reshape(img.height, img.width)
        assert np.array_equal(np.isnan(depth), mask == 0) and set(np.unique(mask)) <= {0, 255}
    return stamps


def statuses(sub, got):
    return [{kv.key: kv.value for kv in sub.decode("depth_status", r.data).status[0].values} for r in got]


def test_node_publishes_predict_bags_messages_and_restarts_with_the_replay(flight):
    from cyclonedds.core import Policy

    tmp, model, bag, image_stamps = flight
    sub = Subscriber(NS)
    node = cosemdepth(
        "node", "--model", model, "--image-topic", IMAGE, "--pose-topic", ODOM, "--camera-info-topic", INFO,
        "--convention", "ned", "--threads", "1", "--report-every", "0", "--summary", tmp / "summary.json",
        log=tmp / "node.log",
    )  # fmt: skip
    try:
        replay = cosemdepth("replay", bag, "--rate", "2", "--wait", "30", log=tmp / "replay1.log")
        sub.wait_for(10, 120, name="input", quiet=60)  # the replay killed mid-flight, after 10 of its 23 images
        rc_replay = stop(replay)
        assert rc_replay == 0 and "(stopped)" in (tmp / "replay1.log").read_text()
        sub.wait_for(len(image_stamps), 10)
        first = {k: list(v) for k, v in sub.got.items()}
        sent_first = len(first["input"])
        sub.clear()
        # the camera "restarts": a new replay from the middle of the flight
        replay = cosemdepth("replay", bag, "--rate", "2", "--wait", "30", "--start", "1.8", log=tmp / "replay2.log")
        assert replay.wait(120) == 0, (tmp / "replay2.log").read_text()
        sub.wait_for(len(image_stamps) // 2, 60)
        second = {k: list(v) for k, v in sub.got.items()}
    finally:
        rc = stop(node)
        endpoints = dict(sub.endpoints)
        sub.close()
    log = (tmp / "node.log").read_text()
    assert rc == 0, log
    assert "SIGTERM: stopping after the frame in progress" in log and "stopped;" in log

    done1 = check_equal_to_predict(sub, first, model, bag, tmp, "first")
    done2 = check_equal_to_predict(sub, second, model, bag, tmp, "second")
    assert set(done1) <= set(image_stamps) and set(done2) <= set(image_stamps)
    assert sent_first < len(image_stamps) - 4 and max(done1) <= image_stamps[sent_first - 1]  # stopped mid-flight
    assert min(done2) > image_stamps[8]
    s1, s2 = statuses(sub, first["depth_status"]), statuses(sub, second["depth_status"])
    assert s1[0]["status"] == "reset" and s1[0]["reset_reason"] == "first frame"
    assert s2[0]["status"] == "reset" and s2[0]["reset_reason"].startswith("image publisher changed")
    assert all("reset_reason" not in s for s in s1[1:] + s2[1:])  # no other break in the motion
    assert [s["status"] for s in s1[1:]] == ["estimated"] * (len(s1) - 1)  # every-frame policy: tiny model

    summary = json.loads((tmp / "summary.json").read_text())
    assert summary["frames_processed"] == len(done1) + len(done2) and summary["frames_rejected"] == 0
    assert summary["frames_received"] == summary["frames_processed"] + summary["frames_dropped"]
    assert summary["resets"] == {"first frame": 1, "image publisher changed": 1}
    assert summary["input"]["pose_type"] == "geometry_msgs/msg/PoseStamped"
    assert summary["input"]["image_type"] == "sensor_msgs/msg/Image"
    assert int(s2[-1]["frames_processed"]) == summary["frames_processed"]

    # ROS 2's type names and the sensor-data QoS, as discovery announces them
    types = {
        "depth": "sensor_msgs::msg::dds_::Image_",
        "depth_valid": "sensor_msgs::msg::dds_::Image_",
        "labels": "sensor_msgs::msg::dds_::Image_",
        "labels_color": "sensor_msgs::msg::dds_::Image_",
        "camera_info": "sensor_msgs::msg::dds_::CameraInfo_",
        "depth_status": "diagnostic_msgs::msg::dds_::DiagnosticArray_",
    }
    for name, type_name in types.items():
        e = endpoints[f"rt{NS}/{name}"]
        assert e.type_name == type_name
        assert Policy.Reliability.BestEffort in e.qos and Policy.Durability.Volatile in e.qos
        assert Policy.DataRepresentation(use_cdrv0_representation=True) in e.qos


def test_report_line_and_percentiles():
    from collections import Counter

    from cosemdepth.ros2.node import Reporter, percentiles
    from cosemdepth.ros2.source import LiveStats

    assert percentiles([]) == {"p50": None, "p95": None}
    assert percentiles(range(1, 101)) == {"p50": 50.5, "p95": 95.05}

    class Sink:
        latencies = [10.0, 20.0, 30.0, 40.0]

    lines = []
    stats = LiveStats(received=12, processed=4, dropped=8, unposed=1, resets=Counter({"first frame": 1, "gap": 2}))
    rep = Reporter(stats, Sink(), lines.append, every=0)
    rep(None)  # every=0: no periodic line
    assert lines == []
    line = rep.line(final=True)
    assert line.startswith("12 frames received, 4 processed (") and "8 dropped, 1 without a pose" in line
    assert "latency p50 25 ms, p95 38 ms" in line and "resets: first frame 1, gap 2" in line


#: A pincushion lens (plumb_bob k1 = 0.5) of 24x16 images, as ROS's camera_calibration writes it (pixel centres at
#: integer coordinates: the principal point 11.5, 7.5 is the image centre).
LENS_YAML = """image_width: 24
image_height: 16
camera_name: cam
camera_matrix: {rows: 3, cols: 3, data: [12.0, 0.0, 11.5, 0.0, 12.0, 7.5, 0.0, 0.0, 1.0]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [0.5, 0.0, 0.0, 0.0, 0.0]}
"""


def off_the_sensor(h: int, w: int, f: float, k1: float) -> np.ndarray:
    """Hand-computed ``[h, w]`` bool: the pixels of the undistorted (same-size, centred) camera whose ray lands
    outside the distorted image (radial k1 only)."""
    v, u = np.mgrid[0:h, 0:w] + 0.5
    x, y = (u - w / 2) / f, (v - h / 2) / f
    scale = 1 + k1 * (x * x + y * y)
    ud, vd = f * x * scale + w / 2, f * y * scale + h / 2
    return (ud < 0) | (ud > w) | (vd < 0) | (vd > h)


def test_node_with_a_calibration_file_publishes_the_pinhole_and_no_depth_without_a_source(tmp_path):
    """``--calibration FILE`` in the node's loop (in this process, on loopback): the images are undistorted, the
    camera_info published is the pinhole they were undistorted to (no distortion), and the depth is NaN (validity 0)
    wherever the undistorted image has no source pixel."""
    import threading
    import time

    import torch

    from cosemdepth.inference.policy import Streamer, StreamPolicy
    from cosemdepth.jobs.model import ModelOptions, load_for
    from cosemdepth.robotics.messages import header, image
    from cosemdepth.ros2.dds import Graph
    from cosemdepth.ros2.idl import encode, idl_type, typestore
    from cosemdepth.ros2.midair_bag import _pose_message
    from cosemdepth.ros2.node import run_node
    from cosemdepth.ros2.sink import TopicSink, output_names
    from cosemdepth.ros2.source import LiveOptions, LiveSource

    torch.set_num_threads(1)
    (tmp_path / "cam.yaml").write_text(LENS_YAML)
    model, _ = load_for(ModelOptions(tiny_model(tmp_path / "model")))
    ts = typestore()
    camera = Graph()
    images = camera.writer("/lens/image", idl_type("sensor_msgs/msg/Image"), "reliable")
    poses = camera.writer("/lens/pose", idl_type("geometry_msgs/msg/PoseStamped"), "reliable")
    sub = Subscriber("/lens_out")
    graph = Graph()
    options = LiveOptions("/lens/image", "/lens/pose", calibration=tmp_path / "cam.yaml", convention="flu")
    source = LiveSource(graph, options, None, log=lambda m: None)
    sink = TopicSink(graph, output_names(True, True, False, False), namespace="/lens_out", stats=source.stats)
    done: dict = {}
    # a random model's depths are not well conditioned: every estimate is kept here but for the lens's mask
    policy = StreamPolicy("every-frame", max_conditioning=float("inf"), max_log_ratio=float("inf"))
    node = threading.Thread(target=lambda: done.update(run_node(source, Streamer(model, policy), sink,
                                                                 max_frames=3, report_every=0, log=lambda m: None)))  # fmt: skip
    rgb = np.random.default_rng(3).integers(0, 255, (16, 24, 3)).astype(np.uint8)
    try:
        node.start()
        until = time.monotonic() + 30
        outputs = [f"rt/lens_out/{n}" for n in ("depth", "depth_valid", "camera_info")]
        while not (images.subscribers() and poses.subscribers() and all(o in sub.endpoints for o in outputs)):
            assert time.monotonic() < until, "discovery timed out"
            time.sleep(0.02)
        time.sleep(0.5)
        for k in range(61):  # 1 m/s to the body's left (FLU y): the camera moves along its -x, parallax everywhere
            msg = _pose_message(ts, "geometry_msgs/msg/PoseStamped", T0 + 10 * k * MS, np.array([0, 0.01 * k, 0]),
                                np.array([1.0, 0, 0, 0]))  # fmt: skip
            poses.write(encode(msg, ts))
        for k in range(1, 4):
            images.write(encode(image(ts, header(ts, T0 + 150 * k * MS, "cam"), np.roll(rgb, k, 1), "rgb8"), ts))
            while source.stats.processed < k:
                assert time.monotonic() < until + 60, "the node did not process the frame"
                time.sleep(0.02)
        node.join(30)
        sub.wait_for(3, 10)
    finally:
        source.stop()
        node.join(10)
        sub.close()
        camera.close()
    assert done["frames_processed"] == 3 and not node.is_alive()
    info = sub.decode("camera_info", sub.got["camera_info"][-1].data)
    assert (info.height, info.width) == (16, 24) and list(info.d) == [0.0] * 5
    assert np.allclose(info.k, [12.0, 0, 11.5, 0, 12.0, 7.5, 0, 0, 1])  # the centred pinhole, ROS pixel centres
    off = off_the_sensor(16, 24, 12.0, 0.5)
    assert 0 < off.sum() < off.size / 2  # the corners
    valid_somewhere = False
    for d, v in zip(sub.got["depth"], sub.got["depth_valid"]):
        img, valid = sub.decode("depth", d.data), sub.decode("depth_valid", v.data)
        depth = np.frombuffer(bytes(img.data), "<f4").reshape(16, 24)
        mask = np.asarray(valid.data, np.uint8).reshape(16, 24)
        assert np.isnan(depth[off]).all() and (mask[off] == 0).all()
        assert np.array_equal(np.isnan(depth), mask == 0)
        valid_somewhere |= bool((mask[~off] == 255).any())
    assert len(sub.got["depth"]) == 3 and valid_somewhere
