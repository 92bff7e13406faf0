"""One streaming run: a source's frames through a :class:`~cosemdepth.inference.policy.Streamer` into sinks.

:func:`run` opens the sinks, iterates ``source.batches(...)``, calls ``streamer.step`` with the lanes' state (sliced
and reordered when a lane ends; a frame whose motion the source says is unusable for depth, ``depth_ok`` False, is
streamed as a reset: no depth, status reset, a new reference), stops on a non-finite output (naming the frame), hands
each
:class:`~cosemdepth.streaming.frames.StreamBatch` to every sink, closes them and returns their merged summaries. On
any exception every opened sink is aborted (nothing half-written) and the exception propagates.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Callable, Iterator, Optional, Sequence

import torch

from ..errors import ConfigError, NonFiniteOutputError
from ..inference.policy import Streamer
from ..models.outputs import RESET
from ..models.protocol import StreamingModel, model_device, model_dtype
from .frames import FrameBatch, Sink, Source, StreamBatch, with_outputs


def _slice_state(state, rows: list[int]):
    """The state of the samples ``rows`` (in that order)."""
    if state is None:
        return state
    if hasattr(state, "select"):
        return state.select(rows)
    if not state.flatten():
        return state
    idx = torch.tensor(rows, device=state.flatten()[0].device)
    return type(state)(**{k: tuple(t.index_select(0, idx) for t in v) for k, v in state.components.items()})


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def check_finite_outputs(heads: dict, frames: FrameBatch) -> None:
    """Raise :class:`NonFiniteOutputError` naming the first frame whose output (any decoder's head) holds NaN/inf."""
    for name, t in (heads or {}).items():
        if t is None:
            continue
        bad = ~torch.isfinite(t.reshape(t.shape[0], -1))
        rows = bad.any(dim=1).nonzero().flatten().tolist()
        if rows:
            b = rows[0]
            src = frames.name[b] if b < len(frames.name) else None
            where = f"{src} (" if src else ""
            where += f"dataset row {frames.index[b]}, trajectory {frames.trajectory[b]}, frame {int(frames.frame[b])}"
            where += ")" if src else ""
            raise NonFiniteOutputError(
                f"{where}: the model's {name} output holds NaN/inf ({int(bad[b].sum())} of {bad.shape[1]} values); "
                "the model weights or this input are broken; stopped, no output was written"
            )


def needs_depth_input(model: StreamingModel) -> bool:
    """Whether ``model`` (or the model a streamer drives) reads the ground-truth depth of every frame (its semantic
    decoder warps with it: ``semantic_time="gt"``)."""
    return bool(getattr(getattr(model, "config", None), "needs_depth_input", False))


def no_depth_where_not_ok(depth_ok, valid, status: list[str]):
    """``(valid, status)`` with nothing valid and the status ``reset`` on the rows whose ``depth_ok`` is False (the
    source could give no usable motion for them: the frame keeps its labels, not its depth)."""
    if depth_ok is None or valid is None or bool(depth_ok.all()):
        return valid, status
    bad = ~depth_ok.to(device=valid.device, dtype=torch.bool)
    valid = valid & ~bad.view(-1, *([1] * (valid.dim() - 1)))
    return valid, [RESET if b else s for s, b in zip(status, bad.tolist())]


def no_depth_below_floor(floor: float, baseline, valid, status: list[str], meta: list[dict]):
    """``valid`` with nothing valid on the rows (estimated or held) whose baseline from their reference frame is
    below ``floor`` (a source's ``min_baseline_m``: its positions cannot measure a shorter motion, so neither an
    estimate nor a carried depth rests on a measured motion), whatever the policy; each such row's ``meta`` gets a
    ``depth_invalid_reason``."""
    if not floor or baseline is None or valid is None:
        return valid
    below = (baseline.detach().reshape(-1).to(torch.float64) < floor).tolist()
    short = [b and s != RESET for b, s in zip(below, status)]
    if not any(short):
        return valid
    for b in (i for i, x in enumerate(short) if x):
        meta[b].setdefault(
            "depth_invalid_reason",
            f"the camera moved less than {floor:.3g} m from its reference frame, too little for the input's positions "
            "to measure (the source's min_baseline_m)",
        )
    mask = torch.tensor(short, device=valid.device).view(-1, *([1] * (valid.dim() - 1)))
    return valid & ~mask


def steps(
    source: Source,
    streamer: Streamer,
    *,
    lanes: int = 1,
    max_frames: Optional[int] = None,
    num_workers: int = 0,
) -> Iterator[StreamBatch]:
    """The streaming steps of :func:`run` as an iterator of :class:`~cosemdepth.streaming.frames.StreamBatch`
    (without sinks; the source is not closed)."""
    device = model_device(streamer)
    dtype = model_dtype(streamer)
    guided = needs_depth_input(streamer)
    floor = float(getattr(source, "min_baseline_m", 0.0) or 0.0)
    state = None
    prev_lanes: tuple[int, ...] = ()
    with torch.inference_mode():
        for frames in source.batches(lanes=lanes, max_frames=max_frames, num_workers=num_workers):
            if prev_lanes and tuple(frames.lanes) != prev_lanes:
                pos = {lane: i for i, lane in enumerate(prev_lanes)}
                state = _slice_state(state, [pos[lane] for lane in frames.lanes])
            prev_lanes = tuple(frames.lanes)
            rgb = frames.rgb.to(device=device, dtype=dtype)
            rot = frames.rot.to(device=device, dtype=dtype)
            trans = frames.trans.to(device=device, dtype=dtype)
            intr = frames.intrinsics.to(device=device, dtype=dtype)
            gt = {k: v.to(device) for k, v in frames.gt.items()}
            extra = {}
            if guided:
                if "depth" not in gt:
                    raise ConfigError(
                        "the model's semantic decoder warps the previous labels with the ground-truth "
                        "depth (semantic_time 'gt'), and this dataset has no depth"
                    )
                extra["guide_depth"] = gt["depth"].to(dtype=dtype)
            _sync(device)
            t0 = time.perf_counter()
            reset = frames.reset if frames.depth_ok is None else frames.reset | ~frames.depth_ok.bool()
            if frames.source_valid is not None:  # an undistorted image: no depth where it has no source pixel
                extra["source_valid"] = frames.source_valid.to(device)
            out, state = streamer.step(rgb, rot, trans, intr, reset.to(device), state, **extra)
            _sync(device)
            seconds = time.perf_counter() - t0
            heads = dict(getattr(out, "heads", None) or {})
            check_finite_outputs(heads, frames)
            valid, status = no_depth_where_not_ok(
                frames.depth_ok, getattr(out, "valid", None), list(getattr(out, "status", None) or ())
            )
            valid = no_depth_below_floor(floor, getattr(out, "baseline", None), valid, status, frames.meta)
            batch = with_outputs(
                frames,
                heads=heads,
                valid=valid,
                status=status,
                baseline=getattr(out, "baseline", None),
                seconds=seconds,
            )
            batch.rgb, batch.rot, batch.trans, batch.intrinsics, batch.gt = rgb, rot, trans, intr, gt
            batch.reset = reset
            yield batch


def run(
    source: Source,
    streamer: Streamer,
    sinks: Sequence[Sink] = (),
    *,
    lanes: int = 1,
    max_frames: Optional[int] = None,
    num_workers: int = 0,
    progress: Optional[Callable[[StreamBatch], None]] = None,
    out: Optional[Path] = None,
) -> dict[str, Any]:
    """Stream ``source`` through ``streamer`` into ``sinks`` (see the module docstring).

    Args:
        source: a :class:`~cosemdepth.streaming.frames.Source` (closed at the end).
        streamer: a :class:`~cosemdepth.inference.policy.Streamer` (its ``step``, with ``guide_depth`` for a model
            that reads the ground-truth depth, and its ``parameters()``: their device and dtype are the frames').
        sinks: :class:`~cosemdepth.streaming.frames.Sink` objects, fed in this order.
        lanes: trajectories streamed side by side (the batch size); max_frames: at most this many frames;
            num_workers: data-loading worker processes of the source.
        progress: called with every batch after the sinks (a progress bar's update).
        out: the folder the sinks write into (``Sink.open``; None: they write none).
    Returns:
        the sinks' summaries (``Sink.close``), merged in order.
    """
    opened: list = []
    summary: dict[str, Any] = {}
    try:
        for sink in sinks:
            sink.open(out)
            opened.append(sink)
        for batch in steps(source, streamer, lanes=lanes, max_frames=max_frames, num_workers=num_workers):
            for sink in sinks:
                sink(batch)
            if progress is not None:
                progress(batch)
        for sink in sinks:
            summary.update(sink.close() or {})
    except BaseException:
        for sink in opened:
            sink.abort()
        raise
    finally:
        source.close()
    return summary


__all__ = [
    "check_finite_outputs",
    "needs_depth_input",
    "no_depth_below_floor",
    "no_depth_where_not_ok",
    "run",
    "steps",
]
