"""Driver for the VMIC VMIVME-2536 (32 optically coupled inputs, 32 outputs): named lines from the
rig wiring table, the interface ``servo.io`` uses of the reference PIO driver for digital lines.

Spec: docs/boards/vmivme2536.md; register map :mod:`hal.pio.vmivme2536_regs`. The board has no
direction registers (``IN0``..``IN31`` are inputs, ``OUT0``..``OUT31`` outputs), no interrupt and
no PWM timer. ``OUTPUT`` reads back the latch, never the wire: an output can only be seen on its
wire when the rig loops it back into a spare input (``loopback``).

The driver keeps a copy of the output latch and writes it whole (never read-modify-write), and
activates the outputs (``CSR``) only after the latch holds the wanted levels.

Example::

    dio = Vmi2536Driver(bus, 0xFF00, lines={"j1.amp_enable": "OUT0", "j1.amp_fault": "IN0"},
                        loopback={"OUT0": "IN16"})
    dio.configure(outputs=["j1.amp_enable"])
    dio.set_line("j1.amp_enable", True)

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`Vmi2536Driver.from_lanes` stacks B drivers
(one per instance) into one on a bus of lanes: :meth:`~Vmi2536Driver.read_port` then returns a
word per lane (``(B,)`` int64, or an int when every lane reads the same) and
:meth:`~Vmi2536Driver.set_line` takes a level per lane. Where one instance's driver would raise
for some lanes only (a line whose latch or looped-back wire does not follow, a port value that is
not 32 bits), those lanes are ejected and the others go on; the cycles are the same in every lane.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from hal.board_types import ProbeReading
from hal.lanes import LaneSet, LaneValue, stack
from hal.pio.pio import LineDirectionError, LineStuckError, PioBoardIdError, UnknownLineError, lane_fail
from hal.pio.vmivme2536_regs import ALL_LINES, LINES_PER_PORT, PORTS, VMI2536_REGS, parse_line
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.errors import VmeError
from hal.vme.types import AddressSpace
from hal.vme.window import BoardWindow

_IN, _OUT = 0, 1
_MASK32 = 0xFFFF_FFFF


class Vmi2536BoardIdError(PioBoardIdError):
    """``BID`` does not read the value the rig states for its VMIVME-2536 (wrong board or base)."""


class Vmi2536Driver:
    """VMIVME-2536 driver.

    ``LINES``: every pin name the board has (the rig file's wiring checks read it).

    Args:
        bus: the VME bus.
        base: board base address (the card's jumpers; the EPICS support's default is 0xFF00).
        space: address space (A16 short I/O).
        lines: logical name → pin (``{"j1.amp_enable": "OUT0"}``); pins may also be used directly.
        board_id: the ``BID`` value :meth:`probe` requires (``None``: any value; the value is not
            published, see the doc's "Identification").
        loopback: output → the input the rig wires it back to (``{"OUT0": "IN16"}``, names or
            pins): the only way this board can see an output's wire.
        settle_s: wait before reading a looped-back input after a write (optocoupler switching
            time; the sources give none, so 0).
    """

    LINES = ALL_LINES
    _lanes: LaneSet  #: in lane mode only (from_lanes): the bus's lanes

    def __init__(
        self,
        bus: VmeBus,
        base: int,
        *,
        space: SpaceLike = "A16",
        lines: dict[str, str] | None = None,
        board_id: int | None = None,
        loopback: dict[str, str] | None = None,
        settle_s: float = 0.0,
    ) -> None:
        self.win = BoardWindow(bus, base, VMI2536_REGS, space)
        self.bus = bus
        self.lines: dict[str, tuple[int, int]] = {}
        for name, pin in (lines or {}).items():
            try:
                self.lines[name] = parse_line(pin)
            except ValueError as e:
                raise UnknownLineError(f"wiring table entry {name!r} = {pin!r}: {e}") from None
        if board_id is not None and not 0 <= board_id <= 0xFFFF:
            raise ValueError(f"board_id {board_id} is not a 16-bit BID value")
        if not settle_s >= 0.0:
            raise ValueError(f"settle_s {settle_s} is not a time ≥ 0")
        self.board_id = board_id
        self.settle_s = settle_s
        #: output bit → input bit it is looped back to
        self._loop: dict[int, int] = {}
        for out, inp in (loopback or {}).items():
            o, i = self.resolve(out), self.resolve(inp)
            if o[0] != _OUT or i[0] != _IN:
                raise LineDirectionError(f"loopback {out!r} → {inp!r}: an output is looped back into an input")
            self._loop[o[1]] = i[1]
        self._latch = self.win.read("OUTPUT")

    # --- the board ---------------------------------------------------------------------------
    def probe(self) -> int:
        """Read ``BID`` (a board that is not there ends the cycle in BERR); raise
        :class:`Vmi2536BoardIdError` if the rig stated ``board_id`` and it reads otherwise."""
        bid = self.win.read("BID")
        if self.board_id is not None and bid != self.board_id:
            raise Vmi2536BoardIdError(
                f"no VMIVME-2536 with BID 0x{self.board_id:04X} at 0x{self.win.base:X}: BID reads "
                f"0x{bid:04X}; check the base address and board_id in the crate/rig file"
            )
        return bid

    def reset(self) -> None:
        """The power-up state by writes: every output low while still active (driven low, not
        left at its last level), then outputs and inputs off and the fail LED on."""
        self.win.write("OUTPUT", 0)
        self.win.write("CSR", 0)
        self._latch = 0

    # --- names -------------------------------------------------------------------------------
    def resolve(self, name: str) -> tuple[int, int]:
        """(port, bit) of a logical line name or a pin name: port 0 = inputs, 1 = outputs."""
        if name in self.lines:
            return self.lines[name]
        try:
            return parse_line(name)
        except ValueError:
            known = ", ".join(sorted(self.lines)) or "none"
            raise UnknownLineError(
                f"unknown VMIVME-2536 line {name!r}: not in the wiring table (known: {known}) "
                "and not a pin IN0..IN31 or OUT0..OUT31"
            ) from None

    @staticmethod
    def _port(port: str | int) -> int:
        if isinstance(port, int) and 0 <= port < len(PORTS):
            return port
        s = str(port).strip().upper()
        if s in PORTS:
            return PORTS.index(s)
        raise UnknownLineError(f"unknown VMIVME-2536 port {port!r}; expected IN or OUT")

    def _names(self, port: int) -> dict[int, str]:
        names = {bit: f"{PORTS[port]}{bit}" for bit in range(LINES_PER_PORT)}
        names.update({b: n for n, (p, b) in self.lines.items() if p == port})
        return names

    # --- levels ------------------------------------------------------------------------------
    def configure(self, outputs: Iterable[str] = (), initial: dict[str, bool] | None = None) -> None:
        """Load the output latch (``initial`` levels of the listed outputs, default low; every
        other output low), then activate outputs and inputs. Listing an input is an error."""
        listed: set[int] = set()
        for name in outputs:
            port, bit = self.resolve(name)
            if port != _OUT:
                raise LineDirectionError(f"VMIVME-2536 line {name!r} is an input (IN0..IN31 cannot drive)")
            listed.add(bit)
        latch = 0
        for name, level in (initial or {}).items():
            port, bit = self.resolve(name)
            if port != _OUT or bit not in listed:
                raise LineDirectionError(f"initial level given for {name!r}, which is not in outputs")
            latch |= int(bool(level)) << bit
        self.win.write("OUTPUT", latch)
        # fail LED off, outputs and inputs active: what the EPICS support writes (drvVmi2536.c:91)
        self.win.write_fields("CSR", led_off=1, outputs_on=1, inputs_on=1)
        self._latch = latch

    def is_output(self, name: str) -> bool:
        return self.resolve(name)[0] == _OUT

    def set_line(self, name: str, level: bool, *, verify: bool = True) -> None:
        """Drive an output. With ``verify`` the latch is read back, and a looped-back output's
        wire through its input; a line that does not follow raises :class:`LineStuckError`."""
        port, bit = self.resolve(name)
        if port != _OUT:
            raise LineDirectionError(f"VMIVME-2536 line {name!r} ({PORTS[port]}{bit}) is an input")
        if level:
            self._latch |= 1 << bit
        else:
            self._latch &= ~(1 << bit) & _MASK32
        self.win.write("OUTPUT", self._latch)
        if verify:
            seen = self.win.read("OUTPUT") >> bit & 1
            if seen == int(bool(level)) and bit in self._loop:
                seen = self._input_bits() >> self._loop[bit] & 1
            if seen != int(bool(level)):
                raise LineStuckError({name: bool(seen)})

    def get_line(self, name: str) -> bool:
        """An input's level (``INPUT``) or an output's latch bit (``OUTPUT``)."""
        port, bit = self.resolve(name)
        return bool(self.win.read("INPUT" if port == _IN else "OUTPUT") >> bit & 1)

    def read_port(self, port: str | int) -> int:
        """``INPUT`` (port 0, ``"IN"``) or ``OUTPUT`` (port 1, ``"OUT"``), 32 bits."""
        return self.win.read("INPUT" if self._port(port) == _IN else "OUTPUT")

    def read_pins(self, port: str | int) -> int:
        """What the board can tell of the wires: ``INPUT`` for the inputs; for the outputs the
        latch with each looped-back output's bit replaced by the level of its input."""
        if self._port(port) == _IN:
            return self.win.read("INPUT")
        value = self.win.read("OUTPUT")
        if self._loop:
            inputs = self._input_bits()
            for out, inp in self._loop.items():
                value = (value & ~(1 << out)) | ((inputs >> inp & 1) << out)
        return value

    def write_port(self, port: str | int, value: int) -> None:
        """Load the whole output latch (port ``"OUT"``; the inputs cannot be written)."""
        if self._port(port) != _OUT:
            raise LineDirectionError("the VMIVME-2536 inputs cannot be written")
        if not 0 <= value <= _MASK32:
            raise ValueError(f"port value {value} is not 32 bits")
        self._latch = value
        self.win.write("OUTPUT", value)

    def verify_outputs(self) -> None:
        """Compare the latch, and every looped-back output's wire, with the driver's copy; raise
        :class:`LineStuckError` listing the lines that differ."""
        names = self._names(_OUT)
        bad: dict[str, bool] = {}
        diff = self.win.read("OUTPUT") ^ self._latch
        for bit in range(LINES_PER_PORT):
            if diff >> bit & 1:
                bad[names[bit]] = not (self._latch >> bit & 1)
        if self._loop:
            inputs = self._input_bits()
            for out, inp in self._loop.items():
                wire = inputs >> inp & 1
                if names[out] not in bad and wire != (self._latch >> out & 1):
                    bad[names[out]] = bool(wire)
        if bad:
            raise LineStuckError(bad)

    def close(self) -> None:
        """Nothing to release: the board has no interrupt (no bus cycle)."""

    def _input_bits(self) -> int:
        if self.settle_s > 0.0:
            self.bus.delay(self.settle_s)
        return self.win.read("INPUT")

    # --- lanes (batched lockstep, hal.lanes) ----------------------------------------------------
    @classmethod
    def from_lanes(cls, drivers: Sequence[Vmi2536Driver], bus: VmeBus) -> Vmi2536Driver:
        """One driver in lane mode for the B scalar ``drivers`` (lane order, each opened and
        configured on its instance's crate) on ``bus``, the crate of their lanes: the same board,
        wiring table, loopbacks and settings in every lane; the latch copies are stacked. No bus
        cycle."""
        first = drivers[0]
        if cls is not Vmi2536Driver:
            raise NotImplementedError(f"{cls.__name__} has no lane mode")
        lanes = getattr(bus, "lanes", None)
        if not isinstance(lanes, LaneSet):
            raise ValueError("a VMIVME-2536 driver in lanes needs a bus of lanes (bus.lanes)")

        def setup(d: Vmi2536Driver) -> tuple[Any, ...]:
            return d.win.base, d.win.am, d.lines, d.board_id, d.settle_s, d._loop

        for d in drivers:
            if type(d) is not cls:
                raise NotImplementedError(f"a {type(d).__name__} cannot share lanes with a {cls.__name__}")
            if setup(d) != setup(first):
                raise NotImplementedError("the lanes' VMIVME-2536 drivers differ in board address, wiring or settings")
        obj = cls.__new__(cls)
        obj.win = BoardWindow(bus, first.win.base, VMI2536_REGS, first.win.am)
        obj.bus = bus
        obj.lines = dict(first.lines)
        obj.board_id, obj.settle_s = first.board_id, first.settle_s
        obj._loop = dict(first._loop)
        obj._latch = stack([d._latch for d in drivers])
        obj._lanes = lanes
        for name in ("set_line", "get_line", "write_port", "verify_outputs"):
            setattr(obj, name, getattr(obj, "_lane_" + name))
        return obj

    def _lane_set_line(self, name: str, level: LaneValue, *, verify: bool = True) -> None:
        # set_line with a level per lane: the same cycles; a lane whose latch, or looped-back
        # wire, does not follow is ejected where one driver raises LineStuckError
        port, bit = self.resolve(name)
        if port != _OUT:
            raise LineDirectionError(f"VMIVME-2536 line {name!r} ({PORTS[port]}{bit}) is an input")
        m = 1 << bit
        latch: LaneValue = self._latch
        if isinstance(level, np.ndarray):
            level = level.astype(bool)
            latch = np.where(level, latch | m, latch & ~m & _MASK32)
        else:
            level = bool(level)
            latch = latch | m if level else latch & ~m & _MASK32
        self._latch = latch
        self.win.write("OUTPUT", latch)
        if verify:
            seen = (self.win.read("OUTPUT") >> bit) & 1 != 0
            lane_fail(self._lanes, seen != level, f"VMIVME-2536 line {name!r}: the latch does not read back "
                      "(LineStuckError)", lambda: LineStuckError({name: bool(seen)}))
            if bit in self._loop:
                wire = (self._input_bits() >> self._loop[bit]) & 1 != 0
                lane_fail(self._lanes, wire != level, f"VMIVME-2536 line {name!r}: its looped-back wire does not "
                          "follow its latch (LineStuckError)", lambda: LineStuckError({name: bool(wire)}))

    def _lane_get_line(self, name: str) -> LaneValue:
        port, bit = self.resolve(name)
        return (self.win.read("INPUT" if port == _IN else "OUTPUT") >> bit) & 1 != 0

    def _lane_write_port(self, port: str | int, value: LaneValue) -> None:
        if self._port(port) != _OUT:
            raise LineDirectionError("the VMIVME-2536 inputs cannot be written")
        lane_fail(self._lanes, (value < 0) | (value > _MASK32), "VMIVME-2536 port OUT: a value that is not 32 bits",
                  lambda: ValueError(f"port value {value} is not 32 bits"))
        self._latch = value
        self.win.write("OUTPUT", value)

    def _lane_verify_outputs(self) -> None:
        # verify_outputs per lane: a difference alike in every lane raises as one driver does
        # (naming the lines); one in some lanes only ejects those lanes
        names = self._names(_OUT)
        bad: dict[str, bool] = {}
        stuck: LaneValue = False
        latch = self._latch
        diff = self.win.read("OUTPUT") ^ latch
        if isinstance(diff, np.ndarray):
            stuck = diff != 0
        else:
            for bit in range(LINES_PER_PORT):
                if diff >> bit & 1:
                    bad[names[bit]] = not (latch >> bit & 1)
        if self._loop:
            inputs = self._input_bits()
            for out, inp in self._loop.items():
                wire = (inputs >> inp) & 1
                want = (latch >> out) & 1
                off = wire != want
                if isinstance(off, np.ndarray):
                    stuck = stuck | off
                elif names[out] not in bad and off:
                    bad[names[out]] = bool(wire)
        if bad:
            raise LineStuckError(bad)
        lane_fail(self._lanes, stuck, "VMIVME-2536 output lines do not follow their latch (LineStuckError)",
                  lambda: LineStuckError({}))


def probe_vmivme2536(bus: VmeBus, base: int, space: AddressSpace) -> ProbeReading:
    """The dry pass's probe (``hal.board_types``; reads only): every register answers at the width
    the sources use (``BID``, ``CSR`` D16; ``INPUT``, ``OUTPUT`` D32). ``BID``'s value is not
    published, so it is reported, not compared: a board that is not there, or one whose registers
    are not at these widths (the reference PIO at the same base: its 0x02 is D8 only), fails."""
    parts: list[str] = []
    bid: int | None = None
    for reg in VMI2536_REGS.registers:
        try:
            value = bus.read(base + reg.offset, space=space, width=reg.width)
        except VmeError as e:
            return ProbeReading(False, "; ".join([*parts, f"{reg.name}: {type(e).__name__}: {e}"]), None, bid)
        if reg.name == "BID":
            bid = value
        parts.append(f"{reg.name} 0x{value:0{2 * int(reg.width)}X}")
    return ProbeReading(True, "; ".join(parts) + " (BID not published: not compared)", None, bid)
