"""ROS 2 topics on DDS without a ROS installation: a Cyclone DDS participant, ROS 2's names and QoS profiles, and
readers and writers of serialized messages.

ROS 2's default transports are DDS, with a published mapping (``rmw_cyclonedds``; field notes "ROS 2 on the wire
without ROS"), which an ordinary DDS participant can follow:

* a ROS topic ``/a/b`` is the DDS topic ``rt/a/b``;
* a message type ``pkg/msg/Type`` is the DDS type ``pkg::msg::dds_::Type_`` (key-less, final extensibility);
* samples are XCDR1 (classic CDR, 4-byte encapsulation header ``00 01 00 00`` little-endian): writers here declare
  XCDR1 only (an XCDR2 writer does not reach ROS 2's XCDR1 readers); readers accept both;
* QoS profiles: ``sensor`` (ROS's SensorDataQoS: best effort, volatile, keep last 5), ``reliable`` (ROS's default
  profile: reliable, volatile, keep last 10), ``static`` (``/tf_static``: reliable, transient local, keep last 1).

The domain is ``ROS_DOMAIN_ID`` (0 when unset), as ROS 2 takes it; the Cyclone DDS configuration (network interface,
peers, multicast) is the C library's, from ``CYCLONEDDS_URI``. :func:`loopback_config` is one that keeps every packet
on this machine (tests, benchmarks).

Samples are written and taken as bytes: the messages are serialized and deserialized with ``rosbags`` (the same CDR
as ROS 2 bags). The Python binding's own (de)serialisation of a message walks every element of an image's ``data``
array in Python (tens of milliseconds for a 384x384 float image), so this module calls the binding's C layer that
``DataWriter.write`` and ``DataReader.take`` call after and before it (``ddspy_write``, ``ddspy_take``) with the
bytes; the DDS topic itself is created with an IDL type of the message (:mod:`.idl`), so that discovery announces
ROS 2's type name and type information. ``cyclonedds`` is an optional dependency (``pip install cosemdepth[live]``),
imported only here.
"""

from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass
from typing import Any, Iterator

from ..errors import ConfigError
from ..optional import require

#: ROS 2's QoS profiles by name: (reliable, transient local, keep-last depth).
QOS_PROFILES: dict[str, tuple[bool, bool, int]] = {
    "sensor": (False, False, 5),
    "reliable": (True, False, 10),
    "static": (True, True, 1),
}
#: The ``--input-qos`` / ``--output-qos`` choices.
QOS_CHOICES = ("sensor", "reliable")
#: The largest DDS domain id whose ports fit (7400 + 250 x domain + offsets < 65536).
MAX_DOMAIN_ID = 232
#: The XCDR1 little-endian encapsulation header of every sample written here.
CDR_LE = b"\x00\x01\x00\x00"
_ROS_NAME = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)+")


def require_cyclonedds():
    """The ``cyclonedds`` package, or a ConfigError saying how to install it."""
    return require("cyclonedds.domain", "joining a ROS 2 graph (cosemdepth node, replay)")


def domain_id(env: dict | None = None) -> int:
    """``ROS_DOMAIN_ID`` (0 when unset or empty); a ConfigError when it is not an integer in 0..232."""
    raw = (os.environ if env is None else env).get("ROS_DOMAIN_ID", "").strip()
    if not raw:
        return 0
    if not raw.isdigit() or int(raw) > MAX_DOMAIN_ID:
        raise ConfigError(f"ROS_DOMAIN_ID={raw!r} is not a domain id (an integer from 0 to {MAX_DOMAIN_ID})")
    return int(raw)


def loopback_config(max_participants: int = 32) -> str:
    """A Cyclone DDS configuration (the text of ``CYCLONEDDS_URI``) that keeps every packet on this machine: the
    loopback interface only, no multicast, discovery by unicast to 127.0.0.1 (each participant takes a port of its
    own, found by the others among the first ``max_participants``)."""
    return (
        '<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
        "<AllowMulticast>false</AllowMulticast></General>"
        "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
        f"<MaxAutoParticipantIndex>{int(max_participants)}</MaxAutoParticipantIndex>"
        '<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>'
    )


def ros_topic(name: str, option: str = "topic") -> str:
    """A ROS topic name made absolute (``camera/image`` -> ``/camera/image``); a ConfigError when it is not a valid
    ROS name (``option`` names the argument)."""
    text = "/" + str(name).strip().strip("/")
    if not _ROS_NAME.fullmatch(text):
        raise ConfigError(
            f"{option} {name!r} is not a valid ROS topic name (letters, digits, _ and /; no part starting with a digit)"
        )
    return text


def dds_topic(ros_name: str) -> str:
    """The DDS topic of a ROS topic: ``/a/b`` -> ``rt/a/b``."""
    return "rt" + ros_name


def dds_type(msgtype: str) -> str:
    """The DDS type name of a ROS message type: ``sensor_msgs/msg/Image`` -> ``sensor_msgs::msg::dds_::Image_``."""
    pkg, kind, name = msgtype.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_type(dds_name: str) -> str | None:
    """The ROS message type of a DDS type name (the inverse of :func:`dds_type`); None for a name that is not
    ROS 2's."""
    m = re.fullmatch(r"(\w+)::(msg|srv|action)::dds_::(\w+)_", dds_name)
    return None if m is None else f"{m[1]}/{m[2]}/{m[3]}"


@dataclass(frozen=True)
class Sample:
    """A taken sample: its serialized ``data`` (encapsulation header first), the time its writer wrote it
    (``source_ns``, ns since 1970 on the writer's clock), the time it was taken (``received_ns``, this machine's
    clock), and which writer wrote it (``writer``: an instance handle, the same for every sample of one writer)."""

    data: bytes
    source_ns: int
    received_ns: int
    writer: int


class Graph:
    """A DDS participant in the ROS 2 graph of ``domain`` (default ``ROS_DOMAIN_ID``): makes raw readers and
    writers of ROS topics and tells which types the graph publishes on a topic. Close it (or use it as a context
    manager) to leave the graph."""

    def __init__(self, domain: int | None = None) -> None:
        require_cyclonedds()
        from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication
        from cyclonedds.core import DDSException, GuardCondition, WaitSet
        from cyclonedds.domain import DomainParticipant

        self.domain = domain_id() if domain is None else int(domain)
        try:
            self.participant = DomainParticipant(self.domain)
        except DDSException as e:  # a malformed CYCLONEDDS_URI, no usable interface
            uri = os.environ.get("CYCLONEDDS_URI", "")
            where = f" (CYCLONEDDS_URI={uri[:200]!r})" if uri else ""
            raise ConfigError(f"cannot join DDS domain {self.domain}{where}: {e}") from None
        self._publications = BuiltinDataReader(self.participant, BuiltinTopicDcpsPublication)
        self._seen: dict[str, set[str]] = {}
        self.waitset = WaitSet(self.participant)
        self.wake = GuardCondition(self.participant)
        self.waitset.attach(self.wake)
        self._topics: dict[str, Any] = {}

    def __enter__(self) -> "Graph":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Leave the graph (every reader and writer made here goes with the participant)."""
        p = getattr(self, "participant", None)
        if p is not None:
            from cyclonedds.core import Entity

            self._topics.clear()
            self.waitset = self.wake = self._publications = self.participant = None
            p._delete(p._ref)  # dds_delete: the participant and every entity made in it, now (not at collection)
            Entity._entities.pop(p._ref, None)

    def _topic(self, ros_name: str, idl_type) -> Any:
        from cyclonedds.topic import Topic

        key = dds_topic(ros_name)
        if key not in self._topics:
            self._topics[key] = Topic(self.participant, key, idl_type)
        return self._topics[key]

    def writer(self, ros_name: str, idl_type, profile: str = "sensor") -> "RawWriter":
        """A writer of serialized samples on ``ros_name`` of type ``idl_type`` (an IDL class, :mod:`.idl`)."""
        from cyclonedds.pub import DataWriter

        return RawWriter(DataWriter(self.participant, self._topic(ros_name, idl_type), qos(profile, writer=True)))

    def reader(self, ros_name: str, idl_type, profile: str = "sensor", depth: int | None = None) -> "RawReader":
        """A reader of serialized samples on ``ros_name`` (``depth``: keep-last depth instead of the profile's),
        attached to :attr:`waitset`."""
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState
        from cyclonedds.sub import DataReader

        r = DataReader(self.participant, self._topic(ros_name, idl_type), qos(profile, depth=depth))
        cond = ReadCondition(r, SampleState.Any | ViewState.Any | InstanceState.Any)
        self.waitset.attach(cond)
        return RawReader(r, cond)

    def wait(self, seconds: float) -> None:
        """Block until a reader made here has samples, :meth:`interrupt` is called, or ``seconds`` pass."""
        from cyclonedds.util import duration

        self.waitset.wait(duration(seconds=max(0.0, seconds)))

    def interrupt(self) -> None:
        """Wake a :meth:`wait` (from another thread or a signal handler), and every later one: the end of reading."""
        self.wake.set(True)

    def published_types(self, ros_name: str) -> set[str]:
        """The ROS message types that writers in the graph (other than this participant's) have announced on
        ``ros_name`` so far (DDS discovery: the built-in publication topic)."""
        for e in self._publications.take(64):
            if getattr(e, "topic_name", None) is None or e.participant_key == self.participant.guid:
                continue
            t = ros_type(e.type_name)
            if t is not None and e.topic_name.startswith("rt/"):
                self._seen.setdefault(e.topic_name[2:], set()).add(t)
        return set(self._seen.get(ros_name, ()))

    def discover_type(self, ros_name: str, accepted: tuple[str, ...], timeout: float, option: str) -> str | None:
        """The type a publisher in the graph announces on ``ros_name``, waiting up to ``timeout`` seconds for one
        (None when none appeared); a ConfigError when it is not one of ``accepted`` (``option`` names the
        argument)."""
        end = time.monotonic() + timeout
        while True:
            types = self.published_types(ros_name)
            good = [t for t in sorted(types) if t in accepted]
            if good:
                return good[0]
            if types:
                raise ConfigError(
                    f"{option} {ros_name}: the graph publishes {', '.join(sorted(types))} on it; expected one of "
                    f"{', '.join(accepted)}"
                )
            if time.monotonic() >= end:
                return None
            time.sleep(0.05)


def qos(profile: str, *, depth: int | None = None, writer: bool = False):
    """The Cyclone QoS of a ROS 2 profile (:data:`QOS_PROFILES`); writers declare XCDR1 only, readers take XCDR1
    and XCDR2."""
    from cyclonedds.core import Policy, Qos
    from cyclonedds.util import duration

    if profile not in QOS_PROFILES:
        raise ConfigError(f"QoS profile must be one of {', '.join(QOS_CHOICES)}, got {profile!r}")
    reliable, transient, keep = QOS_PROFILES[profile]
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=100))
        if reliable
        else Policy.Reliability.BestEffort,
        Policy.Durability.TransientLocal if transient else Policy.Durability.Volatile,
        Policy.History.KeepLast(int(depth or keep)),
        Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=not writer),
    )


class RawWriter:
    """Writes serialized samples (bytes beginning with the encapsulation header) to its topic."""

    def __init__(self, writer) -> None:
        from cyclonedds._clayer import ddspy_write  # the binding's C-layer write of serialized bytes

        self.writer = writer
        self._write = ddspy_write
        self.written = 0

    def write(self, data) -> None:
        """Write one serialized sample (bytes, memoryview or uint8 array), padded with zeros to a multiple of 4 bytes
        as the binding's ``DataWriter.write`` pads (Cyclone pads a shorter sample with unspecified bytes)."""
        pad = -len(data) % 4
        if pad:
            data = bytes(data) + b"\x00" * pad
        ret = self._write(self.writer._ref, data)
        if ret < 0:
            from cyclonedds.core import DDSException

            raise DDSException(ret, f"while writing to {self.writer.topic.name}")
        self.written += 1

    def subscribers(self) -> int:
        """How many readers are matched with this writer now."""
        return len(self.writer.get_matched_subscriptions())


class RawReader:
    """Takes serialized samples of its topic (samples without data, e.g. a writer leaving, are left out)."""

    def __init__(self, reader, condition) -> None:
        from cyclonedds._clayer import ddspy_take  # the binding's C-layer take of serialized bytes
        from cyclonedds.core import InstanceState, SampleState, ViewState

        self.reader, self.condition = reader, condition
        self._take = ddspy_take
        self._mask = SampleState.Any | ViewState.Any | InstanceState.Any

    def take(self, n: int = 64) -> Iterator[Sample]:
        """The samples received since the last take, oldest first (at most ``n``)."""
        got = self._take(self.reader._ref, self._mask, n)
        if isinstance(got, int):
            from cyclonedds.core import DDSException

            raise DDSException(got, f"while taking from {self.reader.topic.name}")
        now = time.time_ns()
        for data, info in got:
            if info.valid_data:
                yield Sample(bytes(data), int(info.source_timestamp), now, int(info.publication_handle))


__all__ = [
    "CDR_LE",
    "Graph",
    "QOS_CHOICES",
    "QOS_PROFILES",
    "RawReader",
    "RawWriter",
    "Sample",
    "dds_topic",
    "dds_type",
    "domain_id",
    "loopback_config",
    "qos",
    "require_cyclonedds",
    "ros_topic",
    "ros_type",
]
