"""The house style of every `vmehil` parser (vmehil.cli_style)."""

from __future__ import annotations

import argparse
import re

import pytest

from vmehil.cli import build_parser, main


def _options(parser: argparse.ArgumentParser, name: str = "vmehil"):
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for n, sub in a.choices.items():
                yield from _options(sub, f"{name} {n}")
        elif a.option_strings and a.nargs != 0 and not isinstance(a, argparse._HelpAction | argparse._VersionAction):
            yield name, a


def _commands(parser: argparse.ArgumentParser, name: str = "vmehil"):
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for n, sub in a.choices.items():
                yield f"{name} {n}", sub
                yield from _commands(sub, f"{name} {n}")


def test_every_value_option_shows_a_metavar_and_one_flag_one_metavar() -> None:
    # `--unit-timeout UNIT_TIMEOUT`, `--json JSON` beside `--json PATH`
    seen: dict[str, set[str]] = {}
    for name, a in _options(build_parser()):
        if a.choices is None:
            assert a.metavar, f"{name} {a.option_strings[-1]} shows its dest as the metavar"
            seen.setdefault(a.option_strings[-1], set()).add(a.metavar)
    # two meanings, two metavars: --out is calibrate's file and tune sweep's directory; `run --motion`
    # also takes `none`, the unit processes' --motion only a file
    assert {flag: m for flag, m in seen.items() if len(m) > 1 and flag not in ("--out", "--motion")} == {}


def test_every_command_has_a_plain_description() -> None:
    # `unit` and `coordinate` had none; `reproduce --help` showed ``reST`` markup
    for name, sub in _commands(build_parser()):
        assert sub.description, name
        assert "``" not in sub.description and not re.search(r":\w+:`", sub.description), name


def test_a_bad_value_is_two_lines_not_the_whole_usage(capsys) -> None:
    # `vmehil run --duration -1` printed the 20-line usage before the one-line error
    with pytest.raises(SystemExit) as stop:
        main(["run", "--duration", "-1"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["vmehil run: error: argument --duration: -1: expected a duration in seconds in (0, 86400]",
                   "(`vmehil run --help` lists the options)"]


def test_a_missing_motion_file_names_the_file_not_a_key(capsys) -> None:
    # it said "/nonexistent.toml: key '<file>': expected an existing TOML file"
    assert main(["run", "--motion", "/nonexistent.toml", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "/nonexistent.toml: expected an existing TOML file" in err and "<file>" not in err
