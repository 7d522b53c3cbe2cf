"""Build a :class:`Crate` from a TOML crate description (a crate file or a rig file's ``[crate]``).

Schema::

    [crate]
    name = "jpl-rack"
    bus_timeout_us = 64          # optional

    [[crate.board]]
    type = "ram"                 # a board type: built in or an entry point (see `vmehil crate types`)
    name = "ram0"                # unique in the crate
    slot = 3                     # optional, 1..21
    space = "A24"                # A16, A24 or A32
    base = 0x200000
    # ... type-specific keys (e.g. size for "ram")
"""

from __future__ import annotations

from pathlib import Path

from emulators.board_factory import BuildContext
from emulators.board_types import BOARD_TYPES
from emulators.crate import Crate
from emulators.signals import Signals
from hal.config import ConfigError, ConfigTable, load_toml
from hal.vme.errors import VmeConfigError
from hal.vme.types import AddressSpace

_COMMON_KEYS = {"type", "name", "slot", "space", "base"}


def build_crate(cfg: ConfigTable, *, signals: Signals | None = None, seed: int = 0) -> Crate:
    """Build a crate from the table that contains ``[crate]``."""
    crate_cfg = cfg.table("crate")
    timeout_us = crate_cfg.get_float("bus_timeout_us", 64.0, min=1.0, max=10_000.0)
    crate = Crate(
        crate_cfg.get_str("name", "crate"), bus_timeout_ns=round(timeout_us * 1000), signals=signals
    )
    ctx = BuildContext(signals=crate.signals, seed=seed)
    for bcfg in crate_cfg.tables("board", []):
        type_name = bcfg.get_str("type")
        factory = BOARD_TYPES.get(type_name)
        if factory is None:
            raise bcfg.error("type", "a board type (" + ", ".join(BOARD_TYPES.names()) + ")", type_name)
        name = bcfg.get_str("name")
        try:
            space = AddressSpace.parse(bcfg.get_str("space"))
        except ValueError:
            raise bcfg.error("space", "A16, A24 or A32", bcfg.raw("space")) from None
        base = bcfg.get_int("base", min=0, max=(1 << 32) - 1)
        slot = bcfg.get_int("slot", None, min=1, max=21) if "slot" in bcfg else None
        board = factory(name, bcfg, ctx)
        bcfg.check_unknown()
        try:
            crate.install(board, base=base, space=space, slot=slot)
        except VmeConfigError as e:
            raise ConfigError(bcfg.source, bcfg.key("base"), f"a free window ({e})") from None
    crate_cfg.check_unknown({"name", "bus_timeout_us", "board"})
    return crate


def load_crate(path: str | Path, *, signals: Signals | None = None, seed: int = 0) -> Crate:
    """Read a crate (or rig) TOML file and build its crate."""
    return build_crate(load_toml(path), signals=signals, seed=seed)
