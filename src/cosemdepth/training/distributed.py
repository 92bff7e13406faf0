"""Multi-process training helpers (``torchrun``, DistributedDataParallel).

A run is distributed when the environment has ``WORLD_SIZE > 1`` (set by ``torchrun``, together with ``RANK``,
``LOCAL_RANK``, ``MASTER_ADDR`` and ``MASTER_PORT``). The process group uses NCCL on CUDA and gloo on CPU. Rank 0
writes every file (checkpoints, best model, event log, TensorBoard); the other ranks only compute.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Callable, TypeVar

import torch
import torch.distributed as dist

from .. import errors
from ..errors import ConfigError, CosemdepthError

T = TypeVar("T")


@dataclass(frozen=True)
class DistInfo:
    """Rank and world size of this process (``world_size == 1``: not distributed)."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    owns_group: bool = False  # this process created the process group (and destroys it at the end)

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def _env_int(name: str, default: int) -> int:
    value = os.environ.get(name)
    if value is None or value == "":
        return default
    try:
        return int(value)
    except ValueError:
        raise ConfigError(f"environment variable {name} must be an integer, got {value!r}") from None


def init_distributed(use_cuda: bool) -> DistInfo:
    """Join the process group described by the environment (if ``WORLD_SIZE > 1``); see the module docstring."""
    if dist.is_available() and dist.is_initialized():
        return DistInfo(dist.get_rank(), dist.get_world_size(), _env_int("LOCAL_RANK", 0), owns_group=False)
    world = _env_int("WORLD_SIZE", 1)
    if world <= 1:
        return DistInfo()
    if not dist.is_available():
        raise ConfigError("WORLD_SIZE > 1 but this torch build has no torch.distributed")
    rank, local = _env_int("RANK", 0), _env_int("LOCAL_RANK", 0)
    backend = "nccl" if use_cuda else "gloo"
    if use_cuda:
        torch.cuda.set_device(local)
    dist.init_process_group(backend=backend, rank=rank, world_size=world)
    return DistInfo(rank, world, local, owns_group=True)


def shutdown(info: DistInfo) -> None:
    if info.owns_group and dist.is_initialized():
        dist.destroy_process_group()


def barrier(info: DistInfo) -> None:
    if info.enabled:
        dist.barrier()


def all_true(flag: bool, info: DistInfo, device: torch.device) -> bool:
    """True when ``flag`` is true on every rank."""
    if not info.enabled:
        return bool(flag)
    t = torch.tensor([1.0 if flag else 0.0], device=device)
    dist.all_reduce(t, op=dist.ReduceOp.MIN)
    return bool(t.item() > 0.5)


def mean_over_ranks(values: dict[str, float], info: DistInfo, device: torch.device) -> dict[str, float]:
    """The average of each value over the ranks (every rank must pass the same keys)."""
    if not info.enabled or not values:
        return dict(values)
    keys = sorted(values)
    t = torch.tensor([float(values[k]) for k in keys], dtype=torch.float64, device=device)
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    t /= info.world_size
    return {k: float(v) for k, v in zip(keys, t.tolist())}


def broadcast(obj: T, info: DistInfo) -> T:
    """Rank 0's ``obj`` on every rank."""
    if not info.enabled:
        return obj
    box = [obj]
    dist.broadcast_object_list(box, src=0)
    return box[0]


def on_main(fn: Callable[[], T], info: DistInfo) -> T:
    """Run ``fn`` on rank 0 and give its result to every rank; a :class:`CosemdepthError` raised by ``fn`` is raised
    on every rank (so that no rank waits forever for a rank that failed)."""
    result: Any = None
    error: tuple[str, str] | None = None
    if info.is_main:
        try:
            result = fn()
        except CosemdepthError as e:
            if not info.enabled:
                raise
            error = (type(e).__name__, str(e))
    if info.enabled:
        result, error = broadcast((result, error), info)
    if error is not None:
        raise getattr(errors, error[0], CosemdepthError)(error[1])
    return result


__all__ = ["DistInfo", "all_true", "barrier", "broadcast", "init_distributed", "mean_over_ranks", "on_main", "shutdown"]
