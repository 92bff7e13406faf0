"""The folders that commands read as input, recognised by their own markers, whoever wrote them.

A dataset, its split folder, a model, a training run or checkpoint, a TensorFlow checkpoint, a flight or a ROS 2 bag
is an input of some command, so it is never another command's output (:func:`cosemdepth.output_safety.outdir.check_output_dir`
refuses to replace it, write into it or delete it). Each kind is known by files or folders its readers require
(``synthair.json``, ``ENV/CLIMATE/sensor_records.hdf5``, ``config.json`` + ``model.safetensors``...), not by a
marker of ours: a dataset copied from elsewhere is as much an input as one ``cosemdepth synth`` wrote.

A marker is a glob relative to the folder (``*`` within one name, a trailing ``/`` for a folder); a kind has one or
more alternatives, each a set of markers that must all be present. Listing a folder is bounded
(:data:`LISTING_BUDGET` entries per look), so that looking at a crowded folder stays cheap.

The names below belong to the readers and writers of each format (named beside each kind);
``tests/output_safety/test_input_kinds.py`` checks that they match those modules' constants and that the folders the real
writers produce are recognised. A new reader adds its layout with :func:`register_input_kind`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from fnmatch import fnmatchcase
from pathlib import Path

#: Most directory entries one :func:`identify` call lists (a marker beyond them is not seen).
LISTING_BUDGET = 20_000


@dataclass(frozen=True)
class InputKind:
    """A kind of folder that commands read as input.

    Attributes:
        name: how messages call it ("a SynthAir dataset").
        markers: alternatives, each a tuple of globs that must all match (see the module docstring).
        writers: the commands whose own output a folder of this kind is (``synth`` resumes a SynthAir dataset,
            ``splits`` replaces its split folder, ``convert`` writes a model folder, ``train`` resumes a run); for
            them the folder itself is an output under the usual rules, for every other command it is never one.
        open_inside: ``(sub-folder, command)`` pairs: where inside such a folder a command may write (a dataset
            root's ``splits/``, written by ``cosemdepth splits``).
    """

    name: str
    markers: tuple[tuple[str, ...], ...]
    writers: tuple[str, ...] = ()
    open_inside: tuple[tuple[str, str], ...] = ()


_SPLITS_INSIDE = (("splits", "splits"),)  # the registry's split_dir of SynthAir and TopAir roots

#: Every kind, most specific first (the first match names a folder).
INPUT_KINDS: list[InputKind] = [
    # synthair.writer.METADATA; its split CSVs in SPLITS_DIR
    InputKind("a SynthAir dataset", (("synthair.json",),), writers=("synth",), open_inside=_SPLITS_INSIDE),
    # training.rundir: CONFIG_NAME with EVENTS_NAME, CHECKPOINTS_NAME or BEST_NAME
    InputKind(
        "a training run folder",
        (("config.yaml", "events.jsonl"), ("config.yaml", "checkpoints/"), ("config.yaml", "best/")),
        writers=("train",),
    ),
    # training.checkpoint: checkpoint_name() folders holding output_safety.manifest.MANIFEST_FILE
    InputKind("a folder of training checkpoints", (("ckpt-*/manifest.json",),)),
    InputKind("a training checkpoint", (("manifest.json", "model.safetensors"),)),
    # checkpoints.model_io: CONFIG_FILE + WEIGHTS_FILE
    InputKind("a model folder", (("config.json", "model.safetensors"),), writers=("convert",)),
    # data.csvsplits: <split>_data/ for the splits of data.midair.splits.SPLITS
    InputKind("a split folder", (("train_data/",), ("val_data/",), ("test_data/",)), writers=("splits",)),
    # data.midair.format.SENSOR_RECORDS, per ENV/CLIMATE
    InputKind("a Mid-Air-format dataset", (("*/*/sensor_records.hdf5",),), open_inside=_SPLITS_INSIDE),
    InputKind("part of a Mid-Air-format dataset", (("sensor_records.hdf5",), ("*/sensor_records.hdf5",))),
    # data.topair_splits.REC_FILE per environment; data.topair's images/, depth/, seg_id/
    InputKind("a TopAir dataset", (("*/airsim_rec.txt",), ("*/images/", "*/seg_id/")), open_inside=_SPLITS_INSIDE),
    InputKind("a TopAir environment folder", (("airsim_rec.txt",), ("images/", "depth/", "seg_id/"))),
    # data.aeroscapes: JPEGImages/ and SegmentationClass/
    InputKind("an Aeroscapes dataset", (("JPEGImages/", "SegmentationClass/"),)),
    # checkpoints.tf_checkpoint: P.index + P.data-SSSSS-of-NNNNN
    InputKind("a TensorFlow checkpoint folder", (("*.index", "*.data-*-of-*"),)),
    # data.flight.DEFAULT_POSE_FILES beside data.flight.IMAGE_EXTENSIONS (any case) or an images/ folder
    InputKind(
        "a flight (images and a pose file)",
        tuple(
            (pose, images)
            for pose in ("poses.txt", "poses.tum", "poses.csv", "groundtruth.txt")
            for images in ("images/", "*.[jJ][pP][gG]", "*.[jJ][pP][eE][gG]", "*.[pP][nN][gG]")
        ),
    ),
    # robotics.rosbag: ROS 2 bag folders (rosbags' metadata.yaml + sqlite3 or MCAP storage)
    InputKind("a ROS 2 bag", (("metadata.yaml", "*.mcap"), ("metadata.yaml", "*.db3"))),
]


def register_input_kind(kind: InputKind) -> InputKind:
    """Add ``kind`` (a new reader's layout) to :data:`INPUT_KINDS`, before the generic ones; a kind of the same
    name is replaced."""
    INPUT_KINDS[:] = [k for k in INPUT_KINDS if k.name != kind.name]
    INPUT_KINDS.insert(0, kind)
    return kind


class _Listing:
    """Directory listings for one look at a folder, cached, within :data:`LISTING_BUDGET` entries."""

    def __init__(self, budget: int = LISTING_BUDGET):
        self.budget = budget
        self.cache: dict[Path, list[tuple[str, bool]]] = {}

    def entries(self, folder: Path) -> list[tuple[str, bool]]:
        """``(name, is a folder)`` of the entries of ``folder`` (symlinks followed); [] when unreadable."""
        if folder in self.cache:
            return self.cache[folder]
        out: list[tuple[str, bool]] = []
        try:
            with os.scandir(folder) as it:
                for entry in it:
                    if self.budget <= 0:
                        break
                    self.budget -= 1
                    try:
                        out.append((entry.name, entry.is_dir()))
                    except OSError:
                        continue
        except OSError:
            pass
        self.cache[folder] = out
        return out

    def match(self, folder: Path, parts: tuple[str, ...], via: str | None = None) -> bool:
        """Whether the glob ``parts`` (split at ``/``; the last may end with ``/``) matches under ``folder``; with
        ``via``, a pattern for a sub-folder of ``folder`` only matches the sub-folder ``via``."""
        head, rest = parts[0], parts[1:]
        want_dir = bool(rest) or head.endswith("/")
        head = head.rstrip("/")
        if not any(c in head for c in "*?["):
            p = folder / head
            if rest:
                return (via is None or via == head) and p.is_dir() and self.match(p, rest)
            return p.is_dir() if want_dir else p.is_file()
        if rest and via is not None:
            return fnmatchcase(via, head) and (folder / via).is_dir() and self.match(folder / via, rest)
        for name, is_dir in self.entries(folder):
            if fnmatchcase(name, head) and is_dir == want_dir:
                if not rest or self.match(folder / name, rest):
                    return True
        return False


def _split(marker: str) -> tuple[str, ...]:
    parts = marker.split("/")
    if marker.endswith("/"):  # "train_data/" -> ("train_data/",)
        parts = parts[:-1]
        parts[-1] += "/"
    return tuple(parts)


def identify(folder: str | os.PathLike, via: str | None = None) -> tuple[InputKind, str] | None:
    """``(kind, evidence)`` of the input folder ``folder`` (evidence: the markers found, e.g. ``"config.json +
    model.safetensors"``), or None if it is none of :data:`INPUT_KINDS` (or not a folder).

    ``via``: look at ``folder`` as an ancestor of a path through its existing sub-folder ``via``; markers in
    sub-folders (``*/*/sensor_records.hdf5``) are then only looked for in ``via``, so that a folder holding one
    dataset part among other things (``/tmp`` beside a loose Mid-Air climate folder) is not taken for a dataset
    root by every path under it; a path into that part still is (through the part's own markers)."""
    folder = Path(folder)
    if not folder.is_dir():
        return None
    listing = _Listing()
    for kind in INPUT_KINDS:
        for alternative in kind.markers:
            if all(listing.match(folder, _split(m), via) for m in alternative):
                return kind, " + ".join(alternative)
    return None


__all__ = ["INPUT_KINDS", "InputKind", "LISTING_BUDGET", "identify", "register_input_kind"]
