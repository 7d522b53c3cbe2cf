"""The ``vmehil`` command line. Each subcommand lives in :mod:`vmehil.commands`."""

from __future__ import annotations

import argparse
import importlib
import sys

from hal.config import ConfigError
from hal.vme.errors import VmeError

# Subcommand modules; each defines ``register(subparsers)`` that sets ``func`` on its parser.
COMMAND_MODULES = [
    "vmehil.commands.crate",
    "vmehil.commands.run",
    "vmehil.commands.tune",
    "vmehil.commands.vision",
    "vmehil.commands.plant_node",
    "vmehil.commands.console",
    "vmehil.commands.calibrate",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="vmehil",
        description="VME hardware-in-the-loop emulation, drivers and servo tools for robot joints.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


class CliError(Exception):
    """A user-facing error: printed without a traceback, exit status 2."""


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (CliError, ConfigError, VmeError, FileNotFoundError, ValueError) as e:
        print(f"vmehil {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"vmehil {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
