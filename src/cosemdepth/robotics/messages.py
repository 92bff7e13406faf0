"""The ROS 2 messages of one processed frame: what ``predict --bag`` writes to its output bag and ``cosemdepth node``
publishes (see :mod:`cosemdepth.streaming.sinks.bag` for the topics), built as ``rosbags`` message objects of a
typestore (``ts``) with the input image's stamp and frame_id."""

from __future__ import annotations

from typing import Any, Iterator, Sequence

import numpy as np


def header(ts, stamp_ns: int, frame_id: str):
    """A ``std_msgs/Header`` with stamp ``stamp_ns`` (integer nanoseconds)."""
    t = ts.types
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id=frame_id)


def image(ts, hdr, array: np.ndarray, encoding: str):
    """A ``sensor_msgs/Image`` of ``array`` ([H, W] or [H, W, C], its bytes as they are) with ``encoding``."""
    h, w = array.shape[:2]
    data = np.ascontiguousarray(array).view(np.uint8).reshape(-1)
    return ts.types["sensor_msgs/msg/Image"](
        header=hdr, height=h, width=w, encoding=encoding, is_bigendian=0, step=data.size // h, data=data
    )


def camera_info(ts, hdr, size: tuple[int, int], k: Sequence[float]):
    """A ``sensor_msgs/CameraInfo`` of ``size`` (H, W) and ``k = (fx, fy, cx, cy)`` in the package's pixel convention
    (written in ROS's: pixel centres at integer coordinates), no distortion."""
    t = ts.types
    fx, fy, cx, cy = (float(v) for v in k)
    cx, cy = cx - 0.5, cy - 0.5  # ROS/OpenCV: pixel centres at integer coordinates
    return t["sensor_msgs/msg/CameraInfo"](
        header=hdr,
        height=int(size[0]),
        width=int(size[1]),
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1], dtype=np.float64),
        r=np.eye(3).reshape(-1),
        p=np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0], dtype=np.float64),
        binning_x=0,
        binning_y=0,
        roi=t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def depth_status(ts, hdr, status: str, values: Sequence[tuple[str, str]]):
    """The ``diagnostic_msgs/DiagnosticArray`` of a frame's depth: one status, level OK ``estimated``, WARN ``held``,
    ERROR otherwise (``reset``), message the status, ``values`` as key/value pairs."""
    t = ts.types
    st = t["diagnostic_msgs/msg/DiagnosticStatus"]
    level = {"estimated": st.OK, "held": st.WARN}.get(status, st.ERROR)
    return t["diagnostic_msgs/msg/DiagnosticArray"](
        header=hdr,
        status=[
            st(
                level=level,
                name="cosemdepth depth",
                message=status,
                hardware_id=hdr.frame_id,
                values=[t["diagnostic_msgs/msg/KeyValue"](key=k, value=v) for k, v in values],
            )
        ],
    )


def point_cloud(ts, hdr, points: np.ndarray):
    """A ``sensor_msgs/PointCloud2`` of ``points`` ``[N, 3]`` (metres in the header's frame): one row of N points,
    fields ``x``, ``y``, ``z`` float32 little-endian, 12 bytes a point, dense (no invalid point)."""
    t = ts.types
    pts = np.ascontiguousarray(points, dtype="<f4").reshape(-1, 3)
    field = t["sensor_msgs/msg/PointField"]
    fields = [field(name=n, offset=4 * i, datatype=field.FLOAT32, count=1) for i, n in enumerate("xyz")]
    return t["sensor_msgs/msg/PointCloud2"](
        header=hdr,
        height=1,
        width=len(pts),
        fields=fields,
        is_bigendian=False,
        point_step=12,
        row_step=12 * len(pts),
        data=pts.view(np.uint8).reshape(-1),
        is_dense=True,
    )


def frame_status(batch, b: int) -> str:
    """Row ``b``'s depth status (``reset`` for a reset frame of a stream without statuses)."""
    statuses = getattr(batch, "status", None) or []
    return statuses[b] if b < len(statuses) else ("reset" if bool(batch.reset[b]) else "estimated")


def valid_depth(batch, b: int) -> tuple[np.ndarray, np.ndarray] | None:
    """``(depth [H, W] float32 little-endian with NaN where not valid, valid [H, W] bool)`` of row ``b``, None
    without depth. A pixel is valid where the stream's mask says so and its depth is finite and positive."""
    if batch.depth is None:
        return None
    depth = batch.depth[b, 0].float().cpu().numpy().astype("<f4")
    valid = np.isfinite(depth) & (depth > 0)
    if getattr(batch, "valid", None) is not None:
        valid &= batch.valid[b, 0].cpu().numpy().astype(bool)
    elif bool(batch.reset[b]):
        valid[...] = False
    return np.where(valid, depth, np.float32(np.nan)).astype("<f4"), valid


def frame_messages(
    ts,
    batch,
    b: int,
    stamp_ns: int,
    frame_id: str,
    intrinsics: Sequence[float],
    palette: np.ndarray | None,
    *,
    status_values: Sequence[tuple[str, str]] = (),
    depth: tuple[np.ndarray, np.ndarray] | None = None,
) -> Iterator[tuple[str, Any]]:
    """``(topic name, message)`` of row ``b`` of a stream batch, in this order: ``depth``, ``depth_valid``,
    ``depth_status`` (values ``status``, ``baseline_m``, ``valid_fraction``, then ``status_values``) without
    M4Semantic; ``labels``, ``labels_color`` (with a ``palette``) without M4Depth; ``camera_info`` (``intrinsics`` at the
    output size, package convention). ``depth``: :func:`valid_depth` of the row when already computed."""
    hdr = header(ts, stamp_ns, frame_id)
    h, w = batch.rgb.shape[-2:]
    depth = valid_depth(batch, b) if depth is None else depth
    if depth is not None:
        d, valid = depth
        yield "depth", image(ts, hdr, d, "32FC1")
        yield "depth_valid", image(ts, hdr, valid.astype(np.uint8) * np.uint8(255), "mono8")
        base = getattr(batch, "baseline", None)
        status = frame_status(batch, b)
        values = [
            ("status", status),
            ("baseline_m", "" if base is None else f"{float(base[b]):.6f}"),
            ("valid_fraction", f"{float(valid.mean()):.6f}"),
            *status_values,
        ]
        yield "depth_status", depth_status(ts, hdr, status, values)
    if batch.labels is not None:
        labels = batch.labels[b].cpu().numpy().astype(np.uint8)
        yield "labels", image(ts, hdr, labels, "mono8")
        if palette is not None:
            yield "labels_color", image(ts, hdr, np.asarray(palette, dtype=np.uint8)[labels], "rgb8")
    yield "camera_info", camera_info(ts, hdr, (int(h), int(w)), intrinsics)


__all__ = [
    "camera_info",
    "depth_status",
    "frame_messages",
    "frame_status",
    "header",
    "image",
    "point_cloud",
    "valid_depth",
]
