"""Live ROS 2 without a ROS installation: a Cyclone DDS participant that follows ROS 2's wire mapping
(:mod:`.dds`, :mod:`.idl`), the live camera + pose input as a streaming source (:mod:`.source`, :mod:`.poses`), the
outputs as topics (:mod:`.sink`), the node's loop (:mod:`.node`) and a bag replayer (:mod:`.replay`).

Attributes are imported lazily (importing the package loads none of its modules, nor ``cyclonedds``)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "Graph": ".dds",
    "loopback_config": ".dds",
    "LiveOptions": ".source",
    "LiveSource": ".source",
    "TopicSink": ".sink",
    "run_node": ".node",
    "replay_bag": ".replay",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
