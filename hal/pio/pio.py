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
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

from hal.errors import HalError
from hal.pio.pio_regs import BOARD_TYPE, LINES_PER_PORT, PIO_REGS, PORTS, PWM_CLOCK_HZ, REVISION, parse_line
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.errors import BoardIdError
from hal.vme.window import BoardWindow

LineCallback = Callable[[str, bool], None]
"""``callback(name, level)`` for a line's input change (name as registered)."""
PortCallback = Callable[[str, int, int], None]
"""``callback(port, changed_mask, pin_levels)`` for a port's input changes."""


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
            if bool(self._latch[port] >> bit & 1) != level:
                self.win.write("PWM_DUTY", 0)
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
