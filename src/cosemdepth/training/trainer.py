"""The training loop (design 9): :class:`Trainer`.

One :class:`Trainer` runs one run folder (layout in :mod:`cosemdepth.training.rundir`):

* Adam with the configured recipe (the paper's: lr 1e-4 constant, betas 0.9/0.999, eps 1e-7, Keras 2's update of
  :mod:`.optim`) on the loss of design 8;
* a checkpoint every ``train.checkpoint_every`` steps and at every epoch end, the newest ``train.keep_last`` kept;
  running the same command again resumes from the newest valid checkpoint (weights, optimizer, position in the
  epoch, RNG states, best metrics), so the resumed run continues exactly where the checkpoint was taken;
* validation as in design 7.3 every ``train.validate_every_epochs`` epochs and/or ``train.validate_every_steps``
  steps, and the best model in ``RUN_DIR/best`` by the rule ``train.best`` (design 9.5, or one metric);
* a non-finite guard: a step whose loss or gradient is not finite is skipped (no optimizer update) and logged; after
  ``train.nonfinite_patience`` such steps in a row the run rolls back to the last good checkpoint, re-shuffles the
  rest of that epoch, and continues; it gives up after ``train.max_rollbacks`` rollbacks without progress;
* one continuous stream of training batches across epochs (:func:`.data.make_train_stream`): its DataLoader
  workers start once per run (and again after a rollback) and prefetch the next epoch's first batches while an
  epoch ends, validates and checkpoints; the batches are those of one loader per epoch, so the epoch
  accounting, resume and rollback are unchanged;
* every model folder it writes (checkpoints, ``best``) records the run's operating point (``config.json``
  ``"operating_point"``: ``data.size``, the training data's focal length in pixels at that size, and the statistics
  of the per-step translations of its training windows; :func:`.data.training_operating_point`);
* DistributedDataParallel when started by ``torchrun`` (rank 0 writes everything);
* TensorBoard, a JSON-lines event log, a tqdm progress bar.

A training step counts one batch, whether its update was applied or skipped; "step N" is the N-th batch of the run
(1-based), and ``ckpt-0000000N`` holds the state after it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import random
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Optional

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import Dataset
from tqdm import tqdm

from ..checkpoints.model_io import read_weights
from ..devices import bf16_convolutions, no_bf16_reason, resolve_device, retain_freed_host_memory
from ..errors import CheckpointError, ConfigError, CosemdepthError, DatasetError
from ..measures.losses import FIRST_SUPERVISED_FRAME, LossTerms, weighted_total
from ..measures.metrics import selection_rule
from ..models import build_model
from ..models.config import ModelConfig
from ..models.footprint import check_size
from ..ops.resample import resize_nn2
from ..output_safety.atomic import atomic_write_text
from ..render.examples import example_strip
from ..tasks import tasks_for
from . import distributed as D
from .board import Board
from .checkpoint import CheckpointManager, get_rng_state, load_checkpoint, set_rng_state
from .config import RunConfig, dump_config
from .data import (
    ResumableSampler,
    build_train_dataset,
    build_val_dataset,
    check_modalities,
    make_loader,
    make_train_stream,
    steps_per_epoch,
    to_device,
    total_steps,
    training_operating_point,
)
from .events import CONSOLE_KINDS, EventLog
from .init import read_transfer_source, transfer_state_dict
from .optim import make_optimizer
from .rundir import (
    BEST_METRICS_NAME,
    BEST_NAME,
    CHECKPOINTS_NAME,
    CONFIG_NAME,
    EVENTS_NAME,
    TENSORBOARD_NAME,
    check_output_dir,
    compare_configs,
    create_run_dir,
    read_run_config,
    recover_best,
    save_best,
)
from .validation import validate


class TrainingDiverged(CosemdepthError):
    """The non-finite guard rolled back ``train.max_rollbacks`` times without reaching a new good checkpoint."""


@dataclass
class LoopState:
    """Where the run is. Saved in every checkpoint (``trainer_state.json``)."""

    step: int = 0
    epoch: int = 0
    batch_in_epoch: int = 0
    #: Salt of the sample order of the current epoch (incremented by each rollback).
    data_salt: int = 0
    #: ``{"step": int, "metrics": {...}}`` of the best validation so far, or None.
    best: Optional[dict] = None
    last_validation: Optional[dict] = None
    last_validation_step: int = -1
    history: list = field(default_factory=list)  # [{"step", "epoch", "metrics"}] of every validation

    @classmethod
    def from_dict(cls, d: dict) -> "LoopState":
        names = set(cls.__dataclass_fields__)
        return cls(**{k: v for k, v in d.items() if k in names})


class NonFiniteGuard:
    """Counts non-finite steps in a row: :meth:`record` says ``"ok"``, ``"skip"`` or ``"rollback"``."""

    def __init__(self, patience: int) -> None:
        self.patience = int(patience)
        self.streak = 0

    def record(self, finite: bool) -> str:
        if finite:
            self.streak = 0
            return "ok"
        self.streak += 1
        return "rollback" if self.streak >= self.patience else "skip"

    def reset(self) -> None:
        self.streak = 0


def seed_everything(seed: int) -> None:
    """Seed python's, numpy's and torch's global generators (CPU and CUDA)."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def compute_loss(out, batch: dict, cfg: RunConfig) -> LossTerms:
    """The training loss (design 8) of a :class:`SequenceOutput` against a batch: the weighted sum of the losses
    of the model's decoders (:meth:`~cosemdepth.tasks.DecoderTask.loss`, ``loss_weight``), in their order.

    Always float32: autocast is switched off here and bfloat16 predictions (``train.bf16``) are cast to float32
    before the log, the resizes and the means, so the loss and its gradient have float32 rounding."""
    tasks = tasks_for(cfg.model)
    device_type = out.maps(tasks[0].head)[0].device.type
    with torch.autocast(device_type, enabled=False) if device_type in ("cpu", "cuda") else contextlib.nullcontext():
        parts = {t.name: t.loss(out, batch, cfg.train) for t in tasks}
        return weighted_total(parts, {t.name: t.loss_weight(cfg.train) for t in tasks})


def forward_batch(net: torch.nn.Module, batch: dict):
    """The training forward of a batch (run it inside :func:`bf16_autocast`): the model's
    :meth:`~cosemdepth.models.SceneModel.forward_sequence` with the outputs wanted from the loss's first supervised
    frame on (the semantic decoder skips frame 0, which no loss term reads); a model whose semantic decoder warps with
    the ground-truth depth (``semantic_time="gt"``) is given the batch's depth."""
    guide = batch["depth"] if getattr(net, "module", net).config.needs_depth_input else None
    return net(
        batch["rgb"],
        batch["rot"],
        batch["trans"],
        batch["intrinsics"],
        batch.get("reset"),
        first_frame=FIRST_SUPERVISED_FRAME,
        guide_depth=guide,
    )


def bf16_supported(device: torch.device) -> bool:
    """Whether ``train.bf16`` applies on ``device``: bfloat16 autocast exists for the CPU and CUDA."""
    return device.type in ("cpu", "cuda")


def bf16_autocast(device: torch.device, enabled: bool):
    """The forward pass's precision context: bfloat16 autocast on the CPU or CUDA when ``enabled``, else none.

    The parameters stay float32 (the master weights Adam updates); autocast runs the convolutions and matrix
    products in bfloat16 and keeps precision-sensitive ops (normalisations, reductions, ``exp``/``log``) in float32.
    The loss is computed outside this context and casts the predictions to float32 (:func:`compute_loss`).
    """
    if enabled and bf16_supported(device):
        return torch.autocast(device.type, dtype=torch.bfloat16)
    return contextlib.nullcontext()


def prepare_for_training(model: torch.nn.Module, device: torch.device, channels_last: bool) -> torch.nn.Module:
    """The model on ``device``, its convolution weights in channels-last memory format when ``channels_last``.

    Channels-last weights make every convolution's output channels-last too, so oneDNN's convolutions (which work
    in a channels-last blocked layout on the CPU) take their activations without reordering them at every call, in
    the forward and the backward. The numbers are the same up to float rounding (other summation orders)."""
    model = model.to(device)
    return model.to(memory_format=torch.channels_last) if channels_last else model


def read_init_weights(path: str, model_config: ModelConfig) -> dict[str, torch.Tensor]:
    """The float32 state dict of ``path`` (``train.init_weights``), checked to fit a model of ``model_config``.

    Raises :class:`CheckpointError` naming the path when the weights are unreadable or belong to another
    architecture (arch, levels, classes or a switch that changes the parameters differ).
    """
    try:
        state_dict, weights_config, origin = read_weights(path)
    except CheckpointError as e:
        raise CheckpointError(f"train.init_weights: {e}") from None
    differ = [
        f"{f.name} {getattr(weights_config, f.name)!r} (run: {getattr(model_config, f.name)!r})"
        for f in dataclasses.fields(ModelConfig)
        if f.name != "pscv_dtype" and getattr(weights_config, f.name) != getattr(model_config, f.name)
    ]
    if differ:
        raise CheckpointError(f"train.init_weights: {origin}: the weights are of another model: {', '.join(differ)}")
    state_dict = {k: v.float() if v.is_floating_point() else v for k, v in state_dict.items()}
    with torch.device("meta"):
        model = build_model(model_config)
    try:
        model.load_state_dict(state_dict, strict=True, assign=True)
    except RuntimeError as e:
        raise CheckpointError(
            f"train.init_weights: {origin}: the weights do not fit the run's model ({str(e).splitlines()[0]})"
        ) from None
    return state_dict


def learning_rate(cfg: RunConfig, epoch: int) -> float:
    """The learning rate of ``epoch``: ``lr * lr_decay ** (number of lr_decay_epochs <= epoch)``."""
    t = cfg.train
    return t.lr * t.lr_decay ** sum(1 for e in t.lr_decay_epochs if e <= epoch)


class Trainer:
    """Train a model as configured by ``config`` in the run folder ``run_dir``.

    Construction checks everything that can be checked before writing (config, device, datasets, output folder)
    and raises :class:`CosemdepthError` subclasses naming what is wrong; nothing is written until :meth:`fit`.

    Args:
        config: the run config.
        run_dir: the run folder (created, or resumed if it holds a run).
        train_dataset, val_dataset: datasets to use instead of the configured ones (items as
            :func:`cosemdepth.data.open_dataset`); ``val_dataset=None`` uses the configured validation.
        listeners: callables receiving every event dict (see :mod:`cosemdepth.training.events`) on rank 0.
        console: print events and a progress bar.
    """

    def __init__(
        self,
        config: RunConfig,
        run_dir: str | Path,
        *,
        train_dataset: Dataset | None = None,
        val_dataset: Dataset | None = None,
        listeners: Iterable[Callable[[dict], None]] = (),
        console: bool = True,
    ) -> None:
        self.cfg = config
        self.run_dir = Path(run_dir)
        self.listeners = list(listeners)
        self.console = console
        tc = config.train
        device = resolve_device(tc.device, "train.device")
        if tc.bf16 and bf16_supported(device) and not bf16_convolutions(device):
            raise ConfigError(f"train.bf16 (--bf16): {no_bf16_reason()}: train in float32, without --bf16")
        self.dist = D.init_distributed(device.type == "cuda")
        if self.dist.enabled and device.type == "cuda":
            device = torch.device("cuda", self.dist.local_rank)
        self.device = device
        # the size against the memory here, before anything is read or written (an absurd data.size is one line)
        with torch.device("meta"):
            shapes_only = build_model(config.model)
        check_size(
            shapes_only,
            *config.data.size,
            device=device,
            batch=tc.batch_size,
            frames=config.data.seq_len,
            training=True,
            what="data.size",
        )
        # the run folder first (output policy): nothing is read or built for a run that cannot be written
        self.resuming = D.on_main(lambda: check_output_dir(self.run_dir, config), self.dist)
        if tc.num_threads:
            torch.set_num_threads(tc.num_threads)
        if device.type == "cpu" and tc.retain_host_memory:
            # a step's activations reused from the heap, not faulted in afresh each step (docs/training.md)
            retain_freed_host_memory()
        # the weights a new run starts from, read now so that a bad path fails before anything is written
        self._init_state = (
            read_init_weights(tc.init_weights, config.model) if tc.init_weights and not self.resuming else None
        )
        #: ``train.init_from``: the source weights, read now for the same reason (the plan is made again at set-up)
        self._init_source = (
            read_transfer_source(tc.init_from, config.model)[0] if tc.init_from and not self.resuming else None
        )

        self.train_set = (
            train_dataset if train_dataset is not None else build_train_dataset(config.data, config.model, tc.seed)
        )
        check_modalities(self.train_set, config.model, "the training data")
        #: What every model folder the run writes records (config.json "operating_point").
        self.operating_point = training_operating_point(self.train_set, config.data.size)
        self.val_set = val_dataset if val_dataset is not None else build_val_dataset(config.data, config.model, tc.seed)
        if self.val_set is not None:
            check_modalities(self.val_set, config.model, "the validation data")
        self.steps_per_epoch = steps_per_epoch(self.train_set, tc.batch_size, self.dist.world_size)
        if self.steps_per_epoch == 0:
            raise DatasetError(
                f"the training data has {len(self.train_set)} sequences, fewer than one batch of "
                f"train.batch_size = {tc.batch_size} per process ({self.dist.world_size} "
                "process(es)); lower the batch size or add data"
            )
        self.total_steps = total_steps(tc.epochs, self.steps_per_epoch, tc.max_steps)
        self.is_better = selection_rule(tc.best)

        self.state = LoopState()
        self.guard = NonFiniteGuard(tc.nonfinite_patience)
        self.model = None
        self.optimizer = None
        self.events = EventLog(None, console=False)
        self.board = None
        self._injected: set[int] = set()
        self._pending_checkpoint = False
        self._last_saved_step = -1
        self._rollbacks_since_good = 0
        self._max_salt = 0
        self._bar = None
        self._acc: dict[str, float] = {}
        self._acc_n = 0
        self._t_log = time.time()
        self._steps_at_log = 0
        #: Seconds the loop waited for the data loader since the last log (logged per step as ``data_wait_s``).
        self._data_wait_s = 0.0

    # ------------------------------------------------------------------------------------------------ set-up
    def _setup(self) -> None:
        cfg, dist = self.cfg, self.dist
        main = dist.is_main

        def prepare() -> list[str]:
            if self.resuming:
                changes = compare_configs(read_run_config(self.run_dir), cfg, self.run_dir)
                if changes:
                    atomic_write_text(self.run_dir / CONFIG_NAME, dump_config(cfg))
                return changes
            create_run_dir(self.run_dir, cfg)
            return []

        changes = D.on_main(prepare, dist)
        if main:
            kinds = set(CONSOLE_KINDS) | ({"train"} if not self._progress_bar_shown() else set())
            self.events = EventLog(
                self.run_dir / EVENTS_NAME, console=self.console, listeners=self.listeners, console_kinds=kinds
            )
            self.events.open()
            if changes:
                self.events("config_changed", changes=changes)
        self.ckpts = CheckpointManager(self.run_dir / CHECKPOINTS_NAME, cfg.train.keep_last, log=self.events)

        seed_everything(cfg.train.seed)
        self.model = prepare_for_training(build_model(cfg.model), self.device, cfg.train.channels_last)
        self.model.train()
        if dist.enabled:
            ids = [self.device.index] if self.device.type == "cuda" else None
            self.net = DistributedDataParallel(self.model, device_ids=ids)
        else:
            self.net = self.model
        t = cfg.train
        self.optimizer = make_optimizer(
            t.optimizer, self.model.parameters(), lr=t.lr, betas=t.betas, eps=t.eps, weight_decay=t.weight_decay
        )
        self.sampler = ResumableSampler(
            self.train_set, num_replicas=dist.world_size, rank=dist.rank, shuffle=True, seed=t.seed
        )

        def find_checkpoint() -> str | None:
            self.ckpts.cleanup()
            recover_best(self.run_dir)
            found = self._latest_valid_path()
            if found is None and self.resuming:  # a rerun that cannot resume: said before it starts over
                self._warn_start_over()
            return found

        path = D.on_main(find_checkpoint, dist)
        if path is not None:
            self._load(path)
            best = self._read_best()
            if best is not None:
                self.state.best = best
            self.events(
                "resume",
                checkpoint=path,
                step=self.state.step,
                epoch=self.state.epoch,
                batch_in_epoch=self.state.batch_in_epoch,
                total_steps=self.total_steps,
            )
        else:
            if cfg.train.init_weights:
                if self._init_state is None:  # a resumed folder without a valid checkpoint starts over
                    self._init_state = read_init_weights(cfg.train.init_weights, cfg.model)
                self.model.load_state_dict(self._init_state)  # copies into the parameters, keeping their layout
                self._init_state = None
            transfer = None
            if cfg.train.init_from:
                if self._init_source is None:
                    self._init_source = read_transfer_source(cfg.train.init_from, cfg.model)[0]
                state, transfer = transfer_state_dict(
                    self._init_source, self.model.state_dict(), f"train.init_from: {cfg.train.init_from}"
                )
                self.model.load_state_dict(state)
                self._init_source = None
            self.events(
                "start",
                run_dir=str(self.run_dir),
                total_steps=self.total_steps,
                init_weights=cfg.train.init_weights or None,
                init_from=cfg.train.init_from or None,
                **({} if transfer is None else transfer.summary(prefix="init_")),
                steps_per_epoch=self.steps_per_epoch,
                world_size=dist.world_size,
                device=str(self.device),
                bf16_autocast=bf16_supported(self.device) and bool(cfg.train.bf16),
                num_parameters=self.model.num_parameters(),
                train_items=len(self.train_set),
                val_items=None if self.val_set is None else len(self.val_set),
                operating_point=self.operating_point.to_dict(),
            )
            self._save_checkpoint()
        if main:
            self.board = _make_board(self.run_dir / TENSORBOARD_NAME, self.state.step if path else None)

    def _warn_start_over(self) -> None:
        """One line on stderr (and a ``start_over`` event): this run folder has no valid checkpoint to resume from,
        naming the invalid ones moved aside, so the run starts again from step 0."""
        aside = self.ckpts.set_aside()
        why = (
            f"its invalid checkpoints were moved aside: {', '.join(str(p) for p in aside)}"
            if aside
            else f"{self.ckpts.folder} holds none"
        )
        self.events("start_over", moved_aside=[str(p) for p in aside])
        if self.console:
            tqdm.write(
                f"cosemdepth train: warning: {self.run_dir}: no valid checkpoint to resume from ({why}); starting "
                "again from step 0",
                file=sys.stderr,
            )

    def _latest_valid_path(self) -> str | None:
        p = self.ckpts.latest_valid()
        return None if p is None else str(p)

    def _progress_bar_shown(self) -> bool:
        """A progress bar on rank 0 when asked for and stderr is a terminal (else "train" events are printed)."""
        return bool(self.console and self.cfg.train.progress and self.dist.is_main and sys.stderr.isatty())

    def _read_best(self) -> dict | None:
        p = self.run_dir / BEST_NAME / BEST_METRICS_NAME

        def read() -> dict | None:
            try:
                d = json.loads(p.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                return None
            return {"step": d.get("step"), "metrics": d}

        return D.on_main(read, self.dist)

    # ------------------------------------------------------------------------------------------------ checkpoints
    def _trainer_state(self) -> dict:
        d = asdict(self.state)
        d.update(
            total_steps=self.total_steps,
            steps_per_epoch=self.steps_per_epoch,
            world_size=self.dist.world_size,
            batch_size=self.cfg.train.batch_size,
            saved_at=time.time(),
        )
        return d

    def _save_checkpoint(self) -> None:
        if self.state.step == self._last_saved_step:
            return
        if self.dist.is_main:
            path = self.ckpts.save(
                model_state=self.model.state_dict(),
                model_config=self.cfg.model,
                optimizer_state=self.optimizer.state_dict(),
                trainer_state=self._trainer_state(),
                rng_state=get_rng_state(),
                source={"kind": "training", "run_dir": str(self.run_dir.absolute()), "epoch": self.state.epoch},
                operating_point=self.operating_point,
            )
            self.events("checkpoint", path=str(path), step=self.state.step, epoch=self.state.epoch)
        D.barrier(self.dist)
        self._last_saved_step = self.state.step
        self._pending_checkpoint = False
        self._rollbacks_since_good = 0

    def _request_checkpoint(self) -> None:
        """Save now, or as soon as the non-finite streak is over (the last checkpoint must stay a good one)."""
        if self.guard.streak > 0:
            if not self._pending_checkpoint:
                self.events("checkpoint_deferred", step=self.state.step, streak=self.guard.streak)
            self._pending_checkpoint = True
        else:
            self._save_checkpoint()

    def _load(self, path: str) -> None:
        ck = load_checkpoint(path, device=self.device)
        self.model.load_state_dict(ck.model)
        self.optimizer.load_state_dict(ck.optimizer)
        set_rng_state(ck.rng)
        self.state = LoopState.from_dict(ck.state)
        if self.state.batch_in_epoch >= self.steps_per_epoch:  # the epoch got shorter (less data, larger batch)
            self.state.epoch += 1
            self.state.batch_in_epoch = 0
        self._last_saved_step = self.state.step
        self._max_salt = max(self._max_salt, self.state.data_salt)

    def _rollback(self, bad_step: int) -> None:
        self._rollbacks_since_good += 1
        if self._rollbacks_since_good > self.cfg.train.max_rollbacks:
            raise TrainingDiverged(
                f"step {bad_step}: {self.guard.streak} non-finite steps in a row again after "
                f"{self.cfg.train.max_rollbacks} rollback(s) without progress; see {self.run_dir / EVENTS_NAME}"
            )
        path = D.on_main(self._latest_valid_path, self.dist)
        if path is None:
            raise TrainingDiverged(f"step {bad_step}: non-finite steps and no valid checkpoint to roll back to")
        best, last, hist = self.state.best, self.state.last_validation, self.state.history
        self._load(path)
        self.state.best = best  # validations after the checkpoint stay known (best/ holds their winner)
        self.state.last_validation, self.state.history = last, hist
        self._max_salt += 1
        self.state.data_salt = self._max_salt
        streak = self.guard.streak
        self.guard.reset()
        self._pending_checkpoint = False
        self.events(
            "rollback",
            from_step=bad_step,
            to_step=self.state.step,
            checkpoint=path,
            streak=streak,
            rollbacks_without_progress=self._rollbacks_since_good,
            data_salt=self.state.data_salt,
        )

    # ------------------------------------------------------------------------------------------------ steps
    def _autocast(self):
        return bf16_autocast(self.device, self.cfg.train.bf16)

    def _train_step(self, batch: dict) -> str:
        """One batch: forward, loss, backward, guard, update. Returns the guard's verdict."""
        st = self.state
        step = st.step + 1
        batch = to_device(batch, self.device)
        for g in self.optimizer.param_groups:
            g["lr"] = learning_rate(self.cfg, st.epoch)
        with self._autocast():
            out = forward_batch(self.net, batch)
        terms = compute_loss(out, batch, self.cfg)
        loss = terms.total
        if step in self.cfg.debug.inject_nonfinite_steps and step not in self._injected:
            self._injected.add(step)
            loss = loss * float("nan")
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        grads = [p.grad for p in self.model.parameters() if p.grad is not None]
        grad_norm = torch.linalg.vector_norm(torch.stack(torch._foreach_norm(grads)))  # (float32 grads)
        finite = bool(torch.isfinite(loss.detach()).item() and torch.isfinite(grad_norm).item())
        finite = D.all_true(finite, self.dist, self.device)
        verdict = self.guard.record(finite)
        if finite:
            if self.cfg.train.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.cfg.train.grad_clip)
            self.optimizer.step()
            values = {k: v for k, v in terms.as_dict().items()}
            values["grad_norm"] = float(grad_norm)
            for k, v in values.items():
                self._acc[k] = self._acc.get(k, 0.0) + v
            self._acc_n += 1
        else:
            self.optimizer.zero_grad(set_to_none=True)
            self.events(
                "nonfinite_step",
                step=step,
                epoch=st.epoch,
                loss=float(loss.detach()),
                grad_norm=float(grad_norm),
                streak=self.guard.streak,
                action=verdict,
                injected=step in self._injected,
            )
        st.step = step
        st.batch_in_epoch += 1
        if finite and self._pending_checkpoint:
            self._save_checkpoint()
        if self.board is not None and self.cfg.train.image_every and step % self.cfg.train.image_every == 0:
            self._log_images("train", batch, out, step)
        return verdict

    def _log_train(self) -> None:
        """Every ``log_every`` steps: mean losses of the good steps since the last log (over all ranks)."""
        st = self.state
        parts = [t.name for t in tasks_for(self.cfg.model)]
        keys = ["total", "grad_norm"] + parts
        means = {k: self._acc[k] / self._acc_n if self._acc_n else math.nan for k in keys}
        means["good_steps"] = float(self._acc_n)
        means = D.mean_over_ranks(means, self.dist, self.device)
        now = time.time()
        speed = (st.step - self._steps_at_log) / max(now - self._t_log, 1e-9)
        data_wait = self._data_wait_s / max(st.step - self._steps_at_log, 1)
        self._t_log, self._steps_at_log, self._data_wait_s = now, st.step, 0.0
        self._acc, self._acc_n = {}, 0
        lr = learning_rate(self.cfg, st.epoch)
        named = {f"loss_{k}" if k in ("total", *parts) else k: v for k, v in means.items()}
        self.events("train", step=st.step, epoch=st.epoch, lr=lr, steps_per_s=speed, data_wait_s=data_wait, **named)
        if self.board is not None:
            self.board.scalars("train", {k: v for k, v in named.items() if k != "good_steps"}, st.step)
            self.board.scalars("train", {"lr": lr, "steps_per_s": speed, "epoch": st.epoch}, st.step)
        if self._bar is not None and math.isfinite(means["total"]):
            self._bar.set_postfix(loss=f"{means['total']:.4f}", epoch=st.epoch, refresh=False)

    def _log_images(self, tag: str, batch: dict, out, step: int) -> None:
        m = self.cfg.model
        size = tuple(batch["rgb"].shape[-2:])
        example = {"rgb": batch["rgb"][0, -1]}
        with torch.no_grad():
            for t in tasks_for(m):
                gt = t.ground_truth(batch)
                pred = resize_nn2(out.maps(t.head)[0][:1, -1].float(), size)[0]
                example.update(t.example(None if gt is None else gt[0, -1], pred, m))
        self.board.image(f"{tag}/rgb_depth_true_pred_labels_true_pred", example_strip_of(example, m), step)

    # ------------------------------------------------------------------------------------------------ validation
    def _validate(self) -> None:
        st = self.state

        def run() -> dict:
            loader = make_loader(
                self.val_set, self.cfg.train.val_batch_size, self.cfg.data.num_workers, seed=self.cfg.train.seed
            )
            metrics, example = validate(
                self.model, loader, self.device, max_batches=self.cfg.train.val_max_batches, autocast=self._autocast()
            )
            if self.board is not None and example is not None:
                self.board.image(
                    "val/rgb_depth_true_pred_labels_true_pred", example_strip_of(example, self.cfg.model), st.step
                )
            return metrics

        # Every rank validates (same weights, same data): no rank waits in a collective for the length of a
        # validation, which could exceed the process group's timeout; rank 0's result is used everywhere.
        metrics = D.broadcast(run(), self.dist)
        st.last_validation = metrics
        st.last_validation_step = st.step
        st.history.append({"step": st.step, "epoch": st.epoch, "metrics": _scalars(metrics)})
        self.events("validation", step=st.step, epoch=st.epoch, metrics=metrics)
        if self.board is not None:
            self.board.scalars("val", {k: v for k, v in metrics.items() if k != "frames"}, st.step)
        best = None if st.best is None else st.best.get("metrics")
        if self.is_better(metrics, best):
            if self.dist.is_main:
                path = save_best(
                    self.run_dir,
                    self.model.state_dict(),
                    self.cfg.model,
                    metrics,
                    {"step": st.step, "epoch": st.epoch, "rule": self.cfg.train.best},
                    self.operating_point,
                )
                self.events(
                    "best", step=st.step, epoch=st.epoch, path=str(path), rule=self.cfg.train.best, metrics=metrics
                )
            D.barrier(self.dist)
            st.best = {"step": st.step, "metrics": metrics}

    # ------------------------------------------------------------------------------------------------ the loop
    def _stream(self):
        """An iterator over the training batches from the current position to the end of the run, across epochs:
        its worker processes live until the run ends or rolls back (no restart, and prefetching, at epoch ends)."""
        st, tc = self.state, self.cfg.train
        seed = (tc.seed * 1_000_003 + st.epoch) * 1_000_033 + st.data_salt
        return iter(
            make_train_stream(
                self.train_set,
                self.sampler,
                tc.batch_size,
                self.cfg.data.num_workers,
                epoch=st.epoch,
                start_batch=st.batch_in_epoch,
                salt=st.data_salt,
                num_batches=self.total_steps - st.step,
                seed=seed,
                pin_memory=self.device.type == "cuda",
            )
        )

    def fit(self) -> dict:
        """Train (or resume) until ``train.epochs`` epochs or ``train.max_steps`` steps; return a summary dict:
        ``step``, ``epoch``, ``best`` ({step, metrics} or None), ``last_validation``, ``checkpoint``, ``run_dir``."""
        try:
            self._setup()
            self._loop()
            summary = {
                "run_dir": str(self.run_dir),
                "step": self.state.step,
                "epoch": self.state.epoch,
                "best": self.state.best,
                "last_validation": self.state.last_validation,
                "checkpoint": str(self.ckpts.folder / f"ckpt-{self.state.step:08d}"),
            }
            self.events(
                "done",
                step=self.state.step,
                epoch=self.state.epoch,
                best_step=None if self.state.best is None else self.state.best.get("step"),
            )
            return summary
        except BaseException as e:
            if not isinstance(e, (KeyboardInterrupt, ConfigError)):
                self.events("error", step=self.state.step, error=f"{type(e).__name__}: {e}")
            raise
        finally:
            if self._bar is not None:
                self._bar.close()
            if self.board is not None:
                self.board.close()
            self.events.close()
            D.shutdown(self.dist)

    def _loop(self) -> None:
        st, tc = self.state, self.cfg.train
        self._bar = tqdm(
            total=self.total_steps,
            initial=min(st.step, self.total_steps),
            desc="train",
            unit="step",
            dynamic_ncols=True,
            disable=not self._progress_bar_shown(),
            smoothing=0.05,
        )
        self._t_log, self._steps_at_log, self._data_wait_s = time.time(), st.step, 0.0
        batches = None
        try:
            while self.state.step < self.total_steps:
                t_wait = time.perf_counter()  # (the time the step waits for the data loader is logged)
                if batches is None:
                    batches = self._stream()  # (starting the workers counts as waiting)
                batch = next(batches, None)
                if batch is None:
                    raise RuntimeError(
                        f"the training data ran out at step {self.state.step}, batch "
                        f"{self.state.batch_in_epoch} of an epoch of {self.steps_per_epoch}"
                    )
                self._data_wait_s += time.perf_counter() - t_wait
                verdict = self._train_step(batch)
                st = self.state
                self._bar.update(1)
                if verdict == "rollback":
                    batches = None  # (its workers stop; the rolled-back position gets a new stream)
                    self._rollback(st.step)
                    self._bar.n = self.state.step
                    self._bar.refresh()
                    continue
                if st.step % tc.log_every == 0:
                    self._log_train()
                epoch_done = st.batch_in_epoch >= self.steps_per_epoch
                if epoch_done:
                    st.epoch += 1
                    st.batch_in_epoch = 0
                    self.events("epoch_end", step=st.step, epoch=st.epoch)
                validate_now = self.val_set is not None and (
                    (epoch_done and tc.validate_every_epochs and st.epoch % tc.validate_every_epochs == 0)
                    or (tc.validate_every_steps and st.step % tc.validate_every_steps == 0)
                )
                if validate_now:
                    self._validate()
                if epoch_done or (tc.checkpoint_every and st.step % tc.checkpoint_every == 0):
                    self._request_checkpoint()
        finally:
            batches = None  # stop the workers now, not when an exception's traceback is freed
        st = self.state
        if (
            self.val_set is not None
            and st.last_validation_step != st.step
            and (tc.validate_every_epochs or tc.validate_every_steps)
        ):
            self._validate()
        self._save_checkpoint()


def _make_board(log_dir: Path, purge_step: int | None):
    """A TensorBoard writer, or None if TensorBoard is not installed."""
    try:
        return Board(log_dir, purge_step=purge_step)
    except ImportError:
        return None


def example_strip_of(example: dict, model: ModelConfig) -> np.ndarray:
    """The training picture of one frame: RGB, then each decoder's panels (true, predicted) from its
    :meth:`~cosemdepth.tasks.DecoderTask.example` tensors in ``example``."""
    return example_strip(example["rgb"], [p for t in tasks_for(model) for p in t.strip_panels(example, model)])


def _scalars(metrics: dict) -> dict:
    return {k: v for k, v in metrics.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}


__all__ = [
    "LoopState",
    "NonFiniteGuard",
    "Trainer",
    "TrainingDiverged",
    "bf16_autocast",
    "bf16_supported",
    "compute_loss",
    "learning_rate",
    "prepare_for_training",
    "resolve_device",
    "seed_everything",
]
