"""The board types crate files can name (``type = "adc"``): the built-in table, plus the entry
points of group ``vmehil.board_types`` that installed distributions declare (docs/architecture.md).

The emulator factories only: the driver side's table of the same names (role, vendor, model,
document, driver and probe) is ``hal.board_types.BOARD_TYPES``; tests/test_board_types.py checks
that the two name the same types. ``ram`` is in both, though no driver drives it (memory)."""

from __future__ import annotations

from typing import Any

from emulators.adc import adc_factory
from emulators.bit3 import bit3_factory
from emulators.board_factory import BoardFactory, BuildContext
from emulators.dac import dac_factory
from emulators.pio import pio_from_config
from emulators.quadrature import quad_from_config
from emulators.ram import RamBoard
from emulators.sbs617 import sbs617_factory
from emulators.vmivme2536 import vmivme2536_from_config
from emulators.vmivme3113a import vmivme3113a_factory
from emulators.vmivme4116 import vmivme4116_factory
from hal.config import ConfigTable
from hal.plugins import PluginTable


def _ram(name: str, cfg: ConfigTable, ctx: BuildContext) -> RamBoard:
    return RamBoard(name, cfg.get_int("size", min=1, max=1 << 32))


BUILTIN_BOARD_TYPES: dict[str, BoardFactory] = {
    "ram": _ram,
    "adc": adc_factory,
    "dac": dac_factory,
    "pio": pio_from_config,
    "quad": quad_from_config,
    "bit3": bit3_factory,
    "vmivme-4116": vmivme4116_factory,
    "vmivme-2536": vmivme2536_from_config,
    "sbs617": sbs617_factory,
    "vmivme-3113a": vmivme3113a_factory,
}


def _factory(name: str, obj: Any) -> BoardFactory:
    if not callable(obj):
        raise TypeError(f"a board type is a factory (name, cfg, ctx) -> Board, not {type(obj).__name__}")
    return obj


BOARD_TYPES: PluginTable[BoardFactory] = PluginTable("vmehil.board_types", "board type", BUILTIN_BOARD_TYPES,
                                                     _factory)
