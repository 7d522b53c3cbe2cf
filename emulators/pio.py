"""Emulated parallel I/O board (see :mod:`hal.pio.pio_regs` for the register map).

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
"""

from __future__ import annotations

from functools import partial
from typing import Any, ClassVar

from emulators.board import RegisterBoard
from hal.pio.pio_regs import ALL_LINES, LINES_PER_PORT, PIO_REGS, PORTS, PWM_CLOCK_HZ, parse_line

_NS_PER_TICK = 1_000_000_000 // PWM_CLOCK_HZ
_DDR = tuple(f"DDR_{p}" for p in PORTS)
_DATA = tuple(f"DATA_{p}" for p in PORTS)
_ICS = tuple(f"ICS_{p}" for p in PORTS)


class PioBoard(RegisterBoard):
    """Three 8-bit ports, input-change interrupt (RORA), PWM timer.

    Args:
        name: board name in the crate.
        lines: line → net name (``{"PA0": "amp1.enable"}``); unwired lines float (inputs read 0).
        pwm_net: analog net receiving the PWM duty fraction 0..1 (``None``: not wired).
    """

    TYPE = "pio"
    REGMAP = PIO_REGS
    irq_release = "rora"
    FAULTS: ClassVar[dict[str, str]] = {
        "line_stuck": "line=PXn, level=bool: the pin is held at level (board and net cannot move it)",
    }

    def __init__(self, name: str, lines: dict[str, str] | None = None, pwm_net: str | None = None) -> None:
        self.nets: dict[tuple[int, int], str] = {}
        for pin, net in (lines or {}).items():
            self.nets[parse_line(pin)] = str(net)
        self.pwm_net = pwm_net
        # the wired lines in (port, bit) order, and per port; the wiring is fixed at construction
        self._wired = tuple((port, bit, net) for (port, bit), net in sorted(self.nets.items()))
        self._port_nets = tuple(tuple((bit, net) for p, bit, net in self._wired if p == port)
                                for port in range(len(PORTS)))
        # the ports each net is wired to, in port order (_on_net runs at every change of a net)
        self._net_ports = {net: tuple(sorted({p for (p, _), n in self.nets.items() if n == net}))
                           for net in set(self.nets.values())}
        self._prev_inputs = [0, 0, 0]
        for i, p in enumerate(PORTS):
            setattr(self, f"read_DATA_{p}", partial(self._read_data, i))
            setattr(self, f"write_DATA_{p}", partial(self._write_data, i))
            setattr(self, f"write_DDR_{p}", partial(self._write_ddr, i))
            setattr(self, f"read_PIN_{p}", partial(self.pins, i))
            setattr(self, f"write_IER_{p}", partial(self._write_ier, i))
            setattr(self, f"write_ICS_{p}", partial(self._write_ics, i))
        super().__init__(name)

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
        wired = {f"P{PORTS[p]}{b}": n for (p, b), n in sorted(self.nets.items())}
        return {"type": self.TYPE, "lines": wired, "pwm_net": self.pwm_net}

    # --- pin model -----------------------------------------------------------------------
    def _stuck(self) -> tuple[tuple[int, int], bool] | None:
        f = self.fault("line_stuck")
        if f is None:
            return None
        return parse_line(str(f.get("line", "PA0"))), bool(f.get("level", False))

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
            return sum(int(self.pin_level(port, b)) << b for b in range(LINES_PER_PORT))
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
        for port in range(len(PORTS)):
            self._resample(port, flag=flag)

    def _write_ier(self, port: int, value: int) -> None:
        self.regs[f"IER_{PORTS[port]}"] = value & 0xFF
        self._update_irq()

    def _write_ics(self, port: int, value: int) -> None:
        self.regs[f"ICS_{PORTS[port]}"] &= ~value & 0xFF
        self._update_irq()

    def write_INT_CTL(self, value: int) -> None:
        self.regs["INT_CTL"] = value & 0xFF87
        self._update_irq()

    def _update_irq(self) -> None:
        ctl = self.regs["INT_CTL"]
        level, ien, vector = ctl & 7, ctl >> 7 & 1, ctl >> 8
        active = any(self.regs[f"ICS_{p}"] & self.regs[f"IER_{p}"] for p in PORTS)
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

    # --- faults --------------------------------------------------------------------------
    def _fault_changed(self, name: str) -> None:
        if name == "line_stuck":
            f = self.fault("line_stuck")
            if f is not None:
                line = str(f.get("line", ""))
                if line.upper() not in ALL_LINES:
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
            if pin.upper() not in ALL_LINES:
                raise tbl.error(pin, "a PIO line name PA0..PC7", pin)
            lines[pin.upper()] = net
    pwm_net = cfg.get_str("pwm_net") if "pwm_net" in cfg else None
    return PioBoard(name, lines=lines, pwm_net=pwm_net)
