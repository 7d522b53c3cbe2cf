"""Running the drivers and the loop on a real VME bus (``--bus vme_user[:DIR]``).

Before anything can enable an amplifier on a real crate:

1. :func:`dry_pass` reads every board of the rig file's ``[crate]`` — its ID register against
   the value the board type's register map declares, and its first status/control register —
   and refuses the rig if any read fails or any ID differs (wrong base, wrong space, board
   missing or another board there);
2. :func:`exercise_safe_stop` runs the safe stop once (enables low, DACs 0 V, PWM off) and
   reads it back (:meth:`servo.io.JointIO.safe_stop`): anything unconfirmed refuses the rig;
3. only with ``--enable-amplifiers`` does ``vmehil run`` go on to the loop; without it the run
   ends after 1 and 2 (a dry run).

The plant boundary is :class:`servo.boundary.WallClockPlant`: time passes by itself, there is
no emulated truth.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from hal.adc_dac import ADC_REGMAP, DAC_REGMAP
from hal.bit3 import BIT3_CSR
from hal.config import ConfigError
from hal.errors import HalError
from hal.pio import PIO_REGS
from hal.quadrature import QUAD_REGS
from hal.vme.bus import VmeBus
from hal.vme.errors import VmeError
from hal.vme.registers import RegisterMap
from hal.vme.types import AddressSpace, Width
from hal.vme.vme_user import VmeUserBus, parse_bus_spec
from servo.boundary import WallClockPlant
from servo.io import JointIO
from servo.nominal import nominal_scaling, rig_nominal
from servo.rig import RigSpec
from vmehil.errors import VmehilError

#: register maps of the board types a rig file names (the drivers' own declarations)
REGMAPS: dict[str, RegisterMap] = {"adc": ADC_REGMAP, "dac": DAC_REGMAP, "pio": PIO_REGS, "quad": QUAD_REGS,
                                   "bit3": BIT3_CSR}
_STATUS_NAMES = ("CSR", "STATUS", "CTRL", "CONTROL")


class RealBusRefused(VmehilError, RuntimeError):
    """The dry pass or the start-up safe stop found the crate unlike the rig file: nothing enabled."""


def is_real_bus(spec: str | None) -> bool:
    return bool(spec) and spec != "emulated"


def open_bus(spec: str, **options: Any) -> VmeUserBus:
    """``vme_user`` / ``vme_user:DIR`` → an open :class:`VmeUserBus`."""
    return VmeUserBus(parse_bus_spec(spec), **options)


def rig_boards(rig: RigSpec) -> list[dict[str, Any]]:
    """The rig file's boards: name, type, space, base."""
    return [{"name": b.get_str("name"), "type": b.get_str("type"), "space": b.get_str("space").upper(),
             "base": b.get_int("base")} for b in rig.table.table("crate").tables("board", [])]


@dataclass
class BoardCheck:
    name: str
    type: str
    space: str
    base: int
    ok: bool
    detail: str

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "type": self.type, "space": self.space, "base": f"0x{self.base:X}",
                "ok": self.ok, "detail": self.detail}


def dry_pass(bus: VmeBus, rig: RigSpec) -> list[BoardCheck]:
    """Read every board's ID and status (reads only; nothing is written)."""
    checks = []
    for b in rig_boards(rig):
        regmap = REGMAPS.get(b["type"])
        space = AddressSpace.parse(b["space"])
        if regmap is None:  # e.g. RAM: no ID register; it must answer at its base
            try:
                v = bus.read(b["base"], space=space, width=Width.D16)
                checks.append(BoardCheck(b["name"], b["type"], b["space"], b["base"], True,
                                         f"no ID register ({b['type']}); answers at its base: 0x{v:X}"))
            except VmeError as e:
                checks.append(BoardCheck(b["name"], b["type"], b["space"], b["base"], False, str(e)))
            continue
        parts, ok = [], True
        try:
            ident = regmap["ID"]
            got = bus.read(b["base"] + ident.offset, space=space, width=ident.width)
            if got != ident.reset:
                ok = False
                parts.append(f"ID reads 0x{got:X}, the rig's {b['type']} has 0x{ident.reset:X}")
            else:
                parts.append(f"ID 0x{got:X}")
            status = next((r for r in regmap.registers if r.name in _STATUS_NAMES and r.access.readable), None)
            if status is not None:
                v = bus.read(b["base"] + status.offset, space=space, width=status.width)
                parts.append(f"{status.name} 0x{v:X}")
        except (VmeError, KeyError) as e:
            ok = False
            parts.append(f"{type(e).__name__}: {e}")
        checks.append(BoardCheck(b["name"], b["type"], b["space"], b["base"], ok, "; ".join(parts)))
    return checks


def exercise_safe_stop(io: JointIO) -> list[str]:
    """Run the safe stop once and read it back; returns what could not be confirmed."""
    return io.safe_stop()


@dataclass
class RealRig:
    """A rig on a real bus: what :func:`vmehil.rig_setup.session.build_loop` and the runners need (a
    :class:`servo.boundary.PlantBoundary` with the rig and its drivers)."""

    rig: RigSpec
    bus: VmeBus
    io: JointIO
    boundary: WallClockPlant

    # --- servo.boundary.PlantBoundary, by the wall clock ------------------------------------
    @property
    def joints(self) -> list[str]:
        return list(self.boundary.joints)

    @property
    def period_s(self) -> float:
        return self.boundary.period_s

    @property
    def computation_delay_s(self) -> float:
        return self.boundary.computation_delay_s

    def advance_to(self, t_ns: int) -> None:
        self.boundary.advance_to(t_ns)

    def sense(self, tick: int) -> None:
        self.boundary.sense(tick)

    def exchange(self, tick: int) -> None:
        self.boundary.exchange(tick)

    def truth(self) -> None:
        return None

    @property
    def answer_lag_ticks(self) -> int:
        return self.boundary.answer_lag_ticks

    @property
    def sample_clock(self) -> Callable[[], float | None] | None:
        return self.boundary.sample_clock

    def close(self) -> None:
        close = getattr(self.bus, "close", None)
        if close is not None:
            close()


def prepare_real_rig(rig: RigSpec, bus: VmeBus, *, calibration: Any = None) -> tuple[RealRig, list[BoardCheck]]:
    """Dry pass, drivers, start-up safe stop: raise :class:`RealBusRefused` on any doubt.
    ``calibration``: the drivers' calibration store (None: nominal values)."""
    checks = dry_pass(bus, rig)
    bad = [c for c in checks if not c.ok]
    if bad:
        raise RealBusRefused("dry pass failed, nothing enabled: "
                             + "; ".join(f"{c.name} ({c.type} {c.space} 0x{c.base:X}): {c.detail}" for c in bad))
    try:
        io = JointIO(bus, rig, nominal_scaling(rig_nominal(rig)), calibration=calibration)
        failures = exercise_safe_stop(io)
    except HalError as e:
        if isinstance(e, ConfigError):
            raise  # the rig file's wiring: bad input, said as such
        # a driver that fails while it is set up (an ADC conversion that never finishes, a short
        # write): the crate is not what the rig needs — refused like a failed dry pass (exit 1)
        raise RealBusRefused(f"setting up the drivers failed, nothing enabled: {type(e).__name__}: {e}") from e
    if failures:
        raise RealBusRefused("the start-up safe stop could not be confirmed: " + "; ".join(failures))
    boundary = WallClockPlant([j.name for j in rig.joints], rig.period_s, rig.computation_delay_s)
    return RealRig(rig, bus, io, boundary), checks
