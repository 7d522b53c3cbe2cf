"""Driver for a linear transconductance (current-mode) amplifier.

Wiring (from the rig file):

* command input ← a DAC channel (volts); the amplifier sets motor current = ``gain_a_per_v`` × volts
* enable ← a PIO output line (high = enabled)
* fault → a PIO input line (high = latched fault: over-current, over-temperature, compliance)
* fault reset ← a PIO output line (a high pulse clears the latch)
* current monitor → an ADC channel (``monitor_v_per_a`` volts per ampere)

The driver works in amperes; volts appear only at the converter edge. Joint torque becomes
current in one place, where the servo writes its commands with the calibrated scaling
(``servo.io.JointIO.write_torque``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from hal.errors import HalError


def clamp_current(current_a: float, limit_a: float) -> float:
    """``current_a`` limited to ±``limit_a`` (the amplifier's current limit)."""
    return max(-limit_a, min(limit_a, current_a))


def command_volts(current_a: float, gain_a_per_v: float, offset_a: float = 0.0) -> float:
    """Command volts for a current on an amplifier whose output is ``gain·v + offset`` (A)."""
    return (current_a - offset_a) / gain_a_per_v


class AmplifierFault(HalError, RuntimeError):
    """The amplifier's fault line is asserted (latched in the amplifier until reset)."""


class DacChannel(Protocol):
    def write_volts(self, channel: int, volts: float, update: bool = True) -> object: ...


class DigitalLines(Protocol):
    def set_line(self, name: str, level: bool) -> None: ...
    def get_line(self, name: str) -> bool: ...


class AnalogInput(Protocol):
    def read_volts(self, channel: int, gain: int = 1) -> float: ...


@dataclass(frozen=True)
class LinearAmpConfig:
    """Static description of one amplifier channel.

    Attributes:
        gain_a_per_v: transconductance, amperes of motor current per command volt.
        current_limit_a: the amplifier's own current limit (A); commands beyond it are clamped.
        monitor_v_per_a: current-monitor scaling (V/A).
        dac_channel: DAC channel driving the command input.
        monitor_channel: ADC channel reading the current monitor (``None`` if not wired).
        enable_line, fault_line, reset_line: PIO logical line names (``None`` if not wired).
        offset_a: output current at 0 V command (A; from calibration).
    """

    gain_a_per_v: float
    current_limit_a: float
    monitor_v_per_a: float
    dac_channel: int
    monitor_channel: int | None = None
    enable_line: str | None = None
    fault_line: str | None = None
    reset_line: str | None = None
    offset_a: float = 0.0


class LinearAmp:
    """Set current (A), enable/disable, read the monitor, clear faults."""

    def __init__(self, cfg: LinearAmpConfig, dac: DacChannel, pio: DigitalLines | None = None,
                 adc: AnalogInput | None = None) -> None:
        if cfg.gain_a_per_v <= 0 or cfg.monitor_v_per_a <= 0:
            raise ValueError("amplifier gain and monitor scaling must be positive")
        self.cfg, self.dac, self.pio, self.adc = cfg, dac, pio, adc
        self.commanded_a = 0.0

    def command_volts_for(self, current_a: float) -> float:
        """The DAC volts that command ``current_a`` (clamped to the current limit)."""
        cfg = self.cfg
        return command_volts(clamp_current(current_a, cfg.current_limit_a), cfg.gain_a_per_v, cfg.offset_a)

    def set_current(self, current_a: float, update: bool = True) -> float:
        """Command motor current (A); returns the volts written to the DAC."""
        volts = self.command_volts_for(current_a)
        self.dac.write_volts(self.cfg.dac_channel, volts, update=update)
        self.commanded_a = volts * self.cfg.gain_a_per_v + self.cfg.offset_a
        return volts

    def enable(self, on: bool = True) -> None:
        if self.pio is None or self.cfg.enable_line is None:
            raise ValueError("this amplifier has no enable line wired")
        self.pio.set_line(self.cfg.enable_line, on)

    def disable(self) -> None:
        """Zero the command and drop the enable line (safe state)."""
        self.set_current(0.0)
        if self.pio is not None and self.cfg.enable_line is not None:
            self.pio.set_line(self.cfg.enable_line, False)

    def faulted(self) -> bool:
        """True when the amplifier's fault line is asserted."""
        if self.pio is None or self.cfg.fault_line is None:
            return False
        return self.pio.get_line(self.cfg.fault_line)

    def check(self) -> None:
        """Raise :class:`AmplifierFault` if the fault line is asserted."""
        if self.faulted():
            raise AmplifierFault(f"amplifier on DAC channel {self.cfg.dac_channel}: fault line asserted; "
                                 "find the cause, then clear_fault()")

    def clear_fault(self) -> None:
        """Pulse the fault-reset line."""
        if self.pio is None or self.cfg.reset_line is None:
            raise ValueError("this amplifier has no fault-reset line wired")
        self.pio.set_line(self.cfg.reset_line, True)
        self.pio.set_line(self.cfg.reset_line, False)

    def monitor_current(self) -> float:
        """Motor current (A) from the current-monitor output read by the ADC."""
        if self.adc is None or self.cfg.monitor_channel is None:
            raise ValueError("this amplifier's current monitor is not wired to an ADC channel")
        return self.adc.read_volts(self.cfg.monitor_channel) / self.cfg.monitor_v_per_a

    def monitor_to_current(self, volts: float) -> float:
        """Convert a current-monitor reading taken elsewhere (e.g. an ADC scan) to amperes."""
        return volts / self.cfg.monitor_v_per_a
