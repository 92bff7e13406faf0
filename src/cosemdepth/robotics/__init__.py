"""Robotics I/O: ROS 2 bags in (image and pose topics paired into a flight) and out (depth, validity, labels,
status), rerun recordings, and the command-line glue that adds them to ``predict`` and ``view``.

Attributes are imported lazily (importing the package loads none of its modules)."""

from __future__ import annotations

from .._lazy import lazy_getattr as _lazy_getattr

_LAZY = {
    "open_bag_flight": ".bag_flight",
    "BagWriter": ".bag_writer",
    "RerunWriter": ".rerun_writer",
    "add_robotics_args": ".cli",
}

__getattr__ = _lazy_getattr(__name__, _LAZY)


__all__ = sorted(_LAZY)
