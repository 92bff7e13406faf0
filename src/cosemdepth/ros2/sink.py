"""The live topics sink: every processed frame published to the ROS 2 graph, the messages ``predict --bag`` writes
to its bag (:mod:`cosemdepth.robotics.messages`) plus, on request, a point cloud of the valid depth.

Topics (under the namespace, default ``/cosemdepth``; each name can be remapped, ``depth:=/camera/depth/image``):

==================  ===================================  =========================================================
name                type                                 content
==================  ===================================  =========================================================
``depth``           ``sensor_msgs/msg/Image``            ``32FC1`` metres along the optical axis, NaN where not valid
                                                         (and where an undistorted image has no source pixel)
``depth_valid``     ``sensor_msgs/msg/Image``            ``mono8`` 255 where the depth is an estimate, 0 where not
``depth_status``    ``diagnostic_msgs/msg/               the bag's status values, then the node's: ``latency_ms``,
                    DiagnosticArray``                    ``stamp_age_ms``, ``step_ms`` (the model's step),
                                                         ``queue_ms`` (the image waiting for the model and its
                                                         pose), ``convert_ms`` (decoding, resizing or
                                                         undistorting), ``frames_received``, ``frames_processed``,
                                                         ``frames_dropped``, ``frames_without_pose``, and
                                                         ``reset_reason`` / ``depth_invalid_reason`` when there is one
``labels``          ``sensor_msgs/msg/Image``            ``mono8`` class index
``labels_color``    ``sensor_msgs/msg/Image``            ``rgb8`` the class palette
``camera_info``     ``sensor_msgs/msg/CameraInfo``       the output size, K scaled to it (ROS pixel centres); a
                                                         calibrated lens: the pinhole it is undistorted to, no
                                                         distortion
``points``          ``sensor_msgs/msg/PointCloud2``      (``points=True``) the valid depth pixels back-projected:
                                                         x, y, z float32 in the image's optical frame
==================  ===================================  =========================================================

Every message carries the input image's stamp and frame_id. ``latency_ms`` is the time from the input image's
writing (its DDS source timestamp) to the moment its outputs are handed to DDS; ``stamp_age_ms`` the time from its
header stamp (meaningful when the camera stamps with this machine's clock).
"""

from __future__ import annotations

import functools
import time
from collections import deque
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from ..geometry.camera import pixel_rays
from ..robotics.messages import frame_messages, header, point_cloud, valid_depth
from ..streaming.registry import register_sink
from ..streaming.sinks.bag import check_namespace
from .dds import Graph, RawWriter, ros_topic
from .idl import encode, idl_type, typestore

#: Output name -> message type.
OUTPUT_TYPES = {
    "depth": "sensor_msgs/msg/Image",
    "depth_valid": "sensor_msgs/msg/Image",
    "depth_status": "diagnostic_msgs/msg/DiagnosticArray",
    "labels": "sensor_msgs/msg/Image",
    "labels_color": "sensor_msgs/msg/Image",
    "camera_info": "sensor_msgs/msg/CameraInfo",
    "points": "sensor_msgs/msg/PointCloud2",
}
#: Latencies kept for the percentiles of the reports.
LATENCY_WINDOW = 2048


def output_names(has_depth: bool, has_labels: bool, palette: bool, points: bool) -> list[str]:
    """The outputs of a model: depth ones without M4Semantic, label ones without M4Depth."""
    names = ["depth", "depth_valid", "depth_status"] if has_depth else []
    names += (["labels"] + (["labels_color"] if palette else [])) if has_labels else []
    return names + ["camera_info"] + (["points"] if points and has_depth else [])


def parse_remaps(remaps: Sequence[str]) -> dict[str, str]:
    """``NAME:=TOPIC`` pairs (ROS's remapping syntax) -> {output name: absolute topic}; a ConfigError naming a bad
    one."""
    from ..errors import ConfigError

    out = {}
    for r in remaps:
        name, sep, topic = str(r).partition(":=")
        if not sep or name not in OUTPUT_TYPES:
            raise ConfigError(
                f"--remap {r!r}: expected NAME:=TOPIC with NAME one of {', '.join(OUTPUT_TYPES)} "
                "(e.g. depth:=/camera/depth/image)"
            )
        out[name] = ros_topic(topic, f"--remap {name}")
    return out


@functools.lru_cache(maxsize=4)
def _rays(h: int, w: int, intrinsics: tuple[float, ...]) -> np.ndarray:
    """``[3, H, W]`` float64 pixel rays (z = 1) of a camera, computed once per camera (read-only)."""
    rays = pixel_rays(h, w, torch.tensor([list(intrinsics)], dtype=torch.float64))[0].numpy()
    rays.setflags(write=False)
    return rays


def points_of(depth: np.ndarray, valid: np.ndarray, intrinsics: Sequence[float]) -> np.ndarray:
    """``[N, 3]`` float32: the valid pixels of ``depth`` ``[H, W]`` (metres along the optical axis) back-projected
    with ``intrinsics`` (fx, fy, cx, cy; package convention), row by row."""
    h, w = depth.shape
    rays = _rays(h, w, tuple(float(v) for v in intrinsics))
    pts = rays[:, valid] * depth[valid].astype(np.float64)
    return pts.T.astype(np.float32)


class TopicSink:
    """A pipeline sink publishing every frame (see the module docstring).

    Args:
        graph: the participant to publish from.
        outputs: the output names to publish (:func:`output_names`).
        namespace: topic prefix (``--out-namespace``); remaps: {output name: topic} overriding it.
        palette: ``[N, 3]`` uint8 of ``labels_color``.
        profile: ``sensor`` or ``reliable`` (:data:`~cosemdepth.ros2.dds.QOS_PROFILES`).
        stats: the run's :class:`~cosemdepth.ros2.source.LiveStats` (counters in each status).
    """

    def __init__(
        self,
        graph: Graph,
        outputs: Sequence[str],
        *,
        namespace: str = "/cosemdepth",
        remaps: dict[str, str] | None = None,
        palette=None,
        profile: str = "sensor",
        stats=None,
    ) -> None:
        ns = check_namespace(namespace)
        self.topics = {n: (remaps or {}).get(n, f"{ns}/{n}") for n in outputs}
        self.graph, self.profile, self.stats = graph, profile, stats
        self.palette = None if palette is None else np.asarray(palette, dtype=np.uint8)
        self.ts = typestore()
        self.writers: dict[str, RawWriter] = {}
        self.latencies: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self.published = 0

    def open(self, folder: Path | None = None) -> None:
        for name, topic in self.topics.items():
            self.writers[name] = self.graph.writer(topic, idl_type(OUTPUT_TYPES[name]), self.profile)

    def __call__(self, batch) -> None:
        for b in range(len(batch)):
            self._publish(batch, b)

    def _publish(self, batch, b: int) -> None:
        meta = batch.meta[b]
        stamp, frame_id = int(meta["stamp_ns"]), str(meta["frame_id"])
        k = meta.get("intrinsics") or [float(v) for v in batch.intrinsics[b].tolist()]
        depth = valid_depth(batch, b)
        now = time.time_ns()
        latency = (now - int(meta["source_ns"])) / 1e6
        self.latencies.append(latency)
        values = [
            ("latency_ms", f"{latency:.1f}"),
            ("stamp_age_ms", f"{(now - stamp) / 1e6:.1f}"),
            ("step_ms", f"{1e3 * float(getattr(batch, 'seconds', 0.0)):.1f}"),
        ]
        if "picked_ns" in meta:  # the source's timings: waiting for the model to be free, converting the image
            values += [
                ("queue_ms", f"{(int(meta['picked_ns']) - int(meta['received_ns'])) / 1e6:.1f}"),
                ("convert_ms", f"{(int(meta['ready_ns']) - int(meta['picked_ns'])) / 1e6:.1f}"),
            ]
        if self.stats is not None:
            values += [(k_, str(v)) for k_, v in self.stats.as_dict().items() if k_ != "resets"]
        values += [(key, str(meta[key])) for key in ("reset_reason", "depth_invalid_reason") if key in meta]
        out = list(
            frame_messages(self.ts, batch, b, stamp, frame_id, k, self.palette, status_values=values, depth=depth)
        )
        if "points" in self.writers and depth is not None:
            out.append(("points", point_cloud(self.ts, header(self.ts, stamp, frame_id), points_of(*depth, k))))
        for name, msg in out:
            writer = self.writers.get(name)
            if writer is not None:
                writer.write(encode(msg, self.ts))
        self.published += 1

    def close(self) -> dict[str, Any]:
        summary = {"topics": dict(self.topics), "frames_published": self.published}
        self.writers.clear()
        return {"live_topics": summary}

    def abort(self) -> None:
        self.writers.clear()


register_sink("topics", TopicSink)


__all__ = ["LATENCY_WINDOW", "OUTPUT_TYPES", "TopicSink", "output_names", "parse_remaps", "points_of"]
