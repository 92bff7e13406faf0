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
