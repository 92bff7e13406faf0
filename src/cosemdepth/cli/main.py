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

from ..errors import CosemdepthError
from . import flag_rules

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
    "export": ("cosemdepth.cli.export", "export the streaming model to ONNX"),
}


#: Commands run with OpenMP threads that sleep rather than spin while waiting (``OMP_WAIT_POLICY=PASSIVE``, unless
#: the user set it): on a machine whose cores are shared with other processes, spinning threads made model steps
#: 2-7x slower (measured on the 2-core dev machine: 0.43 s vs 0.18 s per 128x128 frame with 2 threads under load);
#: on an idle machine the difference is within noise. It must be set before torch is imported.
PASSIVE_WAIT_COMMANDS = ("demo", "evaluate", "predict", "view")


def _available() -> dict[str, tuple[str, str]]:
    out = {}
    for name, (mod, help_) in COMMANDS.items():
        if importlib.util.find_spec(mod) is not None:
            out[name] = (mod, help_)
    return out


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The ``cosemdepth`` parser; ``only``: configure just this command's arguments ("": none; None: all)."""
    parser = argparse.ArgumentParser(
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
    argv = list(sys.argv[1:] if argv is None else argv)
    first = next((a for a in argv if not a.startswith("-")), None)
    if first in PASSIVE_WAIT_COMMANDS and "torch" not in sys.modules:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    # only the command being run gets its arguments (without one, `cosemdepth --help` lists the commands)
    parser = build_parser(only=first if first in COMMANDS else "")
    args = parser.parse_args(argv)
    module = importlib.import_module(COMMANDS[args.command][0])
    try:
        flag_rules.check(args.command, args)  # a flag given that does not apply to the chosen input: exit 2
        return int(module.run(args) or 0)
    except CosemdepthError as e:
        # one line, whatever a wrapped library message holds (YAML and JSON parsers put line breaks in theirs)
        text = "; ".join(part.strip() for part in str(e).splitlines() if part.strip())
        print(f"cosemdepth {args.command}: error: {text}", file=sys.stderr)
        return 2
    except OSError as e:
        # a file system error about a path the user gave (permissions, a file vanished, disk full): one line. An
        # OSError that names no file is not about a user path; it stays a traceback (an internal bug to report).
        if e.filename is None:
            raise
        where = e.filename if e.filename2 is None else f"{e.filename} -> {e.filename2}"
        print(f"cosemdepth {args.command}: error: {where}: {e.strerror or e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"cosemdepth {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
