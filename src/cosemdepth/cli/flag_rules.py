"""Which flags apply to which input source: one table for every command with more than one kind of input.

A command's *sources* are its kinds of input (predict: ``--dataset``, ``--flight`` or ``--bag``; demo: a generated
flight or ``--data-root``...). :data:`RULES` names, per command, its sources and the flags that apply to some of
them only; a flag not in the table applies to every source. A flag given explicitly on the command line that does
not apply to the chosen source stops the command before anything is read: one line naming the flag and the source
(exit 2). "Given explicitly" is recorded while parsing (:func:`track`), so ``--max-pose-gap 0.05`` is refused with
``--dataset`` even though 0.05 is the bag default. Adding a flag to a command is one entry in its ``applies``; the
table is also what the flags' help texts and docs/data.md state.

``not_taken`` lists flags a command accepts only because it shares another command's arguments (view takes
predict's inputs but writes only ``--rrd``): given, they are refused too.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from typing import Mapping

from ..errors import ConfigError

#: the namespace attribute holding the flags given on the command line, in order (``{flag: None}``)
EXPLICIT = "_explicit_flags"


@dataclass(frozen=True)
class Source:
    """One kind of input of a command, named ``label`` in messages. It is chosen when the flag ``flag`` is given
    (``"--bag"``), or when the parsed ``dest`` equals ``value`` (a positional choice), or, with neither, when no
    other source is chosen (the default input)."""

    label: str
    flag: str | None = None
    dest: str | None = None
    value: object = None

    def chosen(self, args: argparse.Namespace, given: Mapping[str, None]) -> bool:
        if self.flag is not None:
            return self.flag in given
        if self.dest is not None:
            return getattr(args, self.dest, None) == self.value
        return False


@dataclass(frozen=True)
class CommandRules:
    """A command's ``sources`` and ``applies``: flag -> the labels of the sources it applies to (flags not listed
    apply to all); ``not_taken``: flag -> why the command does not use it."""

    sources: tuple[Source, ...]
    applies: Mapping[str, tuple[str, ...]]
    not_taken: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        labels = {s.label for s in self.sources}
        for flag, where in self.applies.items():
            unknown = set(where) - labels
            if unknown or not where:
                raise ValueError(f"flag rules: {flag} applies to unknown sources {sorted(unknown)}")

    def source(self, args: argparse.Namespace) -> Source | None:
        """The chosen source (None when the arguments choose none: the command's own checks say what is missing);
        a ConfigError when more than one is chosen."""
        given = explicit(args)
        chosen = [s for s in self.sources if s.chosen(args, given)]
        if len(chosen) > 1:
            raise ConfigError(
                f"give only one of {', '.join(s.label for s in self.sources if s.flag)} "
                f"(got {' and '.join(s.label for s in chosen)})"
            )
        if chosen:
            return chosen[0]
        return next((s for s in self.sources if s.flag is None and s.dest is None), None)


DATASET, FLIGHT, BAG = "--dataset", "--flight", "--bag"
_INPUTS = (Source(DATASET, flag="--dataset"), Source(FLIGHT, flag="--flight"), Source(BAG, flag="--bag"))
#: predict's and view's flags that apply to some of their inputs only
_INPUT_FLAGS: dict[str, tuple[str, ...]] = {
    "--root": (DATASET,),
    "--split-dir": (DATASET,),
    "--split": (DATASET,),
    "--images": (FLIGHT,),
    "--poses": (FLIGHT,),
    "--match": (FLIGHT,),
    "--stamp-unit": (FLIGHT,),
    "--intrinsics": (FLIGHT, BAG),
    "--hfov": (FLIGHT, BAG),
    "--convention": (FLIGHT, BAG),
    "--frame-skip": (FLIGHT, BAG),
    "--max-pose-gap": (FLIGHT, BAG),
    "--skip-unposed": (FLIGHT, BAG),
    "--log": (FLIGHT,),
    "--log-format": (FLIGHT,),
    "--time-offset": (FLIGHT,),
    "--camera-mount": (FLIGHT,),
    "--lever-arm": (FLIGHT,),
    "--image-topic": (BAG,),
    "--pose-topic": (BAG,),
    "--camera-info-topic": (BAG,),
    "--ignore-distortion": (BAG,),
    "--out-namespace": (BAG,),
}
_VIEW_WRITES = "view writes only the --rrd recording"
GENERATED, DATA_ROOT = "a generated flight, without --data-root", "--data-root"
WEIGHTS, FRESH = "--model", "a freshly initialised model, without --model"

RULES: dict[str, CommandRules] = {
    "predict": CommandRules(_INPUTS, _INPUT_FLAGS),
    "view": CommandRules(
        _INPUTS,
        _INPUT_FLAGS,
        not_taken={
            "--out": _VIEW_WRITES,
            "--video": _VIEW_WRITES,
            "--fps": _VIEW_WRITES,
            "--rerun": _VIEW_WRITES + " (give the file as --rrd)",
            "--overwrite": _VIEW_WRITES + " (an existing one is replaced only if cosemdepth wrote it)",
            "--out-namespace": _VIEW_WRITES + " (no output bag)",
            "--invalid": _VIEW_WRITES + " (its depth images draw no point where the depth is not valid)",
        },
    ),
    "demo": CommandRules(
        (Source(GENERATED), Source(DATA_ROOT, flag="--data-root")),
        {flag: (GENERATED,) for flag in ("--frames", "--seed", "--climate", "--supersample", "--data-dir")},
    ),
    "benchmark": CommandRules(
        (Source(FRESH), Source(WEIGHTS, flag="--model")),
        {"--models": (FRESH,), "--levels": (FRESH,), "--no-joint": (FRESH,)},
    ),
    "export": CommandRules(
        (Source(FRESH), Source(WEIGHTS, flag="--model")),
        {"--arch": (FRESH,), "--levels": (FRESH,), "--classes": (FRESH,)},
    ),
    "splits": CommandRules(
        tuple(Source(name, dest="dataset", value=name) for name in ("midair", "synthair", "topair")),
        {"--rule": ("midair", "synthair")},
    ),
}


def explicit(args: argparse.Namespace) -> Mapping[str, None]:
    """The flags given on the command line (their first long spelling), in order."""
    return getattr(args, EXPLICIT, None) or {}


def _flag_name(action: argparse.Action) -> str:
    return next((o for o in action.option_strings if o.startswith("--")), action.option_strings[0])


_RECORDING: dict[type, type] = {}


def _recording(cls: type) -> type:
    """``cls`` with a ``__call__`` that also records the flag in the namespace (argparse calls an action only
    when its flag is on the command line; defaults are set without calling it)."""
    if cls not in _RECORDING:

        def __call__(self, parser, namespace, values, option_string=None):
            cls.__call__(self, parser, namespace, values, option_string)
            setattr(namespace, EXPLICIT, {**explicit(namespace), _flag_name(self): None})

        _RECORDING[cls] = type(cls.__name__, (cls,), {"__call__": __call__})
    return _RECORDING[cls]


def track(parser: argparse.ArgumentParser, command: str) -> None:
    """Record the flags given to ``command``'s parser, and state in each restricted flag's help which sources it
    applies to. Commands without rules are left as they are."""
    rules = RULES.get(command)
    if rules is None:
        return
    for action in parser._actions:
        if not action.option_strings or isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            continue
        if type(action) not in _RECORDING.values():
            action.__class__ = _recording(type(action))
        where = rules.applies.get(_flag_name(action))
        if where is not None and action.help not in (None, argparse.SUPPRESS) and "[applies to" not in action.help:
            action.help += f" [applies to {', '.join(where)}]"


def check(command: str, args: argparse.Namespace) -> None:
    """A ConfigError naming the first flag given that does not apply to ``command`` with the chosen source."""
    rules = RULES.get(command)
    if rules is None:
        return
    given = explicit(args)
    for flag in given:
        if flag in rules.not_taken:
            raise ConfigError(f"{flag} does not apply to {command}: {rules.not_taken[flag]}")
    source = rules.source(args)
    if source is None:
        return
    for flag in given:
        where = rules.applies.get(flag)
        if where is not None and source.label not in where:
            raise ConfigError(f"{flag} does not apply to {source.label} (only to {', '.join(where)})")


__all__ = ["CommandRules", "EXPLICIT", "RULES", "Source", "check", "explicit", "track"]
