"""Helpers of the live ROS 2 tests: the loopback configuration and domain, tiny models and flights, an independent
subscriber."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

#: Written here, not taken from cosemdepth.ros2.dds.loopback_config (whose text a test checks against this one).
LOOPBACK = (
    '<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
    '<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>'
)
#: A domain of this run's own (other runs on the machine pick others).
DOMAIN = 120 + os.getpid() % 100


ROOT = Path(__file__).resolve().parents[2]
#: A tiny SynthAir flight (tests/fixtures/synthair-flight-s32/README.md): 23 images of 32x32 at 6.25 Hz.
FLIGHT = ROOT / "tests" / "fixtures" / "synthair-flight-s32"
IMAGE, INFO, ODOM = "/camera/image_raw", "/camera/camera_info", "/odom"


def tiny_model(path: Path) -> Path:
    """A small randomly initialised Co-SemDepth (2 levels) saved in the package's format."""
    import torch

    from cosemdepth import build_model, save_model

    torch.manual_seed(0)
    save_model(build_model(arch="cosemdepth", levels=2), path)
    return path


def flight_bag(out: Path, **kw) -> dict:
    from cosemdepth.ros2.midair_bag import write_midair_bag

    return write_midair_bag(FLIGHT, "sunny", 0, out, **kw)


def subset_bag(bag: Path, out: Path, stamps) -> Path:
    """A copy of ``bag`` with only the images (and camera_info) of ``stamps``; every pose kept."""
    from cosemdepth.ros2.midair_bag import keep_images

    return keep_images(bag, out, stamps, (IMAGE, INFO))


def bag_messages(bag: Path) -> dict[str, list[tuple[int, bytes]]]:
    """topic -> [(header stamp ns, raw bytes)] of a bag."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list] = {}
    with AnyReader([bag]) as r:
        for c, _, raw in r.messages():
            h = r.deserialize(raw, c.msgtype).header
            out.setdefault(c.topic, []).append((h.stamp.sec * 10**9 + h.stamp.nanosec, bytes(raw)))
    return out


def env() -> dict:
    """The environment of the subprocesses: this checkout's package, one thread, the loopback DDS domain."""
    e = dict(os.environ)
    e.update(
        PYTHONPATH=str(ROOT / "src"),
        OMP_NUM_THREADS="1",
        CYCLONEDDS_URI=LOOPBACK,
        ROS_DOMAIN_ID=str(DOMAIN),
    )
    return e


def cosemdepth(*args, log: Path) -> subprocess.Popen:
    """``cosemdepth ARGS`` as a subprocess, stdout and stderr to ``log``."""
    f = open(log, "w")
    return subprocess.Popen(
        [sys.executable, "-m", "cosemdepth", *map(str, args)], env=env(), stdout=f, stderr=subprocess.STDOUT
    )


def stop(proc: subprocess.Popen, timeout: float = 60.0) -> int:
    """SIGTERM, then the exit status (killed after ``timeout`` seconds: then the test fails on the status)."""
    if proc.poll() is None:
        proc.terminate()
    try:
        return proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        return -9


# ------------------------------------------------------------------------------------------ independent subscriber


@dataclass
class Received:
    data: bytes
    received_ns: int


class Subscriber:
    """Reads the node's outputs under ``namespace`` with Cyclone's own API: hand-written ROS 2 types, best effort,
    keep last 1000; each sample's bytes as they came off the wire, with the time they were taken."""

    def __init__(self, namespace: str = "/cosemdepth") -> None:
        from _ros2_types import OUTPUTS
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
        from cyclonedds.core import Policy, Qos
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        self.types = OUTPUTS
        self.participant = DomainParticipant(DOMAIN)
        qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(1000))
        self.readers = {
            name: DataReader(self.participant, Topic(self.participant, f"rt{namespace}/{name}", cls), qos)
            for name, cls in self.types.items()
        }
        # the camera's images too (the replay's progress)
        self.readers["input"] = DataReader(
            self.participant, Topic(self.participant, f"rt{IMAGE}", OUTPUTS["depth"]), qos
        )
        self.publications = BuiltinDataReader(self.participant, BuiltinTopicDcpsPublication)
        self.got: dict[str, list[Received]] = {n: [] for n in self.readers}
        self.endpoints: dict[str, object] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from cyclonedds._clayer import ddspy_take  # the bytes off the wire, undecoded

        while not self._stop.is_set():
            for name, r in self.readers.items():
                for data, info in ddspy_take(r._ref, 0x7FFF, 1000):
                    if info.valid_data:
                        self.got[name].append(Received(bytes(data), time.time_ns()))
            for e in self.publications.take(64):
                if getattr(e, "topic_name", None):
                    self.endpoints[e.topic_name] = e
            time.sleep(0.01)

    def decode(self, name: str, data: bytes):
        return self.types.get(name, self.types["depth"]).deserialize(data)

    def stamps(self, name: str = "depth") -> list[int]:
        out = []
        for r in self.got[name]:
            h = self.decode(name, r.data).header
            out.append(h.stamp.sec * 10**9 + h.stamp.nanosec)
        return out

    def wait_for(self, count: int, timeout: float, name: str = "depth", quiet: float = 2.0) -> None:
        """Until ``count`` messages of ``name`` came, or none for ``quiet`` seconds after the first, or ``timeout``."""
        end = time.monotonic() + timeout
        last_n, last_t = -1, time.monotonic()
        while time.monotonic() < end:
            n = len(self.got[name])
            if n >= count:
                break
            if n != last_n:
                last_n, last_t = n, time.monotonic()
            elif n and time.monotonic() - last_t > quiet:
                break
            time.sleep(0.05)
        time.sleep(0.3)  # the rest of the last frame's messages

    def clear(self) -> None:
        for v in self.got.values():
            v.clear()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.readers.clear()
        self.participant = None
