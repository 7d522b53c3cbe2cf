"""Driver for the parallel I/O board: named lines from the rig wiring table, input-change
interrupts, and the H-bridge PWM (duty in [-1, 1] with a direction line).

Register map and bit layout: :mod:`hal.pio.pio_regs`. The driver keeps shadows of the
direction registers and output latches and never read-modify-writes ``DATA_x`` (on the
68230-style board a read returns pin levels for input bits, which would then be written into
the latch); a line becomes an output only after its latch holds the wanted level.

Example::

    pio = PioDriver(bus, 0x4000, lines={"amp1.enable": "PA0", "hb1.dir": "PA1", "amp1.fault": "PB0"},
                    pwm_direction_line="hb1.dir")
    pio.configure(outputs=["amp1.enable", "hb1.dir"])
    pio.set_line("amp1.enable", True)
    pio.on_change("amp1.fault", lambda name, level: print(name, level))
    pio.set_pwm(-0.25, period_s=50e-6)   # 20 kHz, 25 % duty, direction line low
    pio.pwm_enable(True)

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`PioDriver.from_lanes` stacks B drivers (one
per instance) into one on a bus of lanes: :meth:`~PioDriver.read_port` then returns a word per
lane (``(B,)`` int64, or an int when every lane reads the same), :meth:`~PioDriver.set_line`
takes a level per lane and :meth:`~PioDriver.set_pwm` a duty per lane. Where one instance's
driver would raise for some lanes only (a line not following its latch, a duty out of range),
those lanes are ejected; a direction reversal that some lanes make and others not (it adds bus
cycles) keeps the majority's (``VmeBus.decide``). Input-change interrupts are not used in lanes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from hal.errors import HalError
from hal.lanes import LaneSet, LaneValue, stack
from hal.pio.pio_regs import BOARD_TYPE, LINES_PER_PORT, PIO_REGS, PORTS, PWM_CLOCK_HZ, REVISION, parse_line
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.errors import BoardIdError
from hal.vme.window import BoardWindow

LineCallback = Callable[[str, bool], None]
"""``callback(name, level)`` for a line's input change (name as registered)."""
PortCallback = Callable[[str, int, int], None]
"""``callback(port, changed_mask, pin_levels)`` for a port's input changes."""


def lane_fail(lanes: LaneSet, cond: LaneValue, reason: str, error: Callable[[], Exception]) -> None:
    """Where one (scalar) driver raises, in lanes: a condition alike in every lane raises as it
    would; one that holds in some lanes ejects those lanes (``reason``) and the others go on."""
    if isinstance(cond, np.ndarray):
        lanes.eject(cond, reason)
    elif cond:
        raise error()


class PioError(HalError):
    """Base class of parallel-I/O driver errors."""


class UnknownLineError(PioError, LookupError):
    """A line name is neither in the wiring table nor a pin name (PA0..PC7)."""


class LineDirectionError(PioError):
    """Writing a line configured as an input (or watching an output for changes)."""


class LineStuckError(PioError):
    """An output line's pin does not follow its latch (shorted or stuck line)."""

    def __init__(self, lines: dict[str, bool]) -> None:
        self.lines = dict(lines)
        desc = ", ".join(f"{n} (latch {int(not v)}, pin {int(v)})" for n, v in self.lines.items())
        super().__init__(
            f"output line(s) do not follow their latch: {desc}; the line is stuck or shorted — "
            "check the wiring and the load before re-enabling"
        )


class PwmRangeError(PioError, ValueError):
    """A PWM duty or period outside what the board can produce."""


class PioBoardIdError(PioError, BoardIdError):
    """The ID register does not read the parallel I/O board's ID (wrong base, space or board)."""


class PioDriver:
    """Parallel I/O board driver.

    Args:
        bus: the VME bus.
        base: board base address.
        space: address space (A16 short I/O normally).
        lines: logical name → pin (``{"amp1.enable": "PA0"}``); pins may also be used directly.
        irq_level: VME interrupt level for input-change interrupts (1..7).
        vector: the 8-bit status/ID vector the board answers with (one handler per vector).
        pwm_direction_line: default line that carries the H-bridge direction for :meth:`set_pwm`.
        direction_forward_level: level of the direction line for a positive duty.
    """

    _lanes: LaneSet  #: in lane mode only (from_lanes): the bus's lanes

    def __init__(
        self,
        bus: VmeBus,
        base: int,
        *,
        space: SpaceLike = "A16",
        lines: dict[str, str] | None = None,
        irq_level: int = 3,
        vector: int = 0x60,
        pwm_direction_line: str | None = None,
        direction_forward_level: bool = True,
    ) -> None:
        self.win = BoardWindow(bus, base, PIO_REGS, space)
        self.bus = bus
        self.lines: dict[str, tuple[int, int]] = {}
        for name, pin in (lines or {}).items():
            try:
                self.lines[name] = parse_line(pin)
            except ValueError as e:
                raise UnknownLineError(f"wiring table entry {name!r} = {pin!r}: {e}") from None
        if not 1 <= irq_level <= 7:
            raise ValueError(f"irq_level {irq_level} is not 1..7")
        if not 0 <= vector <= 0xFF:
            raise ValueError(f"vector {vector} is not an 8-bit status/ID")
        self.irq_level = irq_level
        self.vector = vector
        self.pwm_direction_line = pwm_direction_line
        self.direction_forward_level = direction_forward_level
        self._ddr = [self.win.read(f"DDR_{p}") for p in PORTS]
        self._latch = [self.win.read(f"DATA_{p}") & d for p, d in zip(PORTS, self._ddr, strict=True)]
        self._ier = [0, 0, 0]
        self._line_cbs: dict[tuple[int, int], list[tuple[str, LineCallback]]] = {}
        self._port_cbs: dict[int, list[PortCallback]] = {}
        self._handler_registered = False
        self._period_ticks = self.win.read("PWM_PERIOD")

    # --- the board ---------------------------------------------------------------------------
    def probe(self) -> int:
        """Read the ID register; raise :class:`PioBoardIdError` unless it is a PIO board (0x5001)."""
        self.win.check_id((BOARD_TYPE << 8) | REVISION, "parallel I/O board", error=PioBoardIdError)
        return (BOARD_TYPE << 8) | REVISION

    def reset(self) -> None:
        """Put the board in its power-up state by writes (it has no reset register): PWM stopped
        (control, duty, period 0), interrupt off and the vector released, every latch low and
        then every line an input. The latches go low before the directions change, so an
        output that was high is driven low rather than left floating at its last level."""
        for reg in ("PWM_CTL", "PWM_DUTY", "PWM_PERIOD", "INT_CTL"):
            self.win.write(reg, 0)
        self._period_ticks = 0
        self._release_interrupt()
        for p in PORTS:
            self.win.write(f"IER_{p}", 0)
        for p in PORTS:
            self.win.write(f"ICS_{p}", 0xFF)
        for p in PORTS:
            self.win.write(f"DATA_{p}", 0)
        for p in PORTS:
            self.win.write(f"DDR_{p}", 0)
        self._ier, self._latch, self._ddr = [0, 0, 0], [0, 0, 0], [0, 0, 0]

    # --- names ---------------------------------------------------------------------------
    def resolve(self, name: str) -> tuple[int, int]:
        """(port index, bit) of a logical line name or a pin name."""
        if name in self.lines:
            return self.lines[name]
        try:
            return parse_line(name)
        except ValueError:
            known = ", ".join(sorted(self.lines)) or "none"
            raise UnknownLineError(
                f"unknown PIO line {name!r}: not in the wiring table (known: {known}) and not a pin PA0..PC7"
            ) from None

    @staticmethod
    def _port(port: str | int) -> int:
        if isinstance(port, int) and 0 <= port < len(PORTS):
            return port
        s = str(port).strip().upper().removeprefix("P")
        if s in PORTS:
            return PORTS.index(s)
        raise UnknownLineError(f"unknown PIO port {port!r}; expected A, B or C")

    def _pin_name(self, port: int, bit: int) -> str:
        return f"P{PORTS[port]}{bit}"

    # --- directions and levels -----------------------------------------------------------
    def configure(self, outputs: Iterable[str] = (), initial: dict[str, bool] | None = None) -> None:
        """Make exactly the listed lines outputs (every other line an input).

        Output latches are loaded first (``initial`` levels, default low) and the directions
        written afterwards, so no output ever drives a stale latch value.
        """
        ddr = [0, 0, 0]
        latch = [0, 0, 0]
        for name in outputs:
            port, bit = self.resolve(name)
            ddr[port] |= 1 << bit
        for name, level in (initial or {}).items():
            port, bit = self.resolve(name)
            if not ddr[port] >> bit & 1:
                raise LineDirectionError(f"initial level given for {name!r}, which is not in outputs")
            latch[port] |= int(bool(level)) << bit
        for i, p in enumerate(PORTS):
            self.win.write(f"DATA_{p}", latch[i])
            self.win.write(f"DDR_{p}", ddr[i])
        self._ddr, self._latch = ddr, latch

    def is_output(self, name: str) -> bool:
        port, bit = self.resolve(name)
        return bool(self._ddr[port] >> bit & 1)

    def set_line(self, name: str, level: bool, *, verify: bool = True) -> None:
        """Drive an output line. With ``verify`` the pin is read back (``PIN_x``) and a line
        that does not follow raises :class:`LineStuckError`."""
        port, bit = self.resolve(name)
        if not self._ddr[port] >> bit & 1:
            raise LineDirectionError(
                f"PIO line {name!r} ({self._pin_name(port, bit)}) is an input; "
                "list it in configure(outputs=...) to drive it"
            )
        if level:
            self._latch[port] |= 1 << bit
        else:
            self._latch[port] &= ~(1 << bit) & 0xFF
        self.win.write(f"DATA_{PORTS[port]}", self._latch[port])
        if verify:
            pin = self.win.read(f"PIN_{PORTS[port]}") >> bit & 1
            if pin != int(bool(level)):
                raise LineStuckError({name: bool(pin)})

    def get_line(self, name: str) -> bool:
        """Level of a line from ``DATA_x``: an output reads its latch, an input its pin."""
        port, bit = self.resolve(name)
        return bool(self.win.read(f"DATA_{PORTS[port]}") >> bit & 1)

    def read_port(self, port: str | int) -> int:
        """``DATA_x`` of a port: latch bits for outputs, pin levels for inputs."""
        return self.win.read(f"DATA_{PORTS[self._port(port)]}")

    def read_pins(self, port: str | int) -> int:
        """``PIN_x`` of a port: the wire levels of all eight lines."""
        return self.win.read(f"PIN_{PORTS[self._port(port)]}")

    def write_port(self, port: str | int, value: int) -> None:
        """Load a port's whole output latch (bits of input lines are stored, not driven)."""
        i = self._port(port)
        if not 0 <= value <= 0xFF:
            raise ValueError(f"port value {value} is not a byte")
        self._latch[i] = value
        self.win.write(f"DATA_{PORTS[i]}", value)

    def verify_outputs(self) -> None:
        """Compare every output line's pin with its latch; raise :class:`LineStuckError` listing
        the lines that differ."""
        bad: dict[str, bool] = {}
        names = {v: k for k, v in self.lines.items()}
        for i, p in enumerate(PORTS):
            if not self._ddr[i]:
                continue
            diff = (self.win.read(f"PIN_{p}") ^ self._latch[i]) & self._ddr[i]
            for bit in range(LINES_PER_PORT):
                if diff >> bit & 1:
                    bad[names.get((i, bit), self._pin_name(i, bit))] = not (self._latch[i] >> bit & 1)
        if bad:
            raise LineStuckError(bad)

    # --- input-change interrupts ---------------------------------------------------------
    def on_change(self, target: str, callback: LineCallback | PortCallback) -> None:
        """Call ``callback`` from the interrupt handler when an input changes.

        ``target`` is a line (logical or pin name; ``callback(name, level)``) or a port
        ``"A"``/``"B"``/``"C"`` or ``"PA"``.. (``callback(port, changed_mask, pin_levels)``; a
        wiring-table name takes precedence). Stale status bits are cleared before the
        interrupt is enabled. Callbacks run in the interrupt handler, at the next bus cycle or
        ``bus.delay()`` after the change.
        """
        is_port = target not in self.lines and len(target.strip()) <= 2
        if is_port and target.strip().upper().removeprefix("P") in PORTS:
            port = self._port(target)
            mask = ~self._ddr[port] & 0xFF
            self._port_cbs.setdefault(port, []).append(callback)  # type: ignore[arg-type]
        else:
            port, bit = self.resolve(target)
            if self._ddr[port] >> bit & 1:
                raise LineDirectionError(
                    f"PIO line {target!r} is an output; input-change interrupts watch inputs only"
                )
            mask = 1 << bit
            self._line_cbs.setdefault((port, bit), []).append((target, callback))  # type: ignore[arg-type]
        if not self._handler_registered:
            self.bus.register_irq_handler(self.vector, self._isr)
            self._handler_registered = True
        p = PORTS[port]
        self.win.write(f"ICS_{p}", mask)
        self._ier[port] |= mask
        self.win.write(f"IER_{p}", self._ier[port])
        self.win.write_fields("INT_CTL", vector=self.vector, ien=1, level=self.irq_level)

    def close(self) -> None:
        """Disable the change interrupt and release the vector."""
        self.win.write_fields("INT_CTL", vector=self.vector, ien=0, level=self.irq_level)
        for i, p in enumerate(PORTS):
            self._ier[i] = 0
            self.win.write(f"IER_{p}", 0)
        self._release_interrupt()

    def _release_interrupt(self) -> None:
        """Unregister the handler and forget the callbacks (no bus cycle)."""
        if self._handler_registered:
            self.bus.unregister_irq_handler(self.vector)
            self._handler_registered = False
        self._line_cbs.clear()
        self._port_cbs.clear()

    def _isr(self, vector: int) -> None:
        for i, p in enumerate(PORTS):
            if not self._ier[i]:
                continue
            status = self.win.read(f"ICS_{p}") & self._ier[i]
            if not status:
                continue
            self.win.write(f"ICS_{p}", status)  # clear first: a later change re-flags
            pins = self.win.read(f"PIN_{p}")
            for cb in self._port_cbs.get(i, ()):
                cb(p, status, pins)
            for bit in range(LINES_PER_PORT):
                if status >> bit & 1:
                    for name, lcb in self._line_cbs.get((i, bit), ()):
                        lcb(name, bool(pins >> bit & 1))

    # --- PWM -----------------------------------------------------------------------------
    def set_pwm_period(self, period_s: float) -> None:
        """PWM period in seconds (100 ns resolution, 200 ns .. 6.5535 ms)."""
        ticks = round(period_s * PWM_CLOCK_HZ) if math.isfinite(period_s) else -1
        if not 2 <= ticks <= 0xFFFF:
            raise PwmRangeError(
                f"PWM period {period_s!r} s is outside 2..65535 ticks of {PWM_CLOCK_HZ / 1e6:g} MHz "
                "(0.2 µs .. 6.5535 ms)"
            )
        self._period_ticks = ticks
        self.win.write("PWM_PERIOD", ticks)

    def set_pwm(self, duty: float, direction_line: str | None = None, period_s: float | None = None) -> None:
        """Signed duty in [-1, 1]: the direction line takes the sign, ``PWM_DUTY`` gets |duty|.

        When the sign changes, the duty is zeroed before the direction line moves, so the
        bridge never sees full duty in the old direction after the reversal is commanded.
        """
        if not (math.isfinite(duty) and -1.0 <= duty <= 1.0):
            raise PwmRangeError(f"PWM duty {duty!r} is outside [-1, 1]")
        if period_s is not None:
            self.set_pwm_period(period_s)
        if self._period_ticks == 0:
            raise PwmRangeError("PWM period is 0 (output held low); pass period_s or call set_pwm_period first")
        line = direction_line if direction_line is not None else self.pwm_direction_line
        ticks = round(abs(duty) * self._period_ticks)
        if line is None:
            if duty < 0:
                raise PwmRangeError(f"negative duty {duty} needs a direction line (none configured)")
        else:
            port, bit = self.resolve(line)
            if not self._ddr[port] >> bit & 1:
                raise LineDirectionError(f"PWM direction line {line!r} is an input; configure it as an output")
            level = self.direction_forward_level if duty >= 0 else not self.direction_forward_level
            flip = bool(self._latch[port] >> bit & 1) != level
            # One program whether the direction reverses or not (a batch of lanes runs it for every
            # lane alike, hal.lanes): the duty is zeroed first where the direction reverses and set
            # to its new value where it stays; then the line is written (and read back: a line stuck
            # the wrong way is found at the next command, not at the next reversal); then the duty.
            self.win.write("PWM_DUTY", 0 if flip else ticks)
            self.set_line(line, level)
        self.win.write("PWM_DUTY", ticks)

    def pwm_enable(self, on: bool) -> None:
        """Start (True) or stop (False) the PWM output."""
        self.win.write_fields("PWM_CTL", enable=int(bool(on)))

    def pwm_duty(self) -> float:
        """Unsigned duty fraction the board is producing now (0 when disabled)."""
        if not self.win.read_field("PWM_CTL", "enable"):
            return 0.0
        period = self.win.read("PWM_PERIOD")
        return min(self.win.read("PWM_DUTY"), period) / period if period else 0.0

    # --- lanes (batched lockstep, hal.lanes) ----------------------------------------------------
    @classmethod
    def from_lanes(cls, drivers: Sequence[PioDriver], bus: VmeBus) -> PioDriver:
        """One driver in lane mode for the B scalar ``drivers`` (lane order, each opened and
        configured on its instance's crate) on ``bus``, the crate of their lanes: the same board,
        wiring table, direction line and interrupt settings in every lane; the shadows of the
        direction registers, latches and PWM period are stacked. No bus cycle. A driver with an
        input-change callback cannot run in lanes (``NotImplementedError``)."""
        first = drivers[0]
        if cls is not PioDriver:
            raise NotImplementedError(f"{cls.__name__} has no lane mode")
        if not isinstance(bus.lanes, LaneSet):
            raise ValueError("a PIO driver in lanes needs a bus of lanes (bus.lanes)")

        def setup(d: PioDriver) -> tuple[Any, ...]:
            return (d.win.base, d.win.am, d.lines, d.irq_level, d.vector, d.pwm_direction_line,
                    d.direction_forward_level)

        for d in drivers:
            if type(d) is not cls:
                raise NotImplementedError(f"a {type(d).__name__} cannot share lanes with a {cls.__name__}")
            if d._handler_registered or d._line_cbs or d._port_cbs:
                raise NotImplementedError("a PIO driver with input-change interrupts runs scalar")
            if setup(d) != setup(first):
                raise NotImplementedError("the lanes' PIO drivers differ in board address, wiring or settings")
        obj = cls.__new__(cls)
        obj.win = BoardWindow(bus, first.win.base, PIO_REGS, first.win.am)
        obj.bus = bus
        obj.lines = dict(first.lines)
        obj.irq_level, obj.vector = first.irq_level, first.vector
        obj.pwm_direction_line = first.pwm_direction_line
        obj.direction_forward_level = first.direction_forward_level
        obj._ddr = [stack([d._ddr[i] for d in drivers]) for i in range(len(PORTS))]
        obj._latch = [stack([d._latch[i] for d in drivers]) for i in range(len(PORTS))]
        obj._ier = [stack([d._ier[i] for d in drivers]) for i in range(len(PORTS))]
        obj._line_cbs, obj._port_cbs, obj._handler_registered = {}, {}, False
        obj._period_ticks = stack([d._period_ticks for d in drivers])
        obj._lanes = bus.lanes
        for name in ("set_line", "get_line", "write_port", "verify_outputs", "on_change", "set_pwm_period", "set_pwm",
                     "pwm_duty"):
            setattr(obj, name, getattr(obj, "_lane_" + name.lstrip("_")))
        return obj

    def _lane_fail(self, cond: LaneValue, reason: str, error: Callable[[], Exception]) -> None:
        lane_fail(self._lanes, cond, reason, error)

    def _lane_output(self, name: str, port: int, bit: int, what: str) -> None:
        self._lane_fail((self._ddr[port] >> bit) & 1 == 0, f"PIO {what} {name!r} is an input",
                        lambda: LineDirectionError(
                            f"PIO line {name!r} ({self._pin_name(port, bit)}) is an input; "
                            "list it in configure(outputs=...) to drive it"))

    def _lane_set_line(self, name: str, level: LaneValue, *, verify: bool = True) -> None:
        port, bit = self.resolve(name)
        self._lane_output(name, port, bit, "line")
        latches: list[LaneValue] = self._latch
        latch, m = latches[port], 1 << bit
        if isinstance(level, np.ndarray):
            level = level.astype(bool)
            latches[port] = np.where(level, latch | m, latch & ~m & 0xFF)
        else:
            level = bool(level)
            latches[port] = latch | m if level else latch & ~m & 0xFF
        self.win.write(f"DATA_{PORTS[port]}", self._latch[port])
        if verify:
            pin = (self.win.read(f"PIN_{PORTS[port]}") >> bit) & 1 != 0
            self._lane_fail(pin != level, f"PIO line {name!r} does not follow its latch (LineStuckError)",
                            lambda: LineStuckError({name: bool(pin)}))

    def _lane_get_line(self, name: str) -> LaneValue:
        port, bit = self.resolve(name)
        return (self.win.read(f"DATA_{PORTS[port]}") >> bit) & 1 != 0

    def _lane_write_port(self, port: str | int, value: LaneValue) -> None:
        i = self._port(port)
        self._lane_fail((value < 0) | (value > 0xFF), f"PIO port {PORTS[i]}: a value that is not a byte",
                        lambda: ValueError(f"port value {value} is not a byte"))
        self._latch[i] = value
        self.win.write(f"DATA_{PORTS[i]}", value)

    def _lane_verify_outputs(self) -> None:
        bad: dict[str, bool] = {}
        stuck: Any = False
        names = {v: k for k, v in self.lines.items()}
        for i, p in enumerate(PORTS):
            ddr = self._ddr[i]
            if not self.bus.decide(ddr != 0, f"PIO port {p} has outputs in some lanes only"):
                continue
            diff = (self.win.read(f"PIN_{p}") ^ self._latch[i]) & ddr
            if isinstance(diff, np.ndarray):
                stuck = stuck | (diff != 0)
                continue
            for bit in range(LINES_PER_PORT):
                if diff >> bit & 1:
                    bad[names.get((i, bit), self._pin_name(i, bit))] = not (self._latch[i] >> bit & 1)
        if bad:
            raise LineStuckError(bad)
        self._lane_fail(stuck, "PIO output lines do not follow their latches (LineStuckError)",
                        lambda: LineStuckError({}))

    def _lane_on_change(self, target: str, callback: LineCallback | PortCallback) -> None:
        raise NotImplementedError("PIO input-change interrupts are not used in lanes (such runs go scalar)")

    def _lane_set_pwm_period(self, period_s: LaneValue) -> None:
        if not isinstance(period_s, np.ndarray):
            PioDriver.set_pwm_period(self, period_s)
            return
        with np.errstate(invalid="ignore"):  # round() per lane: half to even, as round() is
            ticks = np.where(np.isfinite(period_s), np.rint(period_s * PWM_CLOCK_HZ), -1).astype(np.int64)
        bad = (ticks < 2) | (ticks > 0xFFFF)
        self._lanes.eject(bad, "PWM period outside 2..65535 ticks (PwmRangeError)")
        self._period_ticks = np.where(bad, 2, ticks)  # type: ignore[assignment]  # a lane value
        self.win.write("PWM_PERIOD", self._period_ticks)

    def _lane_set_pwm(self, duty: LaneValue, direction_line: str | None = None,
                      period_s: LaneValue | None = None) -> None:
        # set_pwm with a duty per lane: the same checks (ejecting where one driver would raise
        # for some lanes) and the same cycles; a reversal some lanes make and others not goes
        # the majority's way (VmeBus.decide)
        lanes = self._lanes
        if isinstance(duty, np.ndarray):
            with np.errstate(invalid="ignore"):
                bad = ~(np.isfinite(duty) & (duty >= -1.0) & (duty <= 1.0))
            lanes.eject(bad, "PWM duty outside [-1, 1] (PwmRangeError)")
        elif not (math.isfinite(duty) and -1.0 <= duty <= 1.0):
            raise PwmRangeError(f"PWM duty {duty!r} is outside [-1, 1]")
        if period_s is not None:
            self.set_pwm_period(period_s)
        self._lane_fail(self._period_ticks == 0, "PWM period is 0 (PwmRangeError)", lambda: PwmRangeError(
            "PWM period is 0 (output held low); pass period_s or call set_pwm_period first"))
        line = direction_line if direction_line is not None else self.pwm_direction_line
        ticks = abs(duty) * self._period_ticks
        if isinstance(ticks, np.ndarray):  # round() per lane (half to even); an ejected lane's NaN: 0
            with np.errstate(invalid="ignore"):
                ticks = np.rint(np.where(ticks <= 0xFFFF, ticks, 0.0)).astype(np.int64)
        else:
            ticks = round(ticks)
        if line is None:
            self._lane_fail(duty < 0, "negative PWM duty without a direction line (PwmRangeError)",
                            lambda: PwmRangeError(f"negative duty {duty} needs a direction line (none configured)"))
        else:
            port, bit = self.resolve(line)
            self._lane_output(line, port, bit, "PWM direction line")
            level = (duty >= 0) == self.direction_forward_level
            flip = ((self._latch[port] >> bit) & 1 != 0) != level
            # set_pwm's one program: a lane that reverses zeroes its duty first, the others set theirs
            first = np.where(flip, 0, ticks) if isinstance(flip, np.ndarray) else 0 if flip else ticks
            self.win.write("PWM_DUTY", first)  # type: ignore[arg-type]  # a lane value
            self.set_line(line, level)
        self.win.write("PWM_DUTY", ticks)

    def _lane_pwm_duty(self) -> LaneValue:
        # pwm_duty's cycles depend on what it reads: lanes that would stop earlier are left
        if not self.bus.decide(self.win.read_field("PWM_CTL", "enable") != 0, "PWM on in some lanes only"):
            return 0.0
        period = self.win.read("PWM_PERIOD")
        if not self.bus.decide(period != 0, "PWM period 0 in some lanes only"):
            return 0.0
        duty = self.win.read("PWM_DUTY")
        if not isinstance(duty, np.ndarray) and not isinstance(period, np.ndarray):
            return min(duty, period) / period  # type: ignore[no-any-return]
        return np.where(period < duty, period, duty) / period  # min(duty, period) / period
