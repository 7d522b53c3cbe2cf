"""Emulated parallel I/O board, written from its spec, docs/boards/pio.md.

A second reading of the doc, independent of the driver: the register map, the line names, the
tick length and the interrupt-control layout below are this module's own, written from the
doc's tables (nothing is imported from ``hal.pio``), so a wrong offset, bit or width in the
driver's map shows up as a driver/board disagreement instead of being copied here.

Wiring: each line (``"PA0"``..``"PC7"``) may be wired to a digital net; outputs drive their
net with ``Signals.set_digital``; inputs read it with ``Signals.get_digital`` and the board
subscribes to input nets to detect changes for the input-change interrupt. The PWM output
is published as an analog net carrying the duty fraction 0..1 (the H-bridge model averages
it).

68230-like behaviour reproduced on purpose (visible to a careless driver):

- the output latch is written for every bit, inputs included, so a line switched to output
  drives the stale latch value unless the latch was written first;
- ``DATA_x`` returns the latch for output lines, so a stuck or shorted output line is
  invisible there; only ``PIN_x`` shows the wire;
- status bits latch on any input change; enabling an interrupt with stale status bits
  interrupts at once;
- a line switched from output to input stops driving, but the net keeps its last level
  (there is no pull-up model on this side).

Faults: ``line_stuck(line="PB0", level=True)`` — the pin is held at ``level`` whatever the
board or the net does: a stuck output drives the stuck level onto its net (``DATA_x`` still
reads the latch, ``PIN_x`` shows the stuck level); a stuck input reads the stuck level.

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`PioBoard.from_lanes` stacks B boards into
one whose registers, pins and nets are lane values (bools per lane on the nets, the PWM duty
fraction per lane on the PWM net). An input-change interrupt a lane would raise is not modelled
in lanes: that lane is ejected (interrupt-driven runs go scalar); injected faults are refused.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any, ClassVar

import numpy as np

from emulators.board import RegisterBoard
from hal.lanes import LaneSet, LaneValue, stack
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

_D8, _D16 = Width.D8, Width.D16
_RO, _RW, _RW1C = Access.RO, Access.RW, Access.W1C

#: docs/boards/pio.md, "Registers", row by row (offset, register, width, access, reset, bits)
PIO_BOARD_MAP = RegisterMap("pio", 0x20, AddressSpace.A16, (
    Register("ID", 0x00, _D16, _RO, reset=0x5001,
             fields=(Field("type", 8, 8, "board type, 0x50"), Field("rev", 0, 8, "revision, 0x01"))),
    Register("DDR_A", 0x02, _D8, _RW),
    Register("DDR_B", 0x03, _D8, _RW),
    Register("DDR_C", 0x04, _D8, _RW),
    Register("DATA_A", 0x06, _D8, _RW),
    Register("DATA_B", 0x07, _D8, _RW),
    Register("DATA_C", 0x08, _D8, _RW),
    Register("PIN_A", 0x0A, _D8, _RO),
    Register("PIN_B", 0x0B, _D8, _RO),
    Register("PIN_C", 0x0C, _D8, _RO),
    Register("IER_A", 0x0E, _D8, _RW),
    Register("IER_B", 0x0F, _D8, _RW),
    Register("IER_C", 0x10, _D8, _RW),
    Register("ICS_A", 0x12, _D8, _RW1C),
    Register("ICS_B", 0x13, _D8, _RW1C),
    Register("ICS_C", 0x14, _D8, _RW1C),
    Register("INT_CTL", 0x16, _D16, _RW,
             fields=(Field("vector", 8, 8, "status/ID answered on IACK"), Field("ien", 7, 1, "interrupt enable"),
                     Field("level", 0, 3, "IRQ level 1..7 (0 = none)"))),
    Register("PWM_CTL", 0x18, _D16, _RW, fields=(Field("enable", 0, 1, "the PWM output runs"),)),
    Register("PWM_PERIOD", 0x1A, _D16, _RW),
    Register("PWM_DUTY", 0x1C, _D16, _RW),
    Register("PWM_COUNT", 0x1E, _D16, _RO),
))

_PORT_LETTERS = "ABC"
#: every line name, "PA0".."PC7" → (port index, bit) (doc: line Pxn is bit n of port x)
_LINES: dict[str, tuple[int, int]] = {f"P{letter}{bit}": (port, bit)
                                      for port, letter in enumerate(_PORT_LETTERS) for bit in range(8)}
_NS_PER_TICK = 100  #: the PWM timer's 10 MHz clock
_INT_CTL_BITS = 0xFF87  #: vector [15:8], ien [7], level [2:0]; bits 6:3 read 0
_IEN = 0x80
_LEVEL = 0x07
_DDR = ("DDR_A", "DDR_B", "DDR_C")
_DATA = ("DATA_A", "DATA_B", "DATA_C")
_IER = ("IER_A", "IER_B", "IER_C")
_ICS = ("ICS_A", "ICS_B", "ICS_C")


def _line(name: str) -> tuple[int, int]:
    """(port index, bit) of a line name (case and surrounding space free); ``ValueError`` else."""
    try:
        return _LINES[name.strip().upper()]
    except KeyError:
        raise ValueError(f"{name!r} is not a PIO line; expected PA0..PA7, PB0..PB7 or PC0..PC7") from None


class PioBoard(RegisterBoard):
    """Three 8-bit ports, input-change interrupt (RORA), PWM timer.

    Args:
        name: board name in the crate.
        lines: line → net name (``{"PA0": "amp1.enable"}``); unwired lines float (inputs read 0).
        pwm_net: analog net receiving the PWM duty fraction 0..1 (``None``: not wired).
    """

    TYPE = "pio"
    REGMAP = PIO_BOARD_MAP
    irq_release = "rora"
    _lanes: LaneSet  #: in lane mode only (from_lanes): the crate's lanes
    FAULTS: ClassVar[dict[str, str]] = {
        "line_stuck": "line=PXn, level=bool: the pin is held at level (board and net cannot move it)",
    }

    def __init__(self, name: str, lines: dict[str, str] | None = None, pwm_net: str | None = None) -> None:
        self.nets: dict[tuple[int, int], str] = {}
        for pin, net in (lines or {}).items():
            self.nets[_line(pin)] = str(net)
        self.pwm_net = pwm_net
        # the wired lines in (port, bit) order, and per port; the wiring is fixed at construction
        self._wired = tuple((port, bit, net) for (port, bit), net in sorted(self.nets.items()))
        self._port_nets = tuple(tuple((bit, net) for p, bit, net in self._wired if p == port)
                                for port in range(3))
        # the ports each net is wired to, in port order (_on_net runs at every change of a net)
        self._net_ports = {net: tuple(sorted({p for (p, _), n in self.nets.items() if n == net}))
                           for net in set(self.nets.values())}
        self._prev_inputs: list[Any] = [0, 0, 0]
        self._bind_ports()
        super().__init__(name)

    def _bind_ports(self) -> None:
        """The per-port register hooks (``read_DATA_A``..), bound to this board's methods."""
        for i, p in enumerate(_PORT_LETTERS):
            setattr(self, f"read_DATA_{p}", partial(self._read_data, i))
            setattr(self, f"write_DATA_{p}", partial(self._write_data, i))
            setattr(self, f"write_DDR_{p}", partial(self._write_ddr, i))
            setattr(self, f"read_PIN_{p}", partial(self.pins, i))
            setattr(self, f"write_IER_{p}", partial(self._write_ier, i))
            setattr(self, f"write_ICS_{p}", partial(self._write_ics, i))

    # --- crate hooks ---------------------------------------------------------------------
    def attach(self, crate) -> None:
        super().attach(crate)
        for net in sorted(set(self.nets.values())):
            crate.signals.subscribe(net, self._on_net)
        self._resample_all(flag=False)
        self._drive_outputs()
        self._publish_pwm()

    def reset(self) -> None:
        super().reset()
        self._prev_inputs = [0, 0, 0]
        if self.crate is not None:
            self._resample_all(flag=False)
            self._publish_pwm()

    def describe(self) -> dict[str, Any]:
        wired = {f"P{_PORT_LETTERS[p]}{b}": n for (p, b), n in sorted(self.nets.items())}
        return {"type": self.TYPE, "lines": wired, "pwm_net": self.pwm_net}

    # --- pin model -----------------------------------------------------------------------
    def _stuck(self) -> tuple[tuple[int, int], bool] | None:
        f = self.fault("line_stuck")
        if f is None:
            return None
        return _line(str(f.get("line", "PA0"))), bool(f.get("level", False))

    def pin_level(self, port: int, bit: int) -> bool:
        """The level on the wire of one line."""
        if self.faulted:
            stuck = self._stuck()
            if stuck is not None and stuck[0] == (port, bit):
                return stuck[1]
        if self.regs[_DDR[port]] >> bit & 1:
            return bool(self.regs[_DATA[port]] >> bit & 1)
        net = self.nets.get((port, bit))
        if net is None or self.crate is None:
            return False
        return self.crate.signals.get_digital(net)

    def pins(self, port: int) -> int:
        """The eight pin levels of ``port`` as a byte."""
        if self.faulted or self.crate is None:
            return sum(int(self.pin_level(port, b)) << b for b in range(8))
        # no stuck line: outputs show the latch, wired inputs their net, unwired inputs 0
        ddr = self.regs[_DDR[port]]
        value = self.regs[_DATA[port]] & ddr
        digital = self.crate.signals.digital
        for bit, net in self._port_nets[port]:
            if not ddr >> bit & 1 and digital.get(net, False):
                value |= 1 << bit
        return value

    def _read_data(self, port: int) -> int:
        ddr = self.regs[_DDR[port]]
        return (self.regs[_DATA[port]] & ddr) | (self.pins(port) & ~ddr & 0xFF)

    def _write_data(self, port: int, value: int) -> None:
        self.regs[_DATA[port]] = value & 0xFF
        self._drive_outputs()

    def _write_ddr(self, port: int, value: int) -> None:
        self.regs[_DDR[port]] = value & 0xFF
        self._drive_outputs()
        self._resample(port, flag=False)  # direction changes are not input changes

    def _drive_outputs(self) -> None:
        if self.crate is None:
            return
        signals, regs = self.crate.signals, self.regs
        if self.faulted:  # a stuck line may override an output's level
            for port, bit, net in self._wired:
                if regs[_DDR[port]] >> bit & 1:
                    signals.set_digital(net, self.pin_level(port, bit))
            return
        for port, bit, net in self._wired:  # no fault: an output's pin is its latch (pin_level)
            if regs[_DDR[port]] >> bit & 1:
                signals.set_digital(net, bool(regs[_DATA[port]] >> bit & 1))

    # --- input change detection and interrupt --------------------------------------------
    def _on_net(self, net: str, value: Any) -> None:
        for port in self._net_ports.get(net, ()):
            self._resample(port, flag=True)

    def _resample(self, port: int, *, flag: bool) -> None:
        inputs = ~self.regs[_DDR[port]] & 0xFF
        now = self.pins(port) & inputs
        changed = (now ^ self._prev_inputs[port]) & inputs
        self._prev_inputs[port] = now
        if flag and changed:
            self.regs[_ICS[port]] |= changed
            self._update_irq()

    def _resample_all(self, *, flag: bool) -> None:
        for port in range(3):
            self._resample(port, flag=flag)

    def _write_ier(self, port: int, value: int) -> None:
        self.regs[_IER[port]] = value & 0xFF
        self._update_irq()

    def _write_ics(self, port: int, value: int) -> None:
        self.regs[_ICS[port]] &= ~value & 0xFF
        self._update_irq()

    def write_INT_CTL(self, value: int) -> None:
        self.regs["INT_CTL"] = value & _INT_CTL_BITS
        self._update_irq()

    def _update_irq(self) -> None:
        ctl = self.regs["INT_CTL"]
        level, ien, vector = ctl & _LEVEL, ctl & _IEN, ctl >> 8
        active = any(self.regs[s] & self.regs[e] for s, e in zip(_ICS, _IER, strict=True))
        if active and ien and level:
            if not self.irq_pending:
                self.request_irq(level, vector)
        elif self.irq_pending:
            self.release_irq()

    # --- PWM -----------------------------------------------------------------------------
    def duty_fraction(self) -> float:
        """The PWM output's mean level 0..1 (what the H-bridge averages)."""
        if not self.regs["PWM_CTL"] & 1:
            return 0.0
        period = self.regs["PWM_PERIOD"]
        if period == 0:
            return 0.0
        return min(self.regs["PWM_DUTY"], period) / period

    def _publish_pwm(self) -> None:
        if self.pwm_net is not None and self.crate is not None:
            self.crate.signals.set_analog(self.pwm_net, self.duty_fraction())

    def write_PWM_CTL(self, value: int) -> None:
        self.regs["PWM_CTL"] = value & 1
        self._publish_pwm()

    def write_PWM_PERIOD(self, value: int) -> None:
        self.regs["PWM_PERIOD"] = value
        self._publish_pwm()

    def write_PWM_DUTY(self, value: int) -> None:
        self.regs["PWM_DUTY"] = value
        self._publish_pwm()

    def read_PWM_COUNT(self) -> int:
        period = self.regs["PWM_PERIOD"]
        if not self.regs["PWM_CTL"] & 1 or period == 0:
            return 0
        return (self.now_ns // _NS_PER_TICK) % period

    # --- lanes (batched lockstep, hal.lanes) ---------------------------------------------
    @classmethod
    def from_lanes(cls, boards: Sequence[Any], crate: Any) -> PioBoard:
        """One board in lane mode holding the B scalar ``boards`` (lane order), for the lane
        crate ``crate`` (a bus of lanes: ``crate.lanes``), which installs it — and so subscribes
        it to its wired nets on ``crate.signals``, as installing a scalar board does. The wiring
        must be the same in every lane; registers and the input-change memory are stacked. No bus
        cycle, no net driven (``Signals.from_lanes`` stacked the nets)."""
        first = boards[0]
        lanes = getattr(crate, "lanes", None)
        if not isinstance(lanes, LaneSet):
            raise ValueError(f"{first.name}: a board in lanes needs a crate of lanes (crate.lanes)")
        for b in boards:
            if type(b) is not cls:
                raise NotImplementedError(f"{first.name}: a {type(b).__name__} cannot be a lane of a {cls.__name__}")
            if b.faulted:
                raise NotImplementedError(f"{b.name}: a board with an injected fault runs scalar")
            if b.irq_pending:
                raise NotImplementedError(f"{b.name}: an input-change interrupt is pending (such runs go scalar)")
            if b.nets != first.nets or b.pwm_net != first.pwm_net:
                raise NotImplementedError(f"{first.name}: the lanes' boards are wired differently")
        lines = {f"P{_PORT_LETTERS[port]}{bit}": net for (port, bit), net in first.nets.items()}
        obj = cls(first.name, lines=lines, pwm_net=first.pwm_net)
        obj._stack_regs(boards)
        obj._prev_inputs = [stack([b._prev_inputs[port] for b in boards]) for port in range(3)]
        obj._lanes = lanes
        for name in ("pins", "pin_level", "_drive_outputs", "_resample", "_write_ics", "_update_irq", "duty_fraction",
                     "read_PWM_COUNT", "inject"):
            setattr(obj, name, getattr(obj, "_lane_" + name.lstrip("_")))
        obj._bind_ports()  # the port hooks again, now bound to the lane methods
        return obj

    def _lane_pin_level(self, port: int, bit: int) -> LaneValue:
        out = (self.regs[_DDR[port]] >> bit) & 1
        latch = (self.regs[_DATA[port]] >> bit) & 1 != 0
        net = self.nets.get((port, bit))
        wire = False if net is None or self.crate is None else self.crate.signals.get_digital(net)
        if isinstance(out, np.ndarray):
            return np.where(out != 0, latch, wire)
        return latch if out else wire

    def _lane_pins(self, port: int) -> LaneValue:
        # pins() without a stuck line (no faults in lanes): outputs show the latch, wired inputs
        # their net (a bool per lane), unwired inputs 0 -- per bit, as a lane word
        ddr = self.regs[_DDR[port]]
        value = self.regs[_DATA[port]] & ddr
        if self.crate is None:
            return value
        digital = self.crate.signals.digital
        for bit, net in self._port_nets[port]:
            value = value | (((ddr >> bit) & 1 ^ 1) & digital.get(net, False)) << bit
        return value

    def _lane_drive_outputs(self) -> None:
        if self.crate is None:
            return
        signals, regs = self.crate.signals, self.regs
        for port, bit, net in self._wired:
            out = (regs[_DDR[port]] >> bit) & 1
            level = (regs[_DATA[port]] >> bit) & 1 != 0
            if isinstance(out, np.ndarray):  # an output in some lanes only: the others keep the net
                signals.set_digital(net, np.where(out != 0, level, signals.get_digital(net)))
            elif out:
                signals.set_digital(net, level)

    def _lane_resample(self, port: int, *, flag: bool) -> None:
        inputs = ~self.regs[_DDR[port]] & 0xFF
        now = self.pins(port) & inputs
        changed = (now ^ self._prev_inputs[port]) & inputs
        self._prev_inputs[port] = now
        if flag and (changed.any() if isinstance(changed, np.ndarray) else changed):
            self.regs[_ICS[port]] = self.regs[_ICS[port]] | changed  # never in place: lane arrays may be shared
            self._update_irq()

    def _lane_write_ics(self, port: int, value: LaneValue) -> None:
        self.regs[_ICS[port]] = self.regs[_ICS[port]] & (~value & 0xFF)
        self._update_irq()

    def _lane_update_irq(self) -> None:
        # A lane that would interrupt leaves the batch: one interrupt controller serves every
        # lane, and an interrupt-driven driver's cycles would differ per lane.
        regs = self.regs
        ctl = regs["INT_CTL"]
        active: Any = 0
        for s, e in zip(_ICS, _IER, strict=True):
            active = active | (regs[s] & regs[e])
        want = (active != 0) & (ctl & _IEN != 0) & (ctl & _LEVEL != 0)
        if isinstance(want, np.ndarray) or want:
            self._lanes.eject(want, f"{self.name}: input-change interrupt (interrupt-driven runs go scalar)")

    def _lane_duty_fraction(self) -> LaneValue:
        ctl, period, duty = self.regs["PWM_CTL"] & 1, self.regs["PWM_PERIOD"], self.regs["PWM_DUTY"]
        if not any(isinstance(x, np.ndarray) for x in (ctl, period, duty)):
            return PioBoard.duty_fraction(self)
        on = (ctl != 0) & (period != 0)
        with np.errstate(all="ignore"):  # int64 / int64: exact operands, one rounding, as int / int
            frac = np.where(period < duty, period, duty) / np.where(on, period, 1)
        return np.where(on, frac, 0.0)

    def _lane_read_PWM_COUNT(self) -> LaneValue:
        ctl, period = self.regs["PWM_CTL"] & 1, self.regs["PWM_PERIOD"]
        if not isinstance(ctl, np.ndarray) and not isinstance(period, np.ndarray):
            return PioBoard.read_PWM_COUNT(self)
        on = (ctl != 0) & (period != 0)
        return np.where(on, (self.now_ns // _NS_PER_TICK) % np.where(on, period, 1), 0)

    def _lane_inject(self, name: str, **params: Any) -> None:
        raise NotImplementedError(f"{self.name}: faults are not injected into lanes (such runs go scalar)")

    # --- faults --------------------------------------------------------------------------
    def _fault_changed(self, name: str) -> None:
        if name == "line_stuck":
            f = self.fault("line_stuck")
            if f is not None:
                line = str(f.get("line", ""))
                if line.upper() not in _LINES:
                    self.clear_fault("line_stuck")
                    raise ValueError(f"line_stuck: {line!r} is not a PIO line (PA0..PC7)")
            if self.crate is not None:
                self._drive_outputs()
                self._resample_all(flag=True)


def pio_from_config(name: str, cfg, ctx) -> PioBoard:
    """Crate-file factory (``type = "pio"``)::

        [[crate.board]]
        type = "pio"
        name = "pio0"
        space = "A16"
        base = 0x4000
        lines = { PA0 = "amp1.enable", PA1 = "hb1.dir", PB0 = "amp1.fault" }
        pwm_net = "hb1.pwm"
    """
    lines: dict[str, str] = {}
    if "lines" in cfg:
        tbl = cfg.table("lines")
        for pin in list(tbl.keys()):
            net = tbl.get_str(pin)
            if pin.upper() not in _LINES:
                raise tbl.error(pin, "a PIO line name PA0..PC7", pin)
            lines[pin.upper()] = net
    pwm_net = cfg.get_str("pwm_net") if "pwm_net" in cfg else None
    return PioBoard(name, lines=lines, pwm_net=pwm_net)
