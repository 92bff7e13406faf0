"""``predict``'s files, pictures and videos: the sink :class:`FilesSink` (``cosemdepth predict``).

Output folder (one sub-folder per trajectory; ``NNNNNN`` is the input image's file stem, so that a user can match
outputs and inputs (for a bag frame: ``<topic's last part>_<seconds, 10 digits>.<nanoseconds, 9 digits>``, the
image's full stamp; for a video frame: its 0-based index in decoding order, 6 digits); the frame's row in its
trajectory, 6 digits, when the dataset has no file names; a stem seen twice in one trajectory gets ``_<row>``
appended)::

    OUT/predictions.json                       what was run, the encodings below, every frame's status and files
    OUT/<trajectory>/depth/NNNNNN.npy          predicted depth, float32 [H, W], metres (the model's output as is;
                                               with invalid="nan", NaN where depth_valid is 0)
    OUT/<trajectory>/depth_valid/NNNNNN.png    8-bit PNG, 255 where the depth is an estimate, 0 where it is not
    OUT/<trajectory>/depth_png/NNNNNN.png      16-bit PNG, uint16 = round(depth_m * 256), saturated to [1, 65535]
                                               (1/256 m steps up to 255.996 m; depth_m = png / 256); 0: no depth
    OUT/<trajectory>/labels/NNNNNN.png         8-bit PNG of class indices (argmax)
    OUT/<trajectory>/labels_color/NNNNNN.png   RGB PNG, the dataset's palette (Mid-Air/SynthAir: design 10.5)
    OUT/<trajectory>/side_by_side/NNNNNN.png   RGB | depth | GT depth | labels | GT labels (GT when known), each
                                               panel >= 384 px, a depth colour bar and a class legend below
    OUT/<trajectory>/video.mp4                 the side-by-side frames as a video (GIF without ffmpeg)

The pictures (:mod:`cosemdepth.render.figures`) colour depth on a range fixed per trajectory, chosen from its
first frames (recorded in ``predictions.json`` under the trajectory's ``pictures``) unless ``depth_range`` is given.

Depth outputs are absent for M4Semantic, label outputs for M4Depth. A depth map says which pixels it could not
estimate (:mod:`cosemdepth.inference.policy`): each frame's record in ``predictions.json`` has its ``status``
(``reset``: the first frame of a trajectory or a frame held after it, no pixel valid, its depth the model's initial
value; ``estimated``; ``held``: the reference frame's depth carried into this view because the camera moved less
than the policy's minimum baseline), ``baseline_m`` and ``valid_fraction``; ``depth_valid`` is the per-pixel mask.

The folder is written under a temporary name beside ``OUT`` and renamed to ``OUT`` at the end (each file is also
written atomically): a run that fails leaves nothing behind; a previous output of ``predict`` in ``OUT`` is replaced.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np

from ...data.video import is_video
from ...errors import ConfigError
from ...render.figures import FlightPictures, frame_maps
from ...render.visualize import DEFAULT_FPS, DEFAULT_VIDEO, VIDEO_FORMATS, VideoWriter, save_png
from ...tasks import TASKS, DecoderTask, TaskWriter, WriteOptions
from ..frames import StreamBatch
from ..registry import register_sink

#: The file ``predict`` writes its manifest to.
MANIFEST = "predictions.json"


class _NoFiles(TaskWriter):
    """The writer of a task that writes no file."""

    def write(self, folder, rel, stem, frames, b, record):
        return {}


_NO_FILES = _NoFiles()
#: What the ``.npy`` depth holds where the mask is 0 (``--invalid``): the model's values, or NaN.
INVALID_MODES = ("keep", "nan")
DEFAULT_INVALID = "keep"
#: ``predictions.json``'s description of the side-by-side pictures.
SIDE_BY_SIDE = (
    "side_by_side/*.png: RGB | predicted depth | ground-truth depth | predicted labels | ground-truth labels (GT when "
    "known), depth on the turbo colour map, linear from red (0 m) to dark blue at the range in "
    "trajectories[].pictures.depth_range_m, with a colour bar and a class legend"
)


@dataclass(frozen=True)
class FileOptions:
    """What ``predict`` writes besides the tasks' files, checked here once.

    Attributes:
        video: ``"mp4"`` (GIF when there is no ffmpeg), ``"gif"`` or None (``"none"`` is taken for None).
        fps: the videos' frame rate (> 0).
        invalid: what the depth ``.npy`` holds where the mask is 0: ``"keep"`` (the model's values) or ``"nan"``.
        depth_range: ``(near, far)`` metres of the depth colour map (None: chosen per trajectory from its first
            frames).
    """

    video: Optional[str] = DEFAULT_VIDEO
    fps: float = DEFAULT_FPS
    invalid: str = DEFAULT_INVALID
    depth_range: Optional[tuple[float, float]] = None

    def __post_init__(self) -> None:
        if self.video == "none":
            object.__setattr__(self, "video", None)
        if self.video is not None and self.video not in VIDEO_FORMATS:
            raise ConfigError(f"--video must be one of {(*VIDEO_FORMATS, 'none')}, got {self.video!r}")
        if not self.fps > 0:
            raise ConfigError(f"--fps must be positive, got {self.fps}")
        if self.invalid not in INVALID_MODES:
            raise ConfigError(f"--invalid must be one of {', '.join(INVALID_MODES)}, got {self.invalid!r}")


def safe_relpath(name: str) -> str:
    """A trajectory name as a relative folder path: path parts kept, odd characters replaced by ``_``."""
    parts = [re.sub(r"[^A-Za-z0-9._-]+", "_", p) for p in re.split(r"[/\\]+", str(name))]
    parts = [p for p in parts if p not in ("", ".", "..")]
    return "/".join(parts) or "trajectory"


#: A file-type extension: a dot, a letter, up to 4 more letters or digits (``.png``, ``.JPEG``, ``.jp2``). A
#: numeric tail is not one: a bag frame's stamp (``image_raw@1700000000.000001000``) keeps its fraction.
_EXTENSION = re.compile(r"\.[A-Za-z][A-Za-z0-9]{0,4}$")
_VIDEO_FRAME = re.compile(r"^(.+)#(\d{6,})$")


def file_stem(source: str) -> str:
    """The last part of a frame's source (a path, or a bag frame's ``bag:topic@stamp``) without its file-type
    extension; a video frame's (``<video file>#000042``) is its index."""
    video = _VIDEO_FRAME.match(source)
    if video and is_video(video.group(1)):
        return video.group(2)
    return _EXTENSION.sub("", Path(source).name)


class FilesSink:
    """Writes the files of every frame into the run's folder (see the module docstring); :meth:`close` returns the
    entries of ``predictions.json`` about them.

    Args:
        tasks: the model's decoder tasks (:func:`cosemdepth.tasks.tasks_for`), whose writers write the files of each
            frame (None: those of the heads the stream has).
        class_names, palette: the class table of the pictures and colourised labels (empty / None without classes).
        options: :class:`FileOptions`.
    """

    def __init__(
        self,
        tasks: Sequence[DecoderTask] | None = None,
        *,
        class_names: Sequence[str] = (),
        palette=None,
        options: FileOptions = FileOptions(),
    ) -> None:
        self.options = options
        self.folder: Path | None = None
        self.names = tuple(class_names)
        self.palette = palette
        self.tasks = None if tasks is None else list(tasks)
        self.write_options = WriteOptions(invalid=options.invalid, palette=self.palette)
        self._writers: dict[str, TaskWriter] = {}
        self.frames: list[dict[str, Any]] = []
        self.trajectories: dict[str, dict[str, Any]] = {}
        self._stems: dict[str, set[str]] = {}
        self._videos: dict[str, VideoWriter] = {}
        self._pictures: dict[str, FlightPictures] = {}

    def open(self, folder: Path | None) -> None:
        if folder is None:
            raise ConfigError("predict's files need an output folder")
        self.folder = Path(folder)

    def __call__(self, batch: StreamBatch) -> None:
        for b in range(len(batch)):
            self.write_frame(batch, b)

    def _stem(self, entry: dict[str, Any], batch: StreamBatch, b: int) -> str:
        """The input image's file stem (made file-name safe), else the row number; unique within the trajectory."""
        row = int(batch.frame[b])
        src = batch.name[b]
        stem = re.sub(r"[^A-Za-z0-9._-]+", "_", file_stem(src)).strip(".") if src else ""
        stem = stem or f"{row:06d}"
        used = self._stems.setdefault(entry["folder"], set())
        if stem in used:
            stem = f"{stem}_{row:06d}"
        used.add(stem)
        return stem

    def write_frame(self, batch: StreamBatch, b: int) -> dict[str, Any]:
        traj = batch.trajectory[b]
        rel = safe_relpath(traj)
        if traj not in self.trajectories:
            if rel in {t["folder"] for t in self.trajectories.values()}:
                rel = f"{rel}_{len(self.trajectories)}"
            self.trajectories[traj] = {"name": traj, "folder": rel, "frames": 0}
        entry = self.trajectories[traj]
        rel = entry["folder"]
        stem = self._stem(entry, batch, b)
        base = self.folder / rel
        record = {"trajectory": traj, "frame": int(batch.frame[b]), "reset": bool(batch.reset[b])}
        files: dict[str, str] = {}
        maps = frame_maps(batch, b, title=f"frame {int(batch.frame[b])}", labels_ok=self._labels_ok)
        for t in self._tasks_of(batch):
            files.update(self._writer(t).write(self.folder, rel, stem, batch, b, record))
        files["side_by_side"] = f"{rel}/side_by_side/{stem}.png"
        pictures = self._pictures.get(traj)
        if pictures is None:
            pictures = self._pictures[traj] = FlightPictures(
                lambda path, image, traj=traj, base=base: self._emit(traj, base, path, image),
                class_names=self.names,
                palette=self.palette,
                depth_range=self.options.depth_range,
            )
        pictures.add(maps, self.folder / files["side_by_side"])
        record["files"] = files
        src = batch.name[b]
        if src is not None:
            record["source"] = src
        record.update(batch.meta[b])
        self.frames.append(record)
        entry["frames"] += 1
        return record

    def _tasks_of(self, batch: StreamBatch) -> list[DecoderTask]:
        """The tasks whose files are written: the model's (``tasks``), else those of every head the stream has."""
        if self.tasks is not None:
            return self.tasks
        return [t for t in TASKS.values() if t.head in batch.heads]

    def _writer(self, t: DecoderTask) -> TaskWriter:
        if t.name not in self._writers:
            self._writers[t.name] = t.writer(self.write_options) or _NO_FILES
        return self._writers[t.name]

    def summary(self) -> dict[str, Any]:
        """What the tasks' writers say about the whole run (e.g. ``frames_by_status``)."""
        return {k: v for w in self._writers.values() for k, v in w.summary().items()}

    def encodings(self) -> dict[str, Any]:
        """``predictions.json``'s ``encodings`` of the files."""
        tasks = {k: v for t in (self.tasks or ()) for k, v in t.encodings(self.write_options).items()}
        return {**tasks, "side_by_side": SIDE_BY_SIDE}

    def _labels_ok(self, gt: np.ndarray) -> bool:
        return self.palette is not None and gt.size > 0 and int(gt.max()) < len(self.palette) and int(gt.min()) >= 0

    def _emit(self, traj: str, base: Path, path: Path, image: np.ndarray) -> None:
        """A drawn side-by-side frame: its PNG and the trajectory's video."""
        save_png(path, image)
        if self.options.video:
            writer = self._videos.get(traj)
            if writer is None:
                writer = self._videos[traj] = VideoWriter(base / "video", fps=self.options.fps, fmt=self.options.video)
            writer.write(image)

    def close(self) -> dict[str, Any]:
        """Draw the frames still held back, finish the videos; ``predictions.json``'s entries about the files."""
        for traj, pictures in self._pictures.items():
            figure = pictures.finish()
            if figure is not None:
                self.trajectories[traj]["pictures"] = figure.metadata()
        for traj, writer in list(self._videos.items()):
            path = writer.close()
            self.trajectories[traj]["video"] = path.relative_to(self.folder).as_posix()
            del self._videos[traj]
        return {
            "frames_by_status": self.summary().get("frames_by_status"),
            "encodings": self.encodings(),
            "class_names": list(self.names),
            "palette": None if self.palette is None else np.asarray(self.palette).tolist(),
            "video": self.options.video,
            "fps": self.options.fps,
            "frames_written": len(self.frames),
            "trajectories": list(self.trajectories.values()),
            "frames": self.frames,
        }

    def abort(self) -> None:
        self._pictures.clear()
        for writer in self._videos.values():
            writer.abort()
        self._videos.clear()


register_sink("files", FilesSink)

__all__ = ["DEFAULT_INVALID", "FileOptions", "FilesSink", "INVALID_MODES", "MANIFEST", "file_stem", "safe_relpath"]
