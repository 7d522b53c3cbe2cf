"""Running the drivers and the loop on a real VME bus (``--bus vme_user[:DIR]``).

Before anything can enable an amplifier on a real crate:

1. :func:`dry_pass` reads every board of the rig file's ``[crate]`` through its board type's
   probe (:mod:`hal.board_types`) — its ID register against the ID the type declares, and its
   first status/control register — and refuses the rig if any read fails or any ID differs
   (wrong base, wrong space, board missing or another board there: named, with the one the rig
   file names), or if it names a PCI card (the SBS 617: not on the VME bus, never read);
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

from hal.board_types import BOARD_TYPES, BoardType, types_answering
from hal.config import ConfigError
from hal.errors import HalError
from hal.plugins import UnknownPluginError
from hal.vme.bus import VmeBus
from hal.vme.errors import VmeError
from hal.vme.types import AddressSpace, Width
from hal.vme.vme_user import VmeUserBus, parse_bus_spec
from servo.boundary import WallClockPlant
from servo.io import JointIO
from servo.nominal import nominal_scaling, rig_nominal
from servo.rig import RigSpec
from vmehil.errors import VmehilError


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
    #: the rig's board type's entry (None: a type the driver-side table does not know)
    board_type: BoardType | None = None

    def as_dict(self) -> dict[str, Any]:
        meta: dict[str, str | None] = {"vendor": None, "model": None, "document": None}
        if self.board_type is not None:
            meta.update(self.board_type.metadata())
        return {"name": self.name, "type": self.type, **meta, "space": self.space, "base": f"0x{self.base:X}",
                "ok": self.ok, "detail": self.detail}


def dry_pass(bus: VmeBus, rig: RigSpec) -> list[BoardCheck]:
    """Identify every board by its type's probe (``hal.board_types``: the ID register and the
    first status register; reads only, nothing is written). A wrong ID names both boards: the one
    the rig file names and, where the ID read is another known type's, the one in the slot."""
    checks = []
    for b in rig_boards(rig):
        name, type_name, base = b["name"], b["type"], b["base"]
        space = AddressSpace.parse(b["space"])
        try:
            board_type = BOARD_TYPES[type_name]
        except UnknownPluginError as e:
            checks.append(BoardCheck(name, type_name, b["space"], base, False, str(e)))
            continue
        if board_type.bus != "vme":
            checks.append(BoardCheck(name, type_name, b["space"], base, False, not_on_the_vme_bus(board_type),
                                     board_type))
            continue
        probe = board_type.load_probe()
        if probe is None:  # e.g. RAM: no ID register; it must answer at its base
            try:
                v = bus.read(base, space=space, width=Width.D16)
                checks.append(BoardCheck(name, type_name, b["space"], base, True,
                                         f"no ID register ({type_name}); answers at its base: 0x{v:X}",
                                         board_type))
            except VmeError as e:
                checks.append(BoardCheck(name, type_name, b["space"], base, False, str(e), board_type))
            continue
        reading = probe(bus, base, space)
        detail = reading.detail
        if reading.id_read is not None and reading.id_expected is not None and reading.id_read != reading.id_expected:
            detail = _wrong_board(type_name, board_type, reading.id_expected, reading.id_read)
        checks.append(BoardCheck(name, type_name, b["space"], base, reading.ok, detail, board_type))
    return checks


def not_on_the_vme_bus(board_type: BoardType) -> str:
    """Why the dry pass refuses a PCI card without a bus cycle: its BARs stand in the emulated
    crate's A32 space, but on a VME bus those addresses are other boards' (docs/vme-user.md,
    "Rigs with a PCI card")."""
    return (f"a {board_type.bus.upper()} card in the host, not a VME board ({board_type.describe()}): its "
            "registers are the host's PCI BARs, which vme_user cannot reach (vmehil has no PCI-BAR backend "
            "yet); to run on this bus, use a rig file without it (nothing uses it there: --vision needs the "
            "emulated rig)")


def _wrong_board(type_name: str, expected: BoardType, id_expected: int, id_read: int) -> str:
    """``ID reads 0xDA08, the rig's adc has 0xAD16: the rig file names type adc (ADC16-REF ...);
    the slot holds type dac (DAC8-REF ...)`` — both boards, so the operator knows which card to move."""
    text = f"ID reads 0x{id_read:X}, the rig's {type_name} has 0x{id_expected:X}"
    want = f"the rig file names type {type_name} ({expected.describe()}, ID 0x{id_expected:X})"
    reg = expected.id_register()
    held = types_answering(reg.offset, reg.width, id_read) if reg is not None else []
    if held:
        got = " or ".join(f"type {t} ({BOARD_TYPES[t].describe()}, ID 0x{id_read:X})" for t in held)
        return f"{text}: {want}; the slot holds {got}"
    return f"{text}: {want}; the slot holds a board of no known type (ID 0x{id_read:X})"


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
