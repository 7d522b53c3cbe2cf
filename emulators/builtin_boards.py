"""Registers the built-in board types with :mod:`emulators.registry`."""

from __future__ import annotations

from emulators.adc import adc_factory
from emulators.bit3 import bit3_factory
from emulators.dac import dac_factory
from emulators.pio import pio_from_config
from emulators.quadrature import quad_from_config
from emulators.ram import RamBoard
from emulators.registry import BuildContext, register_board_type
from hal.config import ConfigTable


def _ram(name: str, cfg: ConfigTable, ctx: BuildContext) -> RamBoard:
    return RamBoard(name, cfg.get_int("size", min=1, max=1 << 32))


register_board_type("ram", _ram)
register_board_type("adc", adc_factory)
register_board_type("dac", dac_factory)
register_board_type("pio", pio_from_config)
register_board_type("quad", quad_from_config)
register_board_type("bit3", bit3_factory)
