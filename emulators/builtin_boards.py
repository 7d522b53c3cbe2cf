"""Registers the built-in board types with :mod:`emulators.registry`."""

from __future__ import annotations

from emulators.bit3 import bit3_factory
from emulators.ram import RamBoard
from emulators.registry import BuildContext, register_board_type
from hal.config import ConfigTable


def _ram(name: str, cfg: ConfigTable, ctx: BuildContext) -> RamBoard:
    return RamBoard(name, cfg.int("size", min=1, max=1 << 32))


register_board_type("ram", _ram)
register_board_type("bit3", bit3_factory)
