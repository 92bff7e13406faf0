"""The declaration of a decoder's task: what it is trained on, how it is measured, how its outputs are written and
drawn (:class:`DecoderTask`), and the one registration of a decoder (:func:`register_decoder`: its module, task,
architectures and TF checkpoint names), the table of the tasks (:data:`TASKS`) and :func:`tasks_for`.

The loops of the package (the trainer's loss, validation, the evaluator, ``predict``) run over the tasks
of a model's decoders and name none of them, so a decoder registered with its task is trained, evaluated and written
like the built-in ones. A task is keyed by its decoder's registered name (:data:`cosemdepth.models.registry.DECODERS`).
The built-in decoders are folders of :mod:`cosemdepth.decoders`, a layer above this one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np
import torch

from ..checkpoints.tf_decoders import TfDecoder
from ..errors import ConfigError
from ..models import registry
from ..models.config import ModelConfig
from ..models.pyramid import PyramidDecoder
from ..models.registry import architecture_of

Tensor = torch.Tensor

#: ``MetricContext.protocol``: the windowed validation of training (design 7.3) or the test protocol (design 11.3).
VALIDATION, TEST = "validation", "test"


@dataclass
class Frames:
    """One batch of frames as the metrics see them: ``heads`` the model's outputs at the input size by head name
    (``StepOutput.heads``), ``gt`` the ground truth by key (:attr:`DecoderTask.gt_key`), ``[B, ...]`` each.

    The test protocol's batches (:class:`~cosemdepth.streaming.frames.StreamBatch`, which has the same
    attributes) also carry the stream: ``reset`` ``[B]``, ``status`` (per frame), ``valid`` (the depth's validity
    mask), ``trajectory`` names, ``rot``, ``trans``, ``intrinsics``; a validation batch has none of these."""

    heads: Mapping[str, Tensor]
    gt: Mapping[str, Tensor]
    reset: Optional[Tensor] = None
    status: Sequence[str] = ()
    valid: Optional[Tensor] = None
    trajectory: Sequence[str] = ()
    rot: Optional[Tensor] = None
    trans: Optional[Tensor] = None
    intrinsics: Optional[Tensor] = None


@dataclass(frozen=True)
class MetricContext:
    """What a task's metrics are computed for.

    Attributes:
        protocol: :data:`VALIDATION` (training's windows: the last frame of each) or :data:`TEST` (streamed
            trajectories, ``cosemdepth evaluate``).
        model: the model's config.
        dataset_name: the dataset's registered name ("" when unknown).
        ground_truth: the ground-truth keys the dataset has (of every registered task, not only the model's).
        exclude_resets: the test protocol leaves the frames that start a trajectory out (``include`` says which).
    """

    protocol: str
    model: ModelConfig
    dataset_name: str = ""
    ground_truth: frozenset = frozenset()
    exclude_resets: bool = True


class TaskMetrics:
    """A metric accumulator: :meth:`update` with every batch, :meth:`compute` the named metrics at the end (the keys
    of ``metrics.json``'s ``metrics`` and of a validation's dict), :meth:`report` further results of the test
    protocol (``confusion_matrix``, ``class_names``, ``protocol`` entries)."""

    def update(self, frames: Frames, include: Optional[Tensor] = None) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def compute(self) -> dict[str, Any]:  # pragma: no cover - interface
        raise NotImplementedError

    def report(self) -> dict[str, Any]:
        return {}


@dataclass
class WriteOptions:
    """What ``predict`` was asked for, for the tasks' writers: ``invalid`` (``"keep"`` or ``"nan"``: the depth's
    ``.npy`` where the mask is 0), ``palette`` (the class colours, None without classes)."""

    invalid: str = "keep"
    palette: Optional[np.ndarray] = None


class TaskWriter:
    """Writes one task's files of every frame of ``predict`` (see :meth:`DecoderTask.writer`)."""

    def write(self, folder: Path, rel: str, stem: str, frames, b: int, record: dict[str, Any]) -> dict[str, str]:
        """Write frame ``b`` of ``frames`` (a StreamBatch) under ``folder / rel``; return ``{output: relative
        path}`` (``predictions.json``'s ``files``); may add entries to the frame's ``record``."""
        raise NotImplementedError  # pragma: no cover - interface

    def summary(self) -> dict[str, Any]:
        """Entries of ``predictions.json`` about the whole run (after the last frame)."""
        return {}


class DecoderTask:
    """What a decoder learns and how it is measured, written and drawn. Subclass it, set the class attributes and
    override the methods the decoder needs; :func:`register_decoder` makes the decoder and its task known.

    Class attributes:
        name: the decoder's registered name (its weights are ``<name>_decoder.*``).
        decoder: its :class:`~cosemdepth.models.pyramid.PyramidDecoder` subclass.
        gt_key: the key of its ground truth in dataset items and batches (``ground_truth`` may derive it instead).
        predicts: what it predicts, in words, for messages ("depth", "class labels").
    """

    name: str = ""
    decoder: type = PyramidDecoder
    gt_key: str = ""
    predicts: str = ""

    # ------------------------------------------------------------------ outputs
    @property
    def head(self) -> str:
        """Its output at the input size (``StepOutput.heads`` key, the ONNX output name)."""
        return self.decoder.head

    @property
    def outputs(self) -> tuple[str, ...]:
        """Its output names: the head, then the per-level maps (``StepOutput.levels`` / ``SequenceOutput`` keys)."""
        return (self.head, *[k for k in self.decoder.maps if k != self.head])

    # ------------------------------------------------------------------ ground truth
    def ground_truth(self, batch: Mapping[str, Any]) -> Optional[Tensor]:
        """Its ground truth in a dataset item or a batch (``[..., C, H, W]`` / ``[..., H, W]``), None without."""
        return batch.get(self.gt_key)

    def dataset_has_ground_truth(self, dataset, first_item: Callable[[], Mapping[str, Any]]) -> bool:
        """Whether ``dataset`` carries its ground truth: from its trajectories when they name the key, else from its
        first item (``first_item()``)."""
        trajs = getattr(dataset, "trajectories", None)
        if trajs and hasattr(trajs[0], self.gt_key):
            return getattr(trajs[0], self.gt_key) is not None
        return self.ground_truth(first_item()) is not None

    def check_dataset(self, model: ModelConfig, dataset_name: str) -> None:
        """Raise :class:`ConfigError` when the model's outputs cannot be compared with this dataset's ground truth."""

    # ------------------------------------------------------------------ training
    def loss(self, out, batch: Mapping[str, Any], train) -> Tensor:
        """Its unweighted loss (float32 scalar) on a :class:`~cosemdepth.models.outputs.SequenceOutput` ``out`` and a
        training batch (``[B, T, ...]``), with the options of the run's :class:`~cosemdepth.training.config.TrainConfig`."""
        raise NotImplementedError(f"the {self.name} decoder declares no loss")

    def loss_weight(self, train) -> float:
        """Its weight in the total loss (``total = sum of weight * loss`` over the model's decoders, in order)."""
        return 1.0

    # ------------------------------------------------------------------ metrics
    def metrics(self, context: MetricContext) -> TaskMetrics:
        """A fresh accumulator of its metrics."""
        raise NotImplementedError(f"the {self.name} decoder declares no metrics")

    def protocol_info(self, metrics: Optional[TaskMetrics]) -> dict[str, Any]:
        """Entries of the test protocol's ``protocol`` record (``metrics`` is None when it was not evaluated)."""
        return {}

    def model_info(self, model: ModelConfig) -> dict[str, Any]:
        """Entries of the evaluation's ``model`` record."""
        return {}

    def report_lines(self, metrics: Mapping[str, Any]) -> list[str]:
        """Lines of the evaluation's Markdown report about its metrics (the built-in decoders' are in the paper's
        tables)."""
        return []

    # ------------------------------------------------------------------ pictures and files
    def example(self, gt: Optional[Tensor], pred: Tensor, model: ModelConfig) -> dict[str, Tensor]:
        """One frame's ground truth (``[C, H, W]`` / ``[H, W]``, or None) and output (``[C, H, W]``, the head) as the
        tensors of a training picture (CPU)."""
        return {}

    def strip_panels(self, example: Mapping[str, Tensor], model: ModelConfig) -> list[np.ndarray]:
        """The ``[H, W, 3]`` uint8 panels of the training pictures (TensorBoard) from :meth:`example`'s tensors."""
        return []

    def writer(self, options: WriteOptions) -> Optional[TaskWriter]:
        """The writer of its ``predict`` files (None: it writes none)."""
        return None

    def encodings(self, options: WriteOptions) -> dict[str, Any]:
        """``predictions.json``'s ``encodings`` of its files."""
        return {}


#: Decoder name -> its task, in registration order (the registry's view, :data:`cosemdepth.models.registry.TASKS`).
TASKS = registry.TASKS


def register_decoder(
    task: DecoderTask,
    architectures: Mapping[str, Any] | None = None,
    tf: Optional[TfDecoder] = None,
) -> DecoderTask:
    """The one registration of a decoder: its module (``task.decoder``, as ``task.name``), its task, the
    ``architectures`` that use it (name -> decoder names in order, or ``(decoder names, {config field: value})`` for
    an architecture that fixes config fields; an architecture is registered with the last of its decoders) and its
    names in the official TF checkpoints (``tf``; None: they do not hold it). Returns ``task``."""
    if not isinstance(task, DecoderTask) or not task.name or not task.gt_key:
        raise TypeError(f"register_decoder needs a DecoderTask with a name and a gt_key, got {task!r}")
    if not (isinstance(task.decoder, type) and issubclass(task.decoder, PyramidDecoder)):
        raise TypeError(f"decoder {task.name!r} must be a PyramidDecoder subclass, got {task.decoder!r}")
    if tf is not None and not isinstance(tf, TfDecoder):
        raise TypeError(f"decoder {task.name!r}: tf must be a TfDecoder, got {tf!r}")
    registry.register(task.name, task.decoder, task=task, tf=tf, architectures=architectures)
    return task


def task(name: str) -> DecoderTask:
    """The task of decoder ``name``; :class:`ConfigError` when the decoder has none."""
    found = TASKS.get(name)
    if found is None:
        raise ConfigError(
            f"the {name!r} decoder has no task (loss, metrics, outputs): register it with "
            f"cosemdepth.tasks.register_decoder; decoders with one: {sorted(TASKS)}"
        )
    return found


def tasks_for(config: ModelConfig) -> list[DecoderTask]:
    """The tasks of ``config``'s decoders, in the architecture's order."""
    return [task(name) for name in config.decoders]


def class_count(config: ModelConfig) -> Optional[int]:
    """The classes ``config``'s decoders predict (the ``num_classes`` a task states in :meth:`DecoderTask.model_info`),
    None when none predicts classes: the palette and class names of the pictures and files."""
    return next(
        (info["num_classes"] for t in tasks_for(config) if (info := t.model_info(config)).get("num_classes")), None
    )


def float32_levels(levels: Sequence[Tensor]) -> list[Tensor]:
    """Per-level predictions in float32 (unchanged if they already are): losses are computed in float32 whatever the
    forward pass's precision (``train.bf16``)."""
    return [p if p.dtype == torch.float32 else p.float() for p in levels]


__all__ = [
    "DecoderTask",
    "Frames",
    "MetricContext",
    "TASKS",
    "TEST",
    "TaskMetrics",
    "TaskWriter",
    "VALIDATION",
    "WriteOptions",
    "architecture_of",
    "class_count",
    "float32_levels",
    "register_decoder",
    "task",
    "tasks_for",
]
