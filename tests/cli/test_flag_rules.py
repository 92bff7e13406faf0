"""The table of which flags apply to which input source: every flag given that does not apply is refused with one
line naming the flag and the source (exit 2, before anything is read); every flag that applies passes the check."""

from __future__ import annotations

import argparse

import pytest

from cosemdepth.cli import flag_rules
from cosemdepth.cli.flag_rules import RULES
from cosemdepth.cli.main import build_parser, main
from cosemdepth.errors import ConfigError

#: the smallest command line choosing each source of each command in the table (nothing is read: the check runs
#: before the command does)
BASE = {
    ("predict", "--dataset"): ["--model", "M", "--dataset", "synthair", "--root", "R", "--out", "O"],
    ("predict", "--flight"): ["--model", "M", "--flight", "--out", "O"],
    ("predict", "--bag"): ["--model", "M", "--bag", "B", "--out", "O"],
    ("view", "--dataset"): ["--model", "M", "--dataset", "synthair", "--root", "R", "--rrd", "x.rrd"],
    ("view", "--flight"): ["--model", "M", "--flight", "--rrd", "x.rrd"],
    ("view", "--bag"): ["--model", "M", "--bag", "B", "--rrd", "x.rrd"],
    ("demo", flag_rules.GENERATED): ["--out", "O"],
    ("demo", "--data-root"): ["--out", "O", "--data-root", "R"],
    ("benchmark", flag_rules.FRESH): [],
    ("benchmark", "--model"): ["--model", "M"],
    ("export", flag_rules.FRESH): ["--onnx", "x.onnx"],
    ("export", "--model"): ["--onnx", "x.onnx", "--model", "M"],
    ("splits", "midair"): ["midair", "R", "O"],
    ("splits", "synthair"): ["synthair", "R", "O"],
    ("splits", "topair"): ["topair", "R", "O"],
}


def actions(command: str) -> dict[str, argparse.Action]:
    parser = build_parser(only=command)
    sub = next(a for a in parser._actions if a.dest == "command").choices[command]
    return {o: a for a in sub._actions for o in a.option_strings}


def flag_argv(action: argparse.Action, flag: str) -> list[str]:
    """``flag`` with a value its parser accepts."""
    if action.nargs == 0:
        return [flag]
    value = str(next(iter(action.choices))) if action.choices else "1"
    return [flag, *[value] * (action.nargs if isinstance(action.nargs, int) else 1)]


def base_flags(command: str, source: str) -> set[str]:
    return {a for a in BASE[command, source] if a.startswith("--")}


CASES = [(c, s.label) for c, rules in RULES.items() for s in rules.sources]
REFUSED = [
    (c, s, flag)
    for c, s in CASES
    for flag, where in RULES[c].applies.items()
    if s not in where and flag not in RULES[c].not_taken and flag not in base_flags(c, s)
]
NOT_TAKEN = [(c, flag) for c, rules in RULES.items() for flag in rules.not_taken]


def test_every_source_has_a_command_line_and_every_flag_exists():
    assert sorted(BASE) == sorted(CASES)
    for command, rules in RULES.items():
        known = actions(command)
        for flag in [*rules.applies, *rules.not_taken]:
            assert flag in known, (command, flag)


@pytest.mark.parametrize("command, source, flag", REFUSED)
def test_a_flag_that_does_not_apply_is_refused(command, source, flag, capsys):
    argv = [command, *BASE[command, source], *flag_argv(actions(command)[flag], flag)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    where = ", ".join(RULES[command].applies[flag])
    assert err == [f"cosemdepth {command}: error: {flag} does not apply to {source} (only to {where})"]


@pytest.mark.parametrize("command, flag", NOT_TAKEN)
def test_a_flag_the_command_does_not_take_is_refused(command, flag, capsys):
    source = RULES[command].sources[0].label
    assert main([command, *BASE[command, source], *flag_argv(actions(command)[flag], flag)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"cosemdepth {command}: error: {flag} does not apply to {command}: ")


@pytest.mark.parametrize("command, source", CASES)
def test_the_flags_that_apply_pass(command, source):
    known = actions(command)
    rules = RULES[command]
    flags = [f for f, where in rules.applies.items() if source in where and f not in rules.not_taken]
    argv = [command, *BASE[command, source]]
    for flag in flags:
        if flag not in base_flags(command, source):
            argv += flag_argv(known[flag], flag)
    args = build_parser(only=command).parse_args(argv)
    assert set(flags) <= set(flag_rules.explicit(args))
    flag_rules.check(command, args)  # no error


def test_given_is_not_judged_by_the_value():
    """A flag given with its default value is given; a flag left out is not, whatever its default."""
    parse = build_parser(only="predict").parse_args
    args = parse(["predict", *BASE["predict", "--dataset"], "--frame-skip", "1", "--max-frames", "3"])
    assert list(flag_rules.explicit(args)) == [
        "--model",
        "--dataset",
        "--root",
        "--out",
        "--frame-skip",
        "--max-frames",
    ]
    with pytest.raises(ConfigError, match=r"^--frame-skip does not apply to --dataset \(only to --flight, --bag\)$"):
        flag_rules.check("predict", args)
    args = parse(["predict", *BASE["predict", "--dataset"]])
    assert args.frame_skip == 1 and "--frame-skip" not in flag_rules.explicit(args)
    flag_rules.check("predict", args)


def test_two_sources_and_abbreviations(capsys):
    assert main(["predict", "--model", "M", "--flight", "--bag", "B", "--out", "O"]) == 2
    assert capsys.readouterr().err.strip() == (
        "cosemdepth predict: error: give only one of --dataset, --flight, --bag (got --flight and --bag)"
    )
    # an abbreviated flag is recorded under its full name
    assert main(["predict", *BASE["predict", "--dataset"], "--hf", "90"]) == 2
    assert "--hfov does not apply to --dataset" in capsys.readouterr().err


def test_help_states_where_a_flag_applies():
    known = actions("predict")
    assert known["--max-pose-gap"].help.endswith("[applies to --flight, --bag]")
    assert known["--image-topic"].help.endswith("[applies to --bag]")
    assert "[applies" not in known["--size"].help
    assert actions("demo")["--frames"].help.endswith(f"[applies to {flag_rules.GENERATED}]")


def test_the_docs_table_is_the_code_table():
    """docs/data.md's table of predict's inputs states RULES['predict'] (every restricted flag, its sources)."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "data.md").read_text()
    section = text.split("## Which flags apply to which input", 1)[1].split("\n## ", 1)[0]
    header, *rows = [ln for ln in section.splitlines() if ln.startswith("| `--") or ln.startswith("| flag |")]
    sources = [c.strip(" `") for c in header.strip("|").split("|")[1:]]
    documented = {}
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        if cells[0].startswith("every other flag"):
            continue
        where = tuple(s for s, c in zip(sources, cells[1:]) if c == "yes")
        for flag in re.findall(r"`(--[a-z-]+)`", cells[0]):
            documented[flag] = where
    assert documented == dict(RULES["predict"].applies)
