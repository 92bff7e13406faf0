"""Robotics inputs: ROS bags read (:mod:`~cosemdepth.robotics.rosbag`: messages, images, poses, camera_info) and an
image topic with a pose topic paired into a flight (:mod:`~cosemdepth.robotics.bag_flight`). The outputs (an output
bag, a rerun recording) are sinks of the streaming pipeline (:mod:`cosemdepth.streaming.sinks`).

Attributes are imported lazily (importing the package loads none of its modules)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "open_bag_flight": ".bag_flight",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
