"""``cosemdepth replay``: a bag's messages reach a subscriber with the bag's bytes, in the bag's order, the chosen
topics and time window only; bags it cannot replay are refused with one line."""

import threading
import time

import pytest
from _live import IMAGE, INFO, ODOM, bag_messages, flight_bag

from cosemdepth.errors import ConfigError, DatasetError
from cosemdepth.ros2.dds import Graph
from cosemdepth.ros2.idl import idl_type
from cosemdepth.ros2.replay import replay_bag


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("replay") / "flight"
    flight_bag(path, frames=6, pose_type="nav_msgs/msg/Odometry")
    return path


def run_replay(bag, listen, **kw):
    """Replay in a thread; the samples each topic's reader took, in order."""
    got = {t: [] for t in listen}
    with Graph() as sub, Graph() as pub:
        types = {IMAGE: "sensor_msgs/msg/Image", INFO: "sensor_msgs/msg/CameraInfo", ODOM: "nav_msgs/msg/Odometry"}
        readers = {t: sub.reader(t, idl_type(types[t]), "sensor", depth=1000) for t in listen}
        result = {}
        th = threading.Thread(target=lambda: result.update(replay_bag(bag, pub, wait=20, **kw)))
        th.start()
        end = time.monotonic() + 60
        while th.is_alive() and time.monotonic() < end:
            for t, r in readers.items():
                got[t].extend(r.take())
            time.sleep(0.01)
        th.join()
        time.sleep(0.3)
        for t, r in readers.items():
            got[t].extend(r.take())
    return got, result


def test_replay_sends_the_bags_bytes_in_order(bag):
    expected = bag_messages(bag)
    got, result = run_replay(bag, [IMAGE, ODOM, INFO], rate=4.0, profile="reliable")
    assert result["messages"] == {t: len(v) for t, v in expected.items()} and result["rounds"] == 1
    for topic, msgs in expected.items():
        assert len(got[topic]) == len(msgs), topic
        for s, (_, raw) in zip(got[topic], msgs):
            assert s.data[: len(raw)] == raw and s.data[len(raw) :] == b"\x00" * (-len(raw) % 4)
    # paced by the recorded times (x4): the images' arrival spacing follows their stamps' (160 ms / 4)
    arrivals = [s.received_ns for s in got[IMAGE]]
    assert arrivals == sorted(arrivals) and arrivals[-1] - arrivals[0] > 0.5 * (5 * 160e6 / 4)


def test_replay_a_window_of_chosen_topics(bag):
    expected = bag_messages(bag)[IMAGE]
    got, result = run_replay(bag, [IMAGE, ODOM], topics=["camera/image_raw"], start=0.35, duration=0.33, rate=4.0)
    assert got[ODOM] == [] and set(result["messages"]) == {IMAGE}
    # the bag starts at its first pose (140 ms); images at 160, 320, 480, 640, ... ms: those in [490, 820) ms
    want = [raw for stamp, raw in expected if 490e6 <= (stamp - 1_700_000_000 * 10**9) + 1e6 < 820e6]
    assert len(want) == 2 and [s.data[: len(r)] for s, r in zip(got[IMAGE], want)] == want


def test_bags_replay_refuses(bag, tmp_path):
    from rosbags.rosbag1 import Writer

    ros1 = tmp_path / "old.bag"
    with Writer(ros1):
        pass
    with Graph() as g:
        with pytest.raises(DatasetError, match="a ROS 1 bag: replay publishes ROS 2 bags"):
            replay_bag(ros1, g)
        with pytest.raises(DatasetError, match="no topic /nope .*topics in the bag: /camera/camera_info"):
            replay_bag(bag, g, topics=["/nope"])
        with pytest.raises(DatasetError, match="bag not found"):
            replay_bag(tmp_path / "missing", g)
        with pytest.raises(ConfigError, match="--rate must be a positive number"):
            replay_bag(bag, g, rate=0)
