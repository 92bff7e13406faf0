"""``view`` as a library: a source, a :class:`~cosemdepth.inference.policy.Streamer` and a rerun recording (the only
output: :class:`~cosemdepth.streaming.sinks.rerun.RerunSink`); :func:`run_view` is what ``cosemdepth view`` runs once
its arguments are parsed."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm.auto import tqdm

from ..inference.policy import policy_info
from ..measures.classes import class_info
from ..models.protocol import model_config
from ..streaming import pipeline
from ..streaming.sinks.rerun import RerunSink, check_rrd_path, require_rerun
from ..streaming.sinks.status import StatusSink
from ..tasks import class_count
from .model import ModelOptions, check_run_size, load_for
from .options import CommandResult, RunOptions, open_source
from .predict import default_policy, depth_report, make_streamer, source_report


@dataclass(frozen=True)
class ViewOptions:
    """Everything ``cosemdepth view`` runs on, checked at construction: the input (``source``, as
    :class:`~cosemdepth.jobs.predict.PredictOptions`), the ``model``, the ``run`` options and the recording ``rrd``
    to write (a new file, or one cosemdepth wrote)."""

    source: Any
    model: ModelOptions
    rrd: Path
    run: RunOptions = field(default_factory=RunOptions)

    def __post_init__(self) -> None:
        require_rerun()


def run_view(options: ViewOptions) -> CommandResult:
    """``cosemdepth view``: the recording's file checked, the source at the model's size, the model, the run."""
    options.model.apply_threads()
    policy, min_baseline = options.run.stream_policy(default_policy(options.source))
    check_rrd_path(options.rrd, option="--rrd", inputs=[*options.model.inputs(), *options.source.inputs()])
    source = open_source(options.source, options.run, options.model.operating_point(), note=True)
    try:
        model, device = load_for(options.model, source.frame_size(), options.run.lanes)
        check_run_size(model, source.frame_size(), device, options.run.lanes, getattr(source, "trajectories", None))
        classes = class_count(model_config(model, "view"))
        names, palette = class_info(classes, "flight") if classes else ((), None)
        recording = RerunSink(
            options.rrd,
            class_names=names,
            palette=palette,
            absolute_poses=getattr(source, "flight", None) is not None,
            command="view",
        )
    except BaseException:
        source.close()
        raise
    streamer = make_streamer(model, policy, min_baseline, source)
    total = source.total_frames(options.run.max_frames) if hasattr(source, "total_frames") else None
    bar = tqdm(total=total, unit="frame", desc="view", disable=not options.run.progress, leave=False)
    try:
        summary = pipeline.run(
            source,
            streamer,
            [recording, StatusSink()],
            lanes=options.run.lanes,
            max_frames=options.run.max_frames,
            num_workers=options.run.workers,
            progress=lambda batch: bar.update(len(batch)),
        )
    finally:
        bar.close()
    rrd = options.rrd
    lines = [
        f"wrote a rerun recording of {summary['rerun']['frames']} frames to {rrd}; open it with: rerun {rrd}"
        + source_report(source)
    ]
    if summary["frames_by_status"]:
        lines.append(depth_report(summary["frames_by_status"], policy_info(streamer), summary["valid_fractions"]))
    return CommandResult(summary, lines)


__all__ = ["ViewOptions", "run_view"]
