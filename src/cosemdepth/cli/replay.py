"""``cosemdepth replay BAG``: publish a recorded ROS 2 bag's topics into the live ROS 2 graph at their recorded rate.

    cosemdepth replay BAG [--rate R] [--topics T ...] [--start S] [--duration S] [--loop] [--qos reliable]

A Cyclone DDS participant (``pip install cosemdepth[live]``) in the domain ``ROS_DOMAIN_ID``, configured by
``CYCLONEDDS_URI``; stops at the end of the bag, or on SIGINT / SIGTERM. See :mod:`cosemdepth.ros2.replay`.
"""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, metavar="BAG", help="a ROS 2 bag folder (MCAP or sqlite3)")
    parser.add_argument("--rate", type=float, default=1.0, help="playback speed (default 1: the recorded rate)")
    parser.add_argument("--topics", nargs="+", metavar="T", help="only these topics (default: all)")
    parser.add_argument("--start", type=float, default=0.0, metavar="S", help="start S seconds into the bag")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="play S seconds of the bag")
    parser.add_argument("--loop", action="store_true", help="start again at the end (until stopped)")
    parser.add_argument(
        "--qos",
        choices=("sensor", "reliable"),
        default="sensor",
        help="sensor (the default; best effort, volatile, keep last 5) or reliable (keep last 10); /tf_static is "
        "always reliable and transient local",
    )
    parser.add_argument(
        "--wait",
        type=float,
        default=2.0,
        metavar="S",
        help="seconds to wait for a subscriber on every topic before the first message (default 2)",
    )


def run(args: argparse.Namespace) -> int:
    from ..ros2.replay import replay_bag

    stop = threading.Event()
    saved = {}
    if threading.current_thread() is threading.main_thread():
        for s in (signal.SIGINT, signal.SIGTERM):
            saved[s] = signal.signal(s, lambda *_: stop.set())
    try:
        result = replay_bag(  # joins the graph once the bag and the arguments are checked
            args.bag,
            topics=args.topics,
            rate=args.rate,
            start=args.start,
            duration=args.duration,
            loop=args.loop,
            profile=args.qos,
            wait=args.wait,
            stop=stop,
        )
    finally:
        for s, h in saved.items():
            signal.signal(s, h)
    n = sum(result["messages"].values())
    parts = ", ".join(f"{t} {c}" for t, c in sorted(result["messages"].items()))
    print(
        f"replayed {n} messages in {result['seconds']:.1f} s{' (stopped)' if stop.is_set() else ''}: {parts}"
        + (f"; {result['rounds']} rounds" if result["rounds"] > 1 else "")
    )
    return 0
