"""Predictions as a ROS 2 bag (MCAP storage), one message per topic and processed image, with the input image's
header stamp and frame_id (``cosemdepth predict --bag``):

==============================  ===============================  =====================================================
topic (default namespace)       type                             content
==============================  ===============================  =====================================================
``/cosemdepth/depth``           ``sensor_msgs/msg/Image``        ``32FC1``: metres along the optical axis; NaN where
                                                                 the depth is not valid (REP 117/118)
``/cosemdepth/depth_valid``     ``sensor_msgs/msg/Image``        ``mono8``: 255 where the depth is an estimate, 0 not
``/cosemdepth/depth_status``    ``diagnostic_msgs/msg/           one status per frame: level OK ``estimated``, WARN
                                DiagnosticArray``                ``held`` (the reference frame's depth carried: too
                                                                 little motion), ERROR ``reset`` (no depth); message:
                                                                 the status; values: ``status``, ``baseline_m``,
                                                                 ``valid_fraction`` (the policy: predictions.json)
``/cosemdepth/labels``          ``sensor_msgs/msg/Image``        ``mono8``: class index
``/cosemdepth/labels_color``    ``sensor_msgs/msg/Image``        ``rgb8``: the class palette
``/cosemdepth/camera_info``     ``sensor_msgs/msg/CameraInfo``   the output size; K scaled to it (ROS pixel centres)
==============================  ===============================  =====================================================

Depth topics are absent for M4Semantic models, label topics for M4Depth. The bag is written with ``rosbags``
(optional: ``pip install cosemdepth[ros]``) into the staging folder of ``predict``, so it appears with the other
outputs or not at all. Messages are logged at their header stamp: the input image's, from each frame's ``meta``
(``stamp_ns``, ``frame_id``: what a bag source puts there).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import ConfigError
from ...robotics.messages import frame_messages
from ...robotics.rosbag import require_rosbags
from ..frames import StreamBatch
from ..registry import register_sink

DEFAULT_NAMESPACE = "/cosemdepth"


def check_namespace(ns: str) -> str:
    """``ns`` as a topic prefix (leading ``/``, no trailing one); a ConfigError when it is not a valid ROS name."""
    ns = "/" + str(ns).strip("/")
    if ns != "/" and not re.fullmatch(r"(/[A-Za-z][A-Za-z0-9_]*)+", ns):
        raise ConfigError(
            f"--out-namespace {ns!r} is not a valid ROS namespace (letters, digits, _ and /; each "
            "part starting with a letter)"
        )
    return "" if ns == "/" else ns


class BagSink:
    """A ``predict`` sink writing the bag at ``FOLDER/bag`` (see the module docstring).

    Args:
        intrinsics: ``(fx, fy, cx, cy)`` at the output size in the package's pixel convention (design 2.1).
        palette: ``[N, 3]`` uint8 for ``labels_color`` (None: no label topics).
        namespace: topic prefix.
    """

    def __init__(self, intrinsics, palette=None, namespace: str = DEFAULT_NAMESPACE) -> None:
        require_rosbags()
        self.k = [float(v) for v in intrinsics]
        self.palette = None if palette is None else np.asarray(palette, dtype=np.uint8)
        self.ns = check_namespace(namespace)
        self._writer = None
        self._conns: dict[str, Any] = {}
        self.messages = 0
        self.path: Path | None = None

    def open(self, folder: Path | None) -> None:
        if folder is None:
            raise ConfigError("the output bag needs an output folder")
        # deferred: an optional dependency (cosemdepth[ros]), checked by require_rosbags
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        self.ts = get_typestore(Stores.ROS2_HUMBLE)
        self.path = Path(folder) / "bag"
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()

    def _conn(self, name: str, msgtype: str):
        if name not in self._conns:
            self._conns[name] = self._writer.add_connection(f"{self.ns}/{name}", msgtype, typestore=self.ts)
        return self._conns[name]

    def _write(self, name: str, msg: Any, stamp: int) -> None:
        self._writer.write(self._conn(name, msg.__msgtype__), stamp, self.ts.serialize_cdr(msg, msg.__msgtype__))
        self.messages += 1

    def __call__(self, batch: StreamBatch) -> None:
        for b in range(len(batch)):
            stamp, frame_id = int(batch.meta[b]["stamp_ns"]), batch.meta[b]["frame_id"]
            for name, msg in frame_messages(self.ts, batch, b, stamp, frame_id, self.k, self.palette):
                self._write(name, msg, stamp)

    def close(self) -> dict[str, Any]:
        """Finish the bag; the manifest entry describing it."""
        self._writer.close()
        self._writer = None
        return {
            "bag": {
                "path": "bag",
                "storage": "mcap",
                "topics": {f"{self.ns}/{n}": c.msgtype for n, c in self._conns.items()},
                "messages": self.messages,
            }
        }

    def abort(self) -> None:
        if self._writer is not None:
            try:
                self._writer.close()
            except Exception:
                pass
            self._writer = None


register_sink("bag", BagSink)

__all__ = ["BagSink", "DEFAULT_NAMESPACE", "check_namespace"]
