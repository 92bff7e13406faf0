"""The options every streaming command shares (:class:`RunOptions`): the input size, the streaming policy, how many
frames and trajectories at once, the data-loading workers, a progress bar; checked here once. Also what a command's
library run returns (:class:`CommandResult`) and its source opened from its options (:func:`open_source`)."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any, Optional

from ..data.frames import FocalSize, as_size
from ..errors import ConfigError
from ..inference.policy import BASELINE, EVERY_FRAME, POLICIES
from ..workers import check_workers


@dataclass(frozen=True)
class RunOptions:
    """How a command streams its input.

    Attributes:
        size: the input size (an int, ``(H, W)``; None: the model's focal length, else the input's default).
        policy: ``baseline`` or ``every-frame`` (None: the command's default for its input); min_baseline: metres
            (None: the model's; given alone it implies ``baseline``).
        max_frames: only the first N frames; lanes: trajectories streamed at once (the batch);
        workers: data-loading worker processes; progress: show a progress bar.
    """

    size: Optional[int | tuple[int, int]] = None
    policy: Optional[str] = None
    min_baseline: Optional[float] = None
    max_frames: Optional[int] = None
    lanes: int = 1
    workers: int = 0
    progress: bool = False

    def __post_init__(self) -> None:
        check_workers(self.workers)
        if self.size is not None and not isinstance(self.size, FocalSize):
            as_size(self.size, "--size")
        if self.max_frames is not None and (not isinstance(self.max_frames, int) or self.max_frames < 1):
            raise ConfigError(f"--max-frames must be a positive integer, got {self.max_frames!r}")
        if not isinstance(self.lanes, int) or self.lanes < 1:
            raise ConfigError(f"--trajectories-per-batch must be a positive integer, got {self.lanes!r}")
        if self.policy is not None and self.policy not in POLICIES:
            raise ConfigError(f"--policy must be one of {', '.join(POLICIES)}, got {self.policy!r}")
        mb = self.min_baseline
        if mb is not None and not 0 <= mb < float("inf"):
            raise ConfigError(f"--min-baseline must be a number of metres >= 0, got {mb}")
        if mb is not None and self.policy == EVERY_FRAME:
            raise ConfigError(
                f"--min-baseline applies to --policy {BASELINE}, not {EVERY_FRAME} (which estimates every "
                "frame from the previous one)"
            )

    def stream_policy(self, default: str | None) -> tuple[str | None, float | None]:
        """``(policy, min_baseline)`` for :class:`~cosemdepth.inference.policy.Streamer`: ``policy`` as given, else
        ``baseline`` when a minimum baseline is given, else ``default`` (None: baseline when the model records its
        training motion, else every-frame)."""
        mb = self.min_baseline
        return (self.policy if self.policy is not None else (BASELINE if mb is not None else default)), mb


@dataclass
class CommandResult:
    """What a command's library run returns: its ``manifest`` (or summary), the ``lines`` it reports on stdout and
    the ``warnings`` on stderr."""

    manifest: dict[str, Any]
    lines: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def open_source(source_options, run: RunOptions, op, *, note: bool = False):
    """The source of ``source_options`` (its table entry in :data:`cosemdepth.streaming.SOURCES`) at ``run.size``,
    or else at the model's focal length (``op``: its operating point; :func:`~cosemdepth.jobs.model.input_size`); a
    ``--size`` far from the model's focal length gets a warning on stderr, and with ``note`` what the undistortion
    says about the calibration it was given (e.g. scaled to the images' size) a note."""
    from ..streaming import SOURCES
    from .model import input_size, warn_far_size

    source = SOURCES[source_options.source].from_options(source_options, input_size(run.size, op))
    dataset = getattr(source, "dataset", None)
    default = dataset.opened_size(input_size(None, op)) if hasattr(dataset, "opened_size") and op else None
    warn_far_size(op, run.size, getattr(source, "intrinsics", None), default_size=default)
    calibration_note = getattr(source, "calibration_note", None)
    text = calibration_note() if note and callable(calibration_note) else None
    if text:
        print(f"cosemdepth: note: {text}", file=sys.stderr)
    return source


__all__ = ["CommandResult", "RunOptions", "open_source"]
