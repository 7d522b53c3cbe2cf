"""The house style of every `vmehil` parser, applied once to the whole tree of parsers.

* an error is two lines — what is wrong, and where the options are — not the full usage first
  (`vmehil run`'s usage alone is 20 lines);
* every command has a description (its one-line help when it has none of its own), in plain text:
  the reST markup of the docstrings it may come from (````x````, ``:mod:`x```) is removed;
* every option that takes a value shows one metavar, the same for the same flag everywhere
  (:data:`METAVARS`; an option may still set its own, e.g. ``--out DIR`` against ``--out PATH``).
"""

from __future__ import annotations

import argparse
import re
from typing import NoReturn

#: the metavar of a flag whose option does not set one (and has no choices to show instead)
METAVARS: dict[str, str] = {
    "--json": "PATH", "--motion": "PATH", "--seed": "N", "--duration": "S", "--unit-timeout": "S",
    "--start-timeout": "S", "--jobs": "N", "--joint": "N", "--points": "N", "--verify-per-segment": "N",
    "--unit": "NAME", "--interface": "NAME", "--channel": "NAME", "--gains": "kp=..,kpi=..,kv=..,kvi=..",
    "--bus": "emulated|vme_user[:DIR]", "--hold": "S", "--move-deg": "DEG", "--step-deg": "DEG",
    "--settle-band-deg": "DEG", "--samples": "N", "--switch-off-kp": "KP", "--width": "BITS", "--x": "GAIN",
    "--y": "GAIN",
}

_REST = (re.compile(r"``([^`]+)``"), re.compile(r":\w+:`~?([^`]+)`"))


class VmehilArgumentParser(argparse.ArgumentParser):
    """argparse's parser with a short error: the message and where the options are."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n(`{self.prog} --help` lists the options)\n")


def plain(text: str) -> str:
    """``text`` without reST inline markup (literals, roles)."""
    for pattern in _REST:
        text = pattern.sub(r"\1", text)
    return text


def apply(parser: argparse.ArgumentParser) -> None:
    """Give ``parser`` and every parser below it the house style (see the module docstring)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                sub.description = plain(sub.description or helps.get(name) or "")
                apply(sub)
        elif (action.option_strings and action.nargs != 0 and action.metavar is None and action.choices is None
              and not isinstance(action, argparse._HelpAction | argparse._VersionAction)):
            action.metavar = METAVARS.get(action.option_strings[-1])
