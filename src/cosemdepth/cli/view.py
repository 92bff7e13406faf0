"""``cosemdepth view``: run a model over a flight (a ROS bag, your own images + poses, or a dataset split) and write
only a rerun recording of it (no viewer is started; open it with ``rerun FILE.rrd``).

    cosemdepth view --model MODEL --bag PATH --image-topic T --pose-topic T --camera-info-topic T --rrd FILE.rrd
    cosemdepth view --model MODEL --flight --images DIR --poses FILE --hfov DEG --rrd FILE.rrd
    cosemdepth view --model MODEL --dataset NAME --root ROOT --max-frames N --rrd FILE.rrd

It takes the inputs of ``predict`` (same arguments, same checks) because the recording needs what a prediction
folder does not keep (the input images, the intrinsics and the camera motion); ``predict ... --rerun FILE.rrd``
writes the same recording beside the usual files. Contents: :mod:`cosemdepth.streaming.sinks.rerun`. The arguments
become a :class:`~cosemdepth.jobs.view.ViewOptions`, run by :func:`cosemdepth.jobs.view.run_view`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..jobs.view import ViewOptions, run_view
from ._options import model_options, run_options, source_options
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


def options(args: argparse.Namespace) -> ViewOptions:
    """The :class:`~cosemdepth.jobs.view.ViewOptions` of the parsed arguments."""
    run = run_options(args)
    model = model_options(args)
    return ViewOptions(source=source_options(args), model=model, rrd=args.rrd, run=run)


def run(args: argparse.Namespace) -> int:
    for line in run_view(options(args)).lines:
        print(line)
    return 0
