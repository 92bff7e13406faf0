"""``cosemdepth replay BAG``: a recorded ROS 2 bag's topics published into the live graph at their recorded rate,
so that the node can be tried (and tested, and demonstrated) without a drone.

Messages go out in the bag's order, each at its recorded log time relative to the first one (divided by ``rate``),
with the bytes the bag holds (ROS 2 bags store the CDR that ROS 2 sends) on topics of the bag's message types (their
definitions are the bag's). ``/tf_static`` is published reliable and transient local (late subscribers get it), the
other topics with ``profile`` (sensor data: best effort, keep last 5; or reliable). Before the first message the
replay waits up to ``wait`` seconds for a subscriber on every topic, then half a second more for the subscribers to
match it in turn (best-effort messages sent before a subscriber matched are lost). ROS 1 bags hold another serialisation and other message definitions: convert them first
(``rosbags-convert``).
"""

from __future__ import annotations

import contextlib
import threading
import time
from pathlib import Path
from typing import Any, Sequence

from ..errors import ConfigError, DatasetError
from ..robotics.rosbag import Bag
from .dds import Graph, ros_topic
from .idl import idl_type


def replay_bag(
    path: str | Path,
    graph: Graph | None = None,
    *,
    topics: Sequence[str] | None = None,
    rate: float = 1.0,
    start: float = 0.0,
    duration: float | None = None,
    loop: bool = False,
    profile: str = "sensor",
    wait: float = 2.0,
    stop: threading.Event | None = None,
) -> dict[str, Any]:
    """Publish the bag at ``path`` (see the module docstring) into ``graph``; returns ``{"messages": {topic: n},
    "seconds": wall time, "rounds": passes over the bag}``.

    Args:
        graph: the participant to publish from (default: one of its own in ``ROS_DOMAIN_ID``, made once the bag and
            the arguments are checked, left at the end).
        topics: the topics to publish (default all).
        rate: playback speed (2.0: twice as fast).
        start, duration: seconds from the bag's first message to start at, and to play (None: to the end).
        loop: start again at the end, until ``stop``.
        wait: seconds to wait for subscribers before the first message.
        stop: set it to stop (e.g. from a signal handler).
    """
    if not (isinstance(rate, (int, float)) and 0 < rate < float("inf")):
        raise ConfigError(f"--rate must be a positive number, got {rate!r}")
    if not start >= 0 or (duration is not None and not duration > 0):
        raise ConfigError(f"--start must be >= 0 and --duration > 0 seconds, got {start!r}, {duration!r}")
    stop = stop or threading.Event()
    with Bag(path) as bag:
        reader = bag.reader
        if not reader.is2:
            raise DatasetError(
                f"{path}: a ROS 1 bag: replay publishes ROS 2 bags (convert it with rosbags-convert first)"
            )
        conns = list(reader.connections)
        have = sorted({c.topic for c in conns})
        if topics:
            wanted = [ros_topic(t, "--topics") for t in topics]
            missing = [t for t in wanted if t not in have]
            if missing:
                raise DatasetError(f"{path}: no topic {missing[0]} (--topics); topics in the bag: {', '.join(have)}")
            conns = [c for c in conns if c.topic in wanted]
        if not conns:
            raise DatasetError(f"{path}: the bag has no topics")
        store = reader.typestore
        with contextlib.nullcontext(graph) if graph is not None else Graph() as g:
            return _play(path, g, reader, conns, store, rate, start, duration, loop, profile, wait, stop)


def _play(path, graph: Graph, reader, conns, store, rate, start, duration, loop, profile, wait, stop) -> dict:
    """Publish the chosen connections of the open ``reader`` (see :func:`replay_bag`)."""
    writers = {}
    for c in conns:
        if c.topic not in writers:
            prof = "static" if c.topic == "/tf_static" else profile
            writers[c.topic] = graph.writer(c.topic, idl_type(c.msgtype, store), prof)
    t_first = reader.start_time
    _wait_for_subscribers(writers, wait, stop)
    counts = {t: 0 for t in writers}
    rounds = 0
    t0_wall = time.monotonic()
    while not stop.is_set():
        rounds += 1
        t_base = None
        t_start = t_first + int(start * 1e9)
        t_stop = None if duration is None else t_start + int(duration * 1e9)
        round_wall = time.monotonic()
        try:
            for conn, t, raw in reader.messages(connections=conns, start=t_start, stop=t_stop):
                if t_base is None:
                    t_base = t
                due = round_wall + (t - t_base) / 1e9 / rate
                delay = due - time.monotonic()
                if delay > 0 and stop.wait(delay):
                    break
                writers[conn.topic].write(raw)
                counts[conn.topic] += 1
        except (DatasetError, ConfigError):
            raise
        except Exception as e:  # rosbags' own errors for a corrupt file
            raise DatasetError(f"{path}: cannot read the bag ({str(e).splitlines()[0][:300]})") from None
        if not loop or t_base is None:
            break
    seconds = time.monotonic() - t0_wall
    return {"messages": counts, "seconds": seconds, "rounds": rounds}


#: Seconds to let the subscribers' side of discovery finish once the writers see them (a reader drops samples of a
#: writer it has not matched yet).
SETTLE = 0.5


def _wait_for_subscribers(writers: dict, wait: float, stop: threading.Event) -> None:
    end = time.monotonic() + max(0.0, wait)
    while time.monotonic() < end and not stop.is_set():
        if all(w.subscribers() > 0 for w in writers.values()):
            stop.wait(SETTLE)
            return
        stop.wait(0.05)


__all__ = ["replay_bag"]
