"""``cosemdepth view``: run a model over a flight (a ROS bag, your own images + poses, or a dataset split) and write
only a rerun recording of it (no viewer is started; open it with ``rerun FILE.rrd``).

    cosemdepth view --model MODEL --bag PATH --image-topic T --pose-topic T --camera-info-topic T --rrd FILE.rrd
    cosemdepth view --model MODEL --flight --images DIR --poses FILE --hfov DEG --rrd FILE.rrd
    cosemdepth view --model MODEL --dataset NAME --root ROOT --max-frames N --rrd FILE.rrd

It takes the inputs of ``predict`` (same arguments, same checks) because the recording needs what a prediction
folder does not keep (the input images, the intrinsics and the camera motion); ``predict ... --rerun FILE.rrd``
writes the same recording beside the usual files. Contents: :mod:`cosemdepth.robotics.rerun_writer`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tqdm.auto import tqdm

from ..evaluation.streaming import make_schedule, stream, trajectory_rows
from ..inference.policy import Streamer, policy_info
from ..robotics.cli import make_sinks
from ..robotics.rerun_writer import check_rrd_path, require_rerun
from ._shared import apply_threads, check_run_size, load
from .predict import _open, _validate, command_inputs, depth_report, flight_report, input_policy
from .predict import configure as configure_predict

#: predict's arguments that do not apply to view (hidden from its help; refused when given: cli.flag_rules).
_PREDICT_ONLY = ("out", "video", "fps", "rerun", "out_namespace", "invalid")


def configure(parser: argparse.ArgumentParser) -> None:
    configure_predict(parser)
    for action in parser._actions:  # the inputs are predict's; its output options are not view's
        if action.dest in _PREDICT_ONLY:
            action.required = False
            action.help = argparse.SUPPRESS
    parser.add_argument(
        "--rrd",
        type=Path,
        required=True,
        metavar="FILE.rrd",
        help="the recording to write (a new file, or one cosemdepth wrote, which is replaced)",
    )


def run(args: argparse.Namespace) -> int:
    apply_threads(args)
    args.rerun = None  # view writes --rrd only
    require_rerun()
    _validate(args)
    policy, min_baseline = input_policy(args)
    check_rrd_path(args.rrd, option="--rrd", inputs=command_inputs(args))
    dataset = _open(args)
    model, device = load(args.model, args.device, fast=not args.reference, precision=args.precision)
    check_run_size(model, dataset, device, args.lanes)
    streamer = Streamer(model, policy, min_baseline=min_baseline)
    statuses: dict[str, int] = {}
    fractions: list[float] = []
    args.rerun = args.rrd
    (writer,) = make_sinks(args, dataset, model, bag_output=False)
    schedule = make_schedule(trajectory_rows(dataset, args.max_frames), args.lanes)
    bar = tqdm(
        total=sum(len(s.indices) for s in schedule),
        unit="frame",
        desc="view",
        disable=args.no_progress or not sys.stderr.isatty(),
        leave=False,
    )
    writer.open()
    try:
        for batch in stream(streamer, dataset, lanes=args.lanes, max_frames=args.max_frames, num_workers=args.workers):
            writer(batch)
            for b, st in enumerate(batch.status if batch.valid is not None else ()):
                statuses[st] = statuses.get(st, 0) + 1
                fractions.append(float(batch.valid[b].float().mean()))
            bar.update(len(batch))
        info = writer.close()
    except BaseException:
        writer.abort()
        raise
    finally:
        bar.close()
        flight = getattr(dataset, "bag_flight", None)
        if flight is not None:
            flight.close()
    print(
        f"wrote a rerun recording of {info['rerun']['frames']} frames to {args.rrd}; open it with: rerun {args.rrd}"
        + flight_report(dataset)
    )
    if statuses:
        print(depth_report(statuses, policy_info(streamer), fractions))
    return 0
