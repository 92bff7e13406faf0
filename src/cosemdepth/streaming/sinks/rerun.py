"""A flight's predictions as a rerun recording (``.rrd``; ``predict --rerun FILE.rrd`` and ``cosemdepth view``).

Open it with ``rerun FILE.rrd`` (the viewer ships with ``pip install cosemdepth[viz]``). Entities, on the timeline
``frame`` (the frame's position in the run) and, when the inputs have stamps, ``time`` (their stamps):

====================================  ===========================================================================
entity                                content
====================================  ===========================================================================
``world``                             (static) the world's axes: ENU (z up) for bags, else the first camera's
                                      optical frame (x right, y down, z forward)
``world/camera``                      ``Transform3D``: camera-to-world pose of every frame
``world/camera/image``                (static) ``Pinhole``: the intrinsics at the output size (RDF camera)
``world/camera/image/rgb``            ``Image``: the model's input
``world/camera/image/depth``          ``DepthImage(meter=1)``: predicted metres, 0 where the depth is not valid
                                      (its mask); under the pinhole the viewer back-projects the others to a
                                      point cloud (a depth of 0 is no point)
``world/camera/image/labels``         ``SegmentationImage``: class index, named and coloured by the static
                                      ``AnnotationContext`` on ``world``
``world/trajectory``                  (static) ``LineStrips3D``: the camera path, one strip per trajectory
``metrics/<name>``                    ``Scalars`` per frame when ground truth is known (not on reset frames):
                                      ``abs_rel``, ``rmse``, ``delta1`` (depth); ``pixel_accuracy``, ``miou``
====================================  ===========================================================================

Without absolute poses (datasets, ``--flight``) the path is the chain of the relative camera motions the model gets,
starting at the identity on every trajectory's first frame; with them (a source whose frames carry ``pose``: bags),
the frames' camera-to-world poses. ``rerun-sdk`` is optional (``pip install
cosemdepth[viz]``) and imported only here, when a recording is made.
"""

from __future__ import annotations

import errno
import os
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from ...data.quaternion import qmatrix
from ...errors import ConfigError
from ...measures.metrics import depth_metrics
from ...optional import require
from ...output_safety.atomic import _default_mode
from ...output_safety.outdir import check_output_file, record_output_file
from ..frames import StreamBatch
from ..registry import register_sink

APPLICATION_ID = "cosemdepth"


def require_rerun():
    """The ``rerun`` module, or a ConfigError saying how to install it."""
    # rerun's own log would print a failed write as a second line: check_recording_written reports it (RUST_LOG set
    # by the user wins)
    os.environ.setdefault("RUST_LOG", "off")
    return require("rerun", "writing a rerun recording")  # lazy: an optional dependency, only for .rrd recordings


def _written_by_us(path: Path) -> bool:
    """Whether ``path`` is a rerun recording this package wrote (its application id)."""
    from rerun.chunk import RrdReader  # deferred: an optional dependency (cosemdepth[viz])

    try:
        return any(e.application_id.startswith(APPLICATION_ID) for e in RrdReader(str(path)).recordings())
    except Exception:  # anything that is not a readable recording is not ours
        return False


def check_rrd_path(path: str | Path, option: str = "--rerun", inputs=()) -> Path:
    """``path`` as the recording's file, under the output policy of :mod:`cosemdepth.output_safety.outdir`: a ConfigError when
    it lacks the ``.rrd`` suffix, is a folder or an input, its folder does not exist or is not writable, or it exists
    and is not a recording that cosemdepth wrote (those are replaced)."""
    path = Path(path)
    if path.suffix != ".rrd":
        raise ConfigError(f"{option} {path}: a rerun recording's name must end with .rrd")
    check_output_file(path, what=f"{option} recording", inputs=inputs, recognize=_written_by_us)
    return path


def check_recording_written(tmp: Path, path: Path) -> None:
    """Raise an OSError naming ``path`` if the recording written to ``tmp`` may have been cut short.

    rerun's file sink writes from a thread of its own and reports a failed write (a full disk) only in its log; the
    file it leaves reads as a shorter recording. A recording is taken as cut short when its file system has no free
    block left once it is closed (where a write would have failed), or when it cannot be read back."""
    try:
        st = os.statvfs(tmp)
        free = (st.f_bfree if hasattr(os, "geteuid") and os.geteuid() == 0 else st.f_bavail) * st.f_frsize
    except (OSError, AttributeError):  # pragma: no cover - a system without statvfs
        free = None
    if free == 0:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    from rerun.chunk import RrdReader  # deferred: an optional dependency (cosemdepth[viz])

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            RrdReader(str(tmp)).recordings()
    except Exception as e:  # noqa: BLE001 - whatever the reader says, the file is not a whole recording
        raise OSError(
            errno.EIO, f"the recording does not read back ({str(e).splitlines()[0][:200]})", str(path)
        ) from None


def _chain(r_prev: np.ndarray, p_prev: np.ndarray, q: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-to-world of frame i from frame i-1's and the relative motion ``X_{i-1} = R(q) X_i + t``."""
    r = qmatrix(np.asarray(q, dtype=np.float64))
    return r_prev @ r, r_prev @ np.asarray(t, dtype=np.float64) + p_prev


class RerunSink:
    """A sink writing the recording ``path`` (``predict --rerun``, ``cosemdepth view``; see the module docstring).

    Args:
        path: the ``.rrd`` file (written under a temporary name, renamed on :meth:`close`).
        class_names, palette: the class table (None: a model without labels).
        absolute_poses: the frames carry absolute camera-to-world poses (``FrameBatch.pose``) in a z-up world
            (bags); else the path is the chain of the relative motions in the first camera's frame.
        command: the command writing it (recorded with the file's checksum in its folder's output marker).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        class_names=None,
        palette=None,
        absolute_poses: bool = False,
        command: str = "view",
    ) -> None:
        self.rr = require_rerun()
        self.path = Path(path)
        self.command = command
        self.names = list(class_names or [])
        self.palette = None if palette is None else np.asarray(palette, dtype=np.uint8)
        self.absolute_poses = absolute_poses
        self.frames = 0
        self._tmp: Path | None = None
        self._rec = None
        self._paths: list[list[list[float]]] = []
        self._traj: Any = None
        self._pose = (np.eye(3), np.zeros(3))

    def open(self, folder: Path | None = None) -> None:
        rr = self.rr
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.absolute().parent)
        os.close(fd)
        self._tmp = Path(tmp)
        rec = self._rec = rr.RecordingStream(APPLICATION_ID)
        rec.save(str(self._tmp))
        up = rr.ViewCoordinates.RIGHT_HAND_Z_UP if self.absolute_poses else rr.ViewCoordinates.RDF
        rec.log("world", up, static=True)
        if self.palette is not None:
            rec.log(
                "world",
                rr.AnnotationContext(
                    [(i, name, tuple(int(c) for c in self.palette[i])) for i, name in enumerate(self.names)]
                ),
                static=True,
            )

    def _camera(self, batch: StreamBatch, b: int) -> tuple[np.ndarray, np.ndarray]:
        if self.absolute_poses:
            pose = batch.pose[b].detach().cpu().numpy().astype(np.float64)
            return pose[:3, :3], pose[:3, 3]
        row, traj = int(batch.frame[b]), batch.trajectory[b]
        if row == 0 or traj != self._traj or bool(batch.reset[b]):
            return np.eye(3), np.zeros(3)
        q, t = (x[b].detach().cpu().numpy() for x in (batch.rot, batch.trans))
        return _chain(*self._pose, q, t)

    def __call__(self, batch: StreamBatch) -> None:
        rr, rec = self.rr, self._rec
        for b in range(len(batch)):
            traj = batch.trajectory[b]
            r, p = self._camera(batch, b)
            if traj != self._traj:
                self._traj = traj
                self._paths.append([])
                h, w = batch.rgb.shape[-2:]
                fx, fy, cx, cy = (float(v) for v in batch.intrinsics[b])
                rec.log(
                    "world/camera/image",
                    rr.Pinhole(
                        focal_length=[fx, fy],
                        principal_point=[cx, cy],
                        resolution=[int(w), int(h)],
                        camera_xyz=rr.ViewCoordinates.RDF,
                    ),
                    static=True,
                )
            self._pose = (r, p)
            self._paths[-1].append([float(v) for v in p])
            rec.set_time("frame", sequence=self.frames)
            if batch.stamp[b] is not None:
                rec.set_time("time", timestamp=float(batch.stamp[b]))
            rec.log("world/camera", rr.Transform3D(translation=p, mat3x3=r))
            rgb = (np.clip(batch.rgb[b].float().cpu().numpy().transpose(1, 2, 0), 0, 1) * 255 + 0.5).astype(np.uint8)
            rec.log("world/camera/image/rgb", rr.Image(rgb))
            if batch.depth is not None:
                depth = batch.depth[b, 0].float().cpu().numpy().astype(np.float32)
                if getattr(batch, "valid", None) is not None:  # no point for a pixel without an estimate
                    depth = np.where(batch.valid[b, 0].cpu().numpy(), depth, np.float32(0.0))
                rec.log("world/camera/image/depth", rr.DepthImage(depth, meter=1.0))
            if batch.labels is not None:
                rec.log(
                    "world/camera/image/labels", rr.SegmentationImage(batch.labels[b].cpu().numpy().astype(np.uint8))
                )
            if not bool(batch.reset[b]):
                if batch.gt_depth is not None and batch.depth is not None:
                    m = depth_metrics(batch.gt_depth[b, 0].float().cpu(), batch.depth[b, 0].float().cpu())
                    for k in ("abs_rel", "rmse", "delta1"):
                        rec.log(f"metrics/{k}", rr.Scalars(float(m[k])))
                if batch.gt_labels is not None and batch.labels is not None:
                    for k, v in label_metrics(batch.gt_labels[b].cpu().numpy(), batch.labels[b].cpu().numpy()).items():
                        rec.log(f"metrics/{k}", rr.Scalars(v))
            self.frames += 1

    def close(self) -> dict[str, Any]:
        """Write the trajectory, finish the file and rename it into place; the manifest entry describing it."""
        rr, rec = self.rr, self._rec
        if self._paths:
            rec.log("world/trajectory", rr.LineStrips3D([np.asarray(s) for s in self._paths]), static=True)
        try:
            rec.flush()
            rec.disconnect()
        except Exception as e:  # noqa: BLE001 - rerun's writer thread died (its errors carry no errno)
            self._rec = None
            check_recording_written(self._tmp, self.path)  # a full disk says so
            raise OSError(
                errno.EIO, f"rerun could not finish the recording ({str(e).splitlines()[0][:200]})", str(self.path)
            ) from None
        self._rec = None
        check_recording_written(self._tmp, self.path)
        os.chmod(self._tmp, _default_mode())  # as every other output (mkstemp creates 0600)
        os.replace(self._tmp, self.path)
        self._tmp = None
        record_output_file(self.path, self.command)  # replaced by a later run only while unchanged
        return {"rerun": {"path": str(self.path), "frames": self.frames}}

    def abort(self) -> None:
        if self._rec is not None:
            try:
                self._rec.disconnect()
            except Exception:
                pass
            self._rec = None
        if self._tmp is not None:
            self._tmp.unlink(missing_ok=True)
            self._tmp = None


def label_metrics(gt: np.ndarray, pred: np.ndarray) -> dict[str, float]:
    """Per-frame ``pixel_accuracy`` and ``miou`` (mean IoU over the classes present in ``gt`` or ``pred``)."""
    gt = np.asarray(gt).reshape(-1)
    pred = np.asarray(pred).reshape(-1)
    ious = []
    for c in np.union1d(np.unique(gt), np.unique(pred)):
        inter = np.sum((gt == c) & (pred == c))
        union = np.sum((gt == c) | (pred == c))
        ious.append(inter / union)
    return {"pixel_accuracy": float(np.mean(gt == pred)), "miou": float(np.mean(ious)) if ious else 0.0}


register_sink("rerun", RerunSink)

__all__ = [
    "APPLICATION_ID",
    "RerunSink",
    "check_recording_written",
    "check_rrd_path",
    "label_metrics",
    "require_rerun",
]
