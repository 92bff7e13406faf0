"""TensorBoard output of a run (rank 0 only): losses, learning rate, metrics and example pictures."""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np


class Board:
    """A thin wrapper of :class:`torch.utils.tensorboard.SummaryWriter` that skips non-numbers.

    Args:
        log_dir: ``RUN_DIR/tensorboard``.
        purge_step: on resume, the step to restart from: events at or after it (from the interrupted run) are
            discarded by TensorBoard so the curves do not overlap.
    """

    def __init__(self, log_dir: str | os.PathLike, purge_step: int | None = None) -> None:
        # deferred: TensorBoard is optional (no board without it, see trainer._make_board) and slow to import
        from torch.utils.tensorboard import SummaryWriter

        Path(log_dir).mkdir(parents=True, exist_ok=True)
        self.writer = SummaryWriter(log_dir=str(log_dir), purge_step=purge_step, flush_secs=30)

    def scalars(self, prefix: str, values: Mapping[str, Any], step: int) -> None:
        """``prefix/name`` for each finite number of ``values``; lists (per-class IoU) as ``prefix/name/i``."""
        for k, v in values.items():
            if isinstance(v, (list, tuple)):
                for i, x in enumerate(v):
                    self._scalar(f"{prefix}/{k}/{i}", x, step)
            else:
                self._scalar(f"{prefix}/{k}", v, step)

    def _scalar(self, tag: str, v: Any, step: int) -> None:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            return
        self.writer.add_scalar(tag, float(v), step)

    def image(self, tag: str, image: np.ndarray, step: int) -> None:
        """``image [H, W, 3]`` uint8."""
        self.writer.add_image(tag, image, step, dataformats="HWC")

    def flush(self) -> None:
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()


__all__ = ["Board"]
