"""``evaluate`` as a library: the test protocol (:mod:`cosemdepth.evaluation.evaluator`) on a dataset split from a
:class:`EvaluateOptions`; :func:`run_evaluate` is what ``cosemdepth evaluate`` runs once its arguments are parsed."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from ..data.registry import dataset_spec
from ..evaluation.evaluator import evaluate
from ..inference.policy import EVERY_FRAME
from ..output_safety.staging import OutputFiles
from ..streaming.sources.dataset import DatasetOptions
from .model import ModelOptions, check_run_size, load_for
from .options import CommandResult, RunOptions, open_source

#: The files ``evaluate --out DIR`` writes.
METRICS_FILES = ("metrics.json", "metrics.md")


@dataclass(frozen=True)
class EvaluateOptions:
    """Everything ``cosemdepth evaluate`` runs on, checked at construction: the split (``source``), the ``model``,
    the ``run`` options (the policy defaults to every-frame, the paper's protocol) and ``out``, the folder of
    ``metrics.json`` and ``metrics.md`` (None: the report is only printed)."""

    source: DatasetOptions
    model: ModelOptions
    run: RunOptions = field(default_factory=RunOptions)
    out: Optional[Path] = None


def run_evaluate(options: EvaluateOptions) -> CommandResult:
    """``cosemdepth evaluate``: the output folder checked, the split at the model's size, the model, the protocol;
    the results written into ``out`` (both files renamed into place together at the end). ``manifest`` is the
    result's JSON content; ``lines`` the Markdown report."""
    options.model.apply_threads()
    policy, min_baseline = options.run.stream_policy(EVERY_FRAME)
    inputs = [*options.model.inputs(), *options.source.inputs()]
    files_ctx = (
        OutputFiles(options.out, "--out folder", command="evaluate", names=METRICS_FILES, inputs=inputs)
        if options.out
        else contextlib.nullcontext()
    )
    with files_ctx as files:
        source = open_source(options.source, options.run, options.model.operating_point())
        dataset = source.dataset
        model, device = load_for(options.model, source.frame_size(), options.run.lanes)
        check_run_size(model, source.frame_size(), device, options.run.lanes, source.trajectories)
        result = evaluate(
            model,
            dataset,
            lanes=options.run.lanes,
            max_frames=options.run.max_frames,
            num_workers=options.run.workers,
            progress=options.run.progress,
            dataset_name=options.source.dataset,
            policy=policy,
            min_baseline=min_baseline,
        )
        result.info["model"].update(path=str(options.model.path), name=Path(str(options.model.path)).name)
        result.info["dataset"].update(
            root=str(options.source.root),
            split=options.source.split or dataset_spec(options.source.dataset).split,
            split_dir=None if options.source.split_dir is None else str(options.source.split_dir),
        )
        if getattr(dataset, "calibration", None):
            result.info["dataset"]["undistortion"] = dataset.calibration
        text = result.to_markdown()
        if files is not None:
            files.add_text("metrics.json", result.to_json())
            files.add_text("metrics.md", text)
    lines = [text]
    if options.out:
        lines.append(f"wrote {Path(options.out) / 'metrics.json'} and {Path(options.out) / 'metrics.md'}")
    no_depth = result.depth_warning()
    return CommandResult(result.to_dict(), lines, [f"cosemdepth evaluate: warning: {no_depth}"] if no_depth else [])


__all__ = ["EvaluateOptions", "METRICS_FILES", "run_evaluate"]
