"""``cosemdepth`` command dispatcher.

Each sub-command lives in its own module ``cosemdepth.cli.<name>`` exposing ``configure(parser)`` (add the
arguments) and ``run(args) -> int``. Modules are imported lazily so that ``cosemdepth synth --help`` does not pay
for importing everything.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import sys

from ..plugins import load_plugins
from . import flag_rules
from ._boundary import error_line

#: name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "convert": ("cosemdepth.cli.convert", "convert an official TensorFlow checkpoint to our format"),
    "synth": ("cosemdepth.cli.synth", "generate a SynthAir dataset (procedural aerial flights, Mid-Air format)"),
    "splits": ("cosemdepth.cli.splits", "write the train/val/test split CSVs of a dataset"),
    "train": ("cosemdepth.cli.train", "train a model"),
    "evaluate": ("cosemdepth.cli.evaluate", "evaluate a model on a test split"),
    "predict": ("cosemdepth.cli.predict", "run a model on a split or on your own flight and write its outputs"),
    "view": ("cosemdepth.cli.view", "run a model over a flight and write a rerun recording (.rrd) of it"),
    "demo": ("cosemdepth.cli.demo", "the end-to-end demo on SynthAir"),
    "benchmark": ("cosemdepth.cli.benchmark", "measure speed and memory"),
    "fast-accuracy": ("cosemdepth.cli.fast_accuracy", "check the fast inference modes' accuracy against the reference"),
    "export": ("cosemdepth.cli.export", "export the streaming model to ONNX"),
    "node": ("cosemdepth.cli.node", "a live ROS 2 node: depth, validity and labels for a camera (no ROS install)"),
    "replay": ("cosemdepth.cli.replay", "publish a ROS 2 bag's topics into the live ROS 2 graph at their rate"),
}


#: Commands run with OpenMP threads that sleep rather than spin while waiting (``OMP_WAIT_POLICY=PASSIVE``, unless
#: the user set it): on a machine whose cores are shared with other processes, spinning threads make model steps
#: several times slower; on an idle machine the difference is within noise. It must be set before torch is imported.
PASSIVE_WAIT_COMMANDS = ("demo", "evaluate", "node", "predict", "view")


def _available() -> dict[str, tuple[str, str]]:
    out = {}
    for name, (mod, help_) in COMMANDS.items():
        if importlib.util.find_spec(mod) is not None:
            out[name] = (mod, help_)
    return out


#: Argument destinations that name a command's outputs (the error boundary names them when an error names no file).
OUTPUT_DESTS = ("out", "out_dir", "onnx", "rrd", "rerun", "json", "md", "data_dir")


class Parser(argparse.ArgumentParser):
    """An argument error is one line, ``cosemdepth CMD: error: ... (see cosemdepth CMD --help)``, exit 2 (the usage
    block stays for ``--help``)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The ``cosemdepth`` parser; ``only``: configure just this command's arguments ("": none; None: all)."""
    parser = Parser(
        prog="cosemdepth",
        description="Joint monocular depth and semantic segmentation for aerial image sequences.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (mod, help_) in _available().items():
        p = sub.add_parser(name, help=help_, description=help_)
        if only is None or only == name:
            importlib.import_module(mod).configure(p)
            flag_rules.track(p, name)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``cosemdepth <command> ...`` on ``argv`` (default: ``sys.argv[1:]``); returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    first = next((a for a in argv if not a.startswith("-")), None)
    if first in PASSIVE_WAIT_COMMANDS and "torch" not in sys.modules:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    command = first if first in COMMANDS else None
    parser = args = None
    try:
        load_plugins()  # further decoders register their tasks and architectures before the arguments are read
        # only the command being run gets its arguments (without one, `cosemdepth --help` lists the commands)
        parser = build_parser(only=command or "")
        args, unknown = parser.parse_known_args(argv)
        command = args.command
        if unknown:  # said by the command's own parser, as its other argument errors are
            _subparser(parser, command).error(f"unrecognized arguments: {' '.join(unknown)}")
        module = importlib.import_module(COMMANDS[command][0])
        flag_rules.check(args.command, args)  # a flag given that does not apply to the chosen input: exit 2
        return int(module.run(args) or 0)
    except KeyboardInterrupt:
        print(f"cosemdepth {command}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # the error boundary: input and environment problems are one line, bugs a traceback
        line = error_line(e, outputs(parser, args) if args is not None else [])
        if line is None:
            raise
        print(f"cosemdepth{' ' + command if command else ''}: error: {line}", file=sys.stderr)
        return 2


def _subparser(parser: argparse.ArgumentParser, command: str) -> argparse.ArgumentParser:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[command]


def outputs(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[str]:
    """The command's output arguments as given (``--out runs/a``), for messages."""
    sub = _subparser(parser, args.command)
    out = []
    for action in sub._actions:
        value = getattr(args, action.dest, None)
        if action.dest in OUTPUT_DESTS and value is not None and action.help != argparse.SUPPRESS:
            out.append(f"{action.option_strings[0]} {value}" if action.option_strings else str(value))
    return out


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
