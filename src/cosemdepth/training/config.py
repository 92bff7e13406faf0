"""The run config: what a training run trains (``model``, ``data``, ``train``, ``debug``), and its YAML files.

Three layers, each with its defaults in one place: the model (:class:`~cosemdepth.models.config.ModelConfig`, beside
the models), the data and the training recipe (:class:`DataConfig`, :class:`TrainConfig`: the paper's Mid-Air
recipe, design sections 9.1 and 14.1, here), and the run that holds them (:class:`RunConfig`). This module sits
above ``data`` and ``evaluation``, whose tables it checks names against (the dataset table, the augmentation
presets, the best-checkpoint metrics).

A config file has up to four sections, ``model``, ``data``, ``train`` and ``debug`` (the fields of
:class:`RunConfig`); a missing key takes its default. :func:`resolve_config` layers defaults < a file < explicit
values < ``KEY=VALUE`` overrides with a dotted key, list items by index (``train.lr=3e-4``,
``data.train.0.root=data/midair``, ``data.train.1.weight=0.5``); an override's value is read as YAML (``true``,
``null``, ``[1, 2]``...). Every value then goes through the one typed coercer (:mod:`cosemdepth.coerce`), so
``"3e-4"`` is a float and a bad value is one line naming its key. :func:`dump_config` writes the YAML back.

The shipped configs live in the package (``cosemdepth/configs/*.yaml``) and can be named without a path
(``--config midair``).
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import math
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Literal, Mapping, Optional, Union

import yaml

from ..coerce import from_mapping
from ..data.augment import resolve_augment
from ..data.registry import DATASETS
from ..defaults import DEFAULT_DEVICE
from ..errors import ConfigError
from ..measures.metrics import selection_rule
from ..models.config import MIDAIR_IMAGE_SIZE, ModelConfig
from ..workers import check_workers

#: ``train.optimizer``: Keras 2's Adam update (the original's) or ``torch.optim.Adam``.
Optimizer = Literal["adam_keras", "adam_torch"]


@dataclass(frozen=True)
class DatasetSource:
    """One dataset of a run: which reader, where, and its weight in a mix.

    ``name`` is a dataset of the dataset table (:mod:`cosemdepth.data.registry`); ``options`` are passed on to
    :func:`cosemdepth.data.open_dataset` as keyword arguments (e.g. ``labels``, ``modalities``; for ``"toy"``:
    ``length``).
    """

    name: str = "midair"
    root: Optional[str] = None
    split_dir: Optional[str] = None
    weight: float = 1.0
    options: dict = field(default_factory=dict)

    def check(self, key: str) -> None:
        """Raise :class:`ConfigError` naming ``key`` (e.g. ``data.train[0]``) if a value is invalid. (A missing
        ``root`` is reported when the dataset is opened, so that a config can be written before the data exists.)"""
        if self.name not in DATASETS:
            raise ConfigError(f"{key}.name: unknown dataset {self.name!r}; choose one of {list(DATASETS)}")
        if not (self.weight >= 0 and math.isfinite(self.weight)):
            raise ConfigError(f"{key}.weight must be a finite number >= 0, got {self.weight!r}")


def key_path(key: str) -> str:
    """``data.train[1]`` -> ``data.train.1`` (the ``--set`` spelling of a key)."""
    return key.replace("[", ".").replace("]", "")


#: The ``data.train_decode`` choices.
TRAIN_DECODES = ("exact", "reduced")


@dataclass(frozen=True)
class DataConfig:
    """What a run trains and validates on (design 9.2, 7.3).

    ``train`` holds one dataset or a weighted mix of several (sampling weights ``weight``). ``val`` defaults to the
    first training dataset's ``val_split``; ``validate: false`` turns validation off.
    """

    train: tuple[DatasetSource, ...] = (DatasetSource(),)
    val: Optional[DatasetSource] = None
    train_split: str = "train"
    val_split: str = "val"
    validate: bool = True
    #: Network input size, [H, W] (a single side, ``size: 384`` or ``(384,)``, is square); the paper uses 384.
    size: tuple[int, ...] = (MIDAIR_IMAGE_SIZE, MIDAIR_IMAGE_SIZE)
    seq_len: int = 4
    db_seq_len: int = 4
    #: Window length of the validation (design 7.3): windows of 4, only the last frame of each counts.
    val_seq_len: int = 4
    #: The augmentations of design 9.3 (True), none (False) or a preset name of the data package.
    augment: Union[bool, str] = True
    #: Items per epoch of a mix (default: the sum of the datasets' lengths).
    mix_length: Optional[int] = None
    num_workers: int = 2
    #: JPEG decoding of the training datasets, one of :data:`TRAIN_DECODES` (validation always decodes exactly):
    #: ``"reduced"`` (the default) decodes at the smallest libjpeg DCT scale M/8 at least ``size`` (a 1024 px frame
    #: at 3/8 for 384) and BL2 resizes the rest: a fraction of the decoding work, a low-pass picture instead of the
    #: original's (identical when no scale below 8/8 is large enough, e.g. 384 px sources at 384); ``"exact"``
    #: decodes at full size and resizes with BL2, the original's pixels. Readers of the Mid-Air format; others
    #: decode exactly.
    train_decode: str = "reduced"

    def __post_init__(self) -> None:
        if isinstance(self.size, int) and not isinstance(self.size, bool):
            object.__setattr__(self, "size", (self.size,))
        if isinstance(self.size, tuple) and len(self.size) == 1:
            object.__setattr__(self, "size", self.size * 2)  # a square size
        if not self.train:
            raise ConfigError("data.train must list at least one dataset")
        for i, src in enumerate(self.train):
            src.check(f"data.train[{i}]")
        if len(self.train) > 1 and sum(s.weight for s in self.train) <= 0:
            raise ConfigError("data.train: the mix weights must not all be zero")
        if self.val is not None:
            self.val.check("data.val")
        if len(self.size) != 2 or any(not isinstance(v, int) or v < 8 for v in self.size):
            raise ConfigError(f"data.size must be an integer >= 8 or [H, W] of such integers, got {list(self.size)}")
        _check_augment(self.augment)
        _positive_int("data.seq_len", self.seq_len, minimum=2)
        _positive_int(
            "data.db_seq_len",
            self.db_seq_len,
            minimum=self.seq_len,
            why=f" (a chunk must hold a window of data.seq_len = {self.seq_len})",
        )
        _positive_int("data.val_seq_len", self.val_seq_len)
        check_workers(self.num_workers, "data.num_workers")
        if self.train_decode not in TRAIN_DECODES:
            raise ConfigError(
                f"data.train_decode must be one of {', '.join(map(repr, TRAIN_DECODES))}, got {self.train_decode!r}"
            )
        if self.mix_length is not None:
            _positive_int("data.mix_length", self.mix_length)

    @property
    def val_source(self) -> Optional[DatasetSource]:
        """The validation dataset (``val`` or the first training dataset), or None if validation is off."""
        if not self.validate:
            return None
        return self.val if self.val is not None else self.train[0]


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation, checkpointing, validation and logging of a run (design 9.1, 9.4, 9.5)."""

    epochs: int = 60
    #: Stop after this many training steps in all (0: no limit besides ``epochs``).
    max_steps: int = 0
    batch_size: int = 3
    #: Adam as Keras' defaults in the original: lr 1e-4 constant, betas 0.9/0.999, eps 1e-7, no weight decay.
    #: ``optimizer``: "adam_keras" (Keras 2's update, epsilon added to sqrt(v) before the bias correction: the
    #: original's) or "adam_torch" (torch.optim.Adam); see :mod:`cosemdepth.training.optim`.
    optimizer: Optimizer = "adam_keras"
    lr: float = 1e-4
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-7
    weight_decay: float = 0.0
    #: Multiply the learning rate by ``lr_decay`` at each of these epochs (0-based; empty: constant, the paper).
    lr_decay_epochs: tuple[int, ...] = ()
    lr_decay: float = 0.1
    #: Clip the gradient norm to this value (0: no clipping, the paper).
    grad_clip: float = 0.0
    #: Weight of the semantic loss in the total loss (design 8.3).
    semantic_weight: float = 0.1
    #: One weight per class for the semantic loss (a deviation from the paper; empty: every pixel alike, the
    #: paper). Rare classes weighted up are learnt at all in short trainings; ``scripts/class_weights.py`` computes
    #: median-frequency weights from a training set's labels.
    semantic_class_weights: tuple[float, ...] = ()
    #: Semantic loss on log-softmax of logits instead of Keras' clipped probabilities (design 8.2).
    semantic_from_logits: bool = False
    #: Start a new run from these weights instead of a random initialisation (fine-tuning, as the original's
    #: ``finetune`` mode): one of our model folders, a run's checkpoint or ``best`` folder, or an official
    #: TensorFlow checkpoint. They must fit ``model`` (same architecture, levels, classes). Only the weights are
    #: taken (a fresh optimizer, step 0); a run that resumes from its own checkpoints ignores this key.
    init_weights: str = ""
    #: Start a new run from the weights of a model of another config (a model folder, a run's checkpoint or
    #: ``best``): tensors of the same shape copied, the new input channels of a grown layer (e.g. the semantic
    #: refiners' ``semantic_sncv`` and ``semantic_time`` inputs) zero, so that the run starts computing exactly the
    #: source model's outputs; tensors the source lacks keep their initialisation (:mod:`cosemdepth.training.init`).
    #: Only ``model.arch``, ``semantic_sncv`` and ``semantic_time`` may differ. Exclusive with ``init_weights``;
    #: a resumed run ignores it.
    init_from: str = ""
    seed: int = 42
    #: "auto" (CUDA when available), "cpu", "cuda", "cuda:1"...
    device: str = DEFAULT_DEVICE
    #: bfloat16 autocast of the forward pass on the CPU and CUDA (float32 weights, optimizer and loss).
    bf16: bool = False
    #: Convolution weights and activations in channels-last memory format: oneDNN's CPU convolutions then take
    #: them without a layout reorder per call (forward and backward); the same numbers up to float rounding.
    channels_last: bool = True
    #: torch CPU threads (0: torch's default).
    num_threads: int = 0
    #: On the CPU, keep freed host memory in the process for reuse (glibc's allocator; see
    #: :func:`cosemdepth.devices.retain_freed_host_memory`): the step's activations are not faulted in afresh each step.
    retain_host_memory: bool = True
    #: Write a checkpoint every this many steps (0: only at epoch ends); one is always written at each epoch end.
    checkpoint_every: int = 1000
    #: Keep the newest K checkpoints (the original keeps 5).
    keep_last: int = 5
    #: Validate every this many epochs (0: never at epoch ends) and/or every this many steps (0: never).
    validate_every_epochs: int = 1
    validate_every_steps: int = 0
    #: Validate on at most this many batches (0: the whole validation set).
    val_max_batches: int = 0
    val_batch_size: int = 4
    #: Best-checkpoint rule: "paper" (design 9.5), or one metric: "rmse", "miou", "abs_rel:min", ...
    best: str = "paper"
    #: Non-finite guard: after this many non-finite steps in a row, roll back to the last good checkpoint.
    nonfinite_patience: int = 3
    #: Give up (error) after this many rollbacks without a good checkpoint in between.
    max_rollbacks: int = 5
    #: Log losses every this many steps (events log, TensorBoard) and images every ``image_every`` steps (0: never).
    log_every: int = 50
    image_every: int = 1000
    #: Show a progress bar (tqdm) on the console.
    progress: bool = True

    def __post_init__(self) -> None:
        _positive_int("train.epochs", self.epochs)
        _positive_int("train.max_steps", self.max_steps, minimum=0)
        _positive_int("train.batch_size", self.batch_size)
        if self.optimizer not in typing.get_args(Optimizer):
            raise ConfigError(
                f"train.optimizer must be {' or '.join(map(repr, typing.get_args(Optimizer)))}, got {self.optimizer!r}"
            )
        _positive_number("train.lr", self.lr)
        if len(self.betas) != 2 or not all(0.0 <= b < 1.0 for b in self.betas):
            raise ConfigError(f"train.betas must be two numbers in [0, 1), got {list(self.betas)}")
        _positive_number("train.eps", self.eps)
        _positive_number("train.weight_decay", self.weight_decay, allow_zero=True)
        if any(e < 0 for e in self.lr_decay_epochs):
            raise ConfigError(f"train.lr_decay_epochs must be epochs >= 0, got {list(self.lr_decay_epochs)}")
        _positive_number("train.lr_decay", self.lr_decay)
        _positive_number("train.grad_clip", self.grad_clip, allow_zero=True)
        _positive_number("train.semantic_weight", self.semantic_weight, allow_zero=True)
        for i, w in enumerate(self.semantic_class_weights):
            _positive_number(f"train.semantic_class_weights[{i}]", w, allow_zero=True)
        if self.semantic_class_weights and not any(self.semantic_class_weights):
            raise ConfigError("train.semantic_class_weights: at least one weight must be > 0, got all zeros")
        if self.init_weights and self.init_from:
            raise ConfigError(
                "train.init_weights and train.init_from: give one of them (init_from also takes "
                "weights of the run's own model)"
            )
        if not self.device or not (self.device in ("auto", "cpu", "mps") or self.device.startswith("cuda")):
            raise ConfigError(f"train.device must be 'auto', 'cpu', 'cuda', 'cuda:N' or 'mps', got {self.device!r}")
        _positive_int("train.num_threads", self.num_threads, minimum=0)
        _positive_int("train.checkpoint_every", self.checkpoint_every, minimum=0)
        _positive_int("train.keep_last", self.keep_last)
        _positive_int("train.validate_every_epochs", self.validate_every_epochs, minimum=0)
        _positive_int("train.validate_every_steps", self.validate_every_steps, minimum=0)
        _positive_int("train.val_max_batches", self.val_max_batches, minimum=0)
        _positive_int("train.val_batch_size", self.val_batch_size)
        _positive_int("train.nonfinite_patience", self.nonfinite_patience)
        _positive_int("train.max_rollbacks", self.max_rollbacks, minimum=0)
        _positive_int("train.log_every", self.log_every)
        _positive_int("train.image_every", self.image_every, minimum=0)
        try:
            selection_rule(self.best)
        except ConfigError as e:
            raise ConfigError(f"train.best: {e}") from None


@dataclass(frozen=True)
class DebugConfig:
    """Test hooks. ``inject_nonfinite_steps``: make the loss of these training steps (1-based) NaN, once each."""

    inject_nonfinite_steps: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if any(s < 1 for s in self.inject_nonfinite_steps):
            raise ConfigError(
                f"debug.inject_nonfinite_steps must be step numbers >= 1, got {list(self.inject_nonfinite_steps)}"
            )


@dataclass(frozen=True)
class RunConfig:
    """Everything a training run needs: ``model``, ``data``, ``train``, ``debug`` (the sections of the YAML file)."""

    model: ModelConfig = field(default_factory=ModelConfig)
    data: DataConfig = field(default_factory=DataConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    debug: DebugConfig = field(default_factory=DebugConfig)

    def __post_init__(self) -> None:
        n = len(self.train.semantic_class_weights)
        if n and not self.model.has_semantic:
            raise ConfigError(f"train.semantic_class_weights: the {self.model.arch} model has no semantic decoder")
        if n and n != self.model.num_classes:
            raise ConfigError(
                f"train.semantic_class_weights must hold one weight per class: {n} given for "
                f"model.num_classes = {self.model.num_classes}"
            )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "RunConfig":
        """Build from a (partial) nested dict; missing keys take the defaults. Values are converted to the field
        types (so ``"3e-4"`` is a float); unknown keys and bad values raise :class:`ConfigError` naming the key."""
        return from_mapping(cls, d, "")


def _check_augment(augment: Any) -> None:
    """``data.augment`` through the data package's own reading of it (the presets live there), so that a config that
    prints (``train --print-config``) is one that runs."""
    try:
        resolve_augment(augment)
    except ConfigError as e:
        text = str(e)
        raise ConfigError(f"data.{text}" if text.startswith("augment ") else f"data.augment: {text}") from None


def _positive_int(key: str, value: Any, minimum: int = 1, why: str = "") -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
        raise ConfigError(f"{key} must be an integer >= {minimum}{why}, got {value!r}")


def _positive_number(key: str, value: Any, allow_zero: bool = False) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    ok = ok and (value >= 0 if allow_zero else value > 0)
    if not ok:
        raise ConfigError(f"{key} must be a finite number {'>= 0' if allow_zero else '> 0'}, got {value!r}")


# ---------------------------------------------------------------------------------------------------------------
# Config files: YAML in, overrides on top, YAML out
# ---------------------------------------------------------------------------------------------------------------


def builtin_configs() -> list[str]:
    """Names of the configs shipped with the package (``midair``, ``synthair-small``...)."""
    folder = importlib.resources.files("cosemdepth") / "configs"
    if not folder.is_dir():
        return []
    return sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def _resolve_path(config: str | Path) -> tuple[str, str]:
    """``(text, origin)`` of a config given as a path or as the name of a shipped config."""
    p = Path(config)
    if p.is_file():
        try:
            return p.read_text(encoding="utf-8"), str(p)
        except (OSError, UnicodeDecodeError) as e:
            raise ConfigError(f"{p}: cannot read the config file ({e})") from e
    if p.exists():
        raise ConfigError(f"{p}: the config must be a YAML file, this is a folder")
    name = str(config)
    if "/" not in name and not name.endswith((".yaml", ".yml")):
        res = importlib.resources.files("cosemdepth") / "configs" / f"{name}.yaml"
        if res.is_file():
            return res.read_text(encoding="utf-8"), f"cosemdepth/configs/{name}.yaml"
    shipped = builtin_configs()
    raise ConfigError(f"{config}: config file not found" + (f" (shipped configs: {shipped})" if shipped else ""))


def load_config_dict(config: str | Path) -> dict[str, Any]:
    """The raw nested dict of a YAML config file (a path, or the name of a shipped config)."""
    text, origin = _resolve_path(config)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{origin}: not valid YAML: {e}") from e
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(
            f"{origin}: the top level must be a mapping with sections model/data/train/debug, got {type(data).__name__}"
        )
    return data


def apply_override(d: dict[str, Any], override: str) -> None:
    """Apply one ``KEY=VALUE`` override to the nested dict ``d`` in place (see the module docstring)."""
    key, sep, raw = override.partition("=")
    key = key.strip()
    if not sep or not key:
        raise ConfigError(f"override {override!r}: expected KEY=VALUE, e.g. train.lr=3e-4")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    set_key(d, key, value)


def set_key(d: dict[str, Any], key: str, value: Any) -> None:
    """Set the dotted ``key`` (integer parts index lists) of the nested dict ``d`` to ``value``."""
    parts = key.split(".")
    node: Any = d
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        where = ".".join(parts[:i]) or "the config"
        if isinstance(node, list):
            if not part.isdigit():
                raise ConfigError(f"override {key!r}: {where} is a list; index it with a number, e.g. {where}.0")
            idx = int(part)
            if idx > len(node):
                raise ConfigError(f"override {key!r}: {where} has {len(node)} item(s); the next index is {len(node)}")
            if idx == len(node):
                node.append({})
            if last:
                node[idx] = value
            else:
                if not isinstance(node[idx], (dict, list)):
                    node[idx] = {}
                node = node[idx]
            continue
        if not isinstance(node, dict):
            raise ConfigError(f"override {key!r}: {where} is a value, not a section")
        if last:
            node[part] = value
        else:
            nxt = parts[i + 1]
            if part not in node or not isinstance(node[part], (dict, list)):
                node[part] = [] if nxt.isdigit() else {}
            node = node[part]


def resolve_config(
    config: str | Path | None = None,
    overrides: Iterable[str] = (),
    values: Mapping[str, Any] | None = None,
) -> RunConfig:
    """Build a :class:`RunConfig`: defaults, then the file ``config`` (if any), then ``values`` (``{dotted key:
    value}``, e.g. from explicit command-line flags), then the ``KEY=VALUE`` ``overrides`` in order."""
    d = load_config_dict(config) if config is not None else {}
    for key, value in (values or {}).items():
        set_key(d, key, value)
    for ov in overrides:
        apply_override(d, ov)
    return RunConfig.from_dict(d)


def dump_config(cfg: RunConfig) -> str:
    """The YAML text of a resolved config (every key, defaults included); loads back to an equal config."""
    return yaml.safe_dump(_plain(cfg.to_dict()), sort_keys=False, default_flow_style=None, width=100)


def _plain(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x


__all__ = [
    "DataConfig",
    "DatasetSource",
    "DebugConfig",
    "Optimizer",
    "RunConfig",
    "TrainConfig",
    "apply_override",
    "builtin_configs",
    "dump_config",
    "key_path",
    "load_config_dict",
    "resolve_config",
    "set_key",
]
