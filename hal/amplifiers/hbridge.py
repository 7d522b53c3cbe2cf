"""Driver for a PWM H-bridge amplifier (the gripper motor in the default rig).

Wiring: PIO PWM timer → bridge duty; PIO output lines → direction and brake; PIO input line
← latched fault (over-current or thermal); PIO output → fault reset; ADC ← current monitor.
Duty is signed in [-1, 1]: the sign selects the direction line, the magnitude the PWM duty.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from hal.amplifiers.linear import AmplifierFault, AnalogInput


def duty_for_current(current_a: float, resistance_ohm: float, ke_v_s_per_rad: float,
                     omega_motor_rad_s: float, supply_v: float) -> float:
    """Signed PWM duty that drives ``current_a`` into a motor turning at ``omega_motor_rad_s``:
    V = R·i + Ke·ω (steady state, back-EMF fed forward), as a fraction of the supply, in [-1, 1]."""
    return max(-1.0, min(1.0, (resistance_ohm * current_a + ke_v_s_per_rad * omega_motor_rad_s) / supply_v))


def duty_for_current_array(current_a: np.ndarray, resistance_ohm, ke_v_s_per_rad, omega_motor_rad_s,
                           supply_v) -> np.ndarray:
    """Array form of :func:`duty_for_current` (element by element, arguments broadcast): the
    same float operations and the same clamps (``min``/``max`` written as the comparisons they
    make, so a NaN clamps to +1 as there), so the same duties bit for bit."""
    d = (resistance_ohm * np.asarray(current_a, dtype=float) + ke_v_s_per_rad * omega_motor_rad_s) / supply_v
    d = np.where(d < 1.0, d, 1.0)  # min(1.0, d)
    return np.where(d > -1.0, d, -1.0)  # max(-1.0, ·)


class PwmLines(Protocol):
    def set_line(self, name: str, level: bool) -> None: ...
    def get_line(self, name: str) -> bool: ...
    def set_pwm(self, duty: float, direction_line: str | None = None) -> object: ...


@dataclass(frozen=True)
class HBridgeConfig:
    """Static description of one H-bridge.

    Attributes:
        supply_v: bridge supply (V); average output ≈ duty × supply (before dead-time loss).
        direction_line, brake_line, fault_line, reset_line, enable_line: PIO logical names.
        monitor_channel: ADC channel of the current monitor; ``monitor_v_per_a`` its scaling.
    """

    supply_v: float
    direction_line: str
    brake_line: str | None = None
    fault_line: str | None = None
    reset_line: str | None = None
    enable_line: str | None = None
    monitor_channel: int | None = None
    monitor_v_per_a: float = 1.0


class HBridgeAmp:
    """Set duty or average voltage, brake, coast, read faults and current."""

    def __init__(self, cfg: HBridgeConfig, pio: PwmLines, adc: AnalogInput | None = None) -> None:
        self.cfg, self.pio, self.adc = cfg, pio, adc
        self.duty = 0.0

    def set_duty(self, duty: float) -> None:
        """Signed duty in [-1, 1]; releases the brake."""
        if not -1.0 <= duty <= 1.0 or duty != duty:
            raise ValueError(f"H-bridge duty {duty} is outside [-1, 1]")
        if self.cfg.brake_line is not None:
            self.pio.set_line(self.cfg.brake_line, False)
        self.pio.set_pwm(duty, direction_line=self.cfg.direction_line)
        self.duty = duty

    def set_voltage(self, volts: float) -> float:
        """Average motor voltage (V), clamped to ±supply; returns the duty used."""
        duty = max(-1.0, min(1.0, volts / self.cfg.supply_v))
        self.set_duty(duty)
        return duty

    def brake(self) -> None:
        """Short the winding (dynamic brake): PWM off, brake line high."""
        self.pio.set_pwm(0.0, direction_line=self.cfg.direction_line)
        if self.cfg.brake_line is None:
            raise ValueError("this H-bridge has no brake line wired")
        self.pio.set_line(self.cfg.brake_line, True)
        self.duty = 0.0

    def coast(self) -> None:
        """All switches off: the current decays through the freewheel diodes."""
        self.pio.set_pwm(0.0, direction_line=self.cfg.direction_line)
        if self.cfg.brake_line is not None:
            self.pio.set_line(self.cfg.brake_line, False)
        self.duty = 0.0

    def enable(self, on: bool = True) -> None:
        if self.cfg.enable_line is not None:
            self.pio.set_line(self.cfg.enable_line, on)

    def disable(self) -> None:
        self.coast()
        self.enable(False)

    def faulted(self) -> bool:
        return self.cfg.fault_line is not None and self.pio.get_line(self.cfg.fault_line)

    def check(self) -> None:
        if self.faulted():
            raise AmplifierFault("H-bridge fault line asserted (over-current or thermal); clear_fault() after cooling")

    def clear_fault(self) -> None:
        if self.cfg.reset_line is None:
            raise ValueError("this H-bridge has no fault-reset line wired")
        self.pio.set_line(self.cfg.reset_line, True)
        self.pio.set_line(self.cfg.reset_line, False)

    def monitor_current(self) -> float:
        if self.adc is None or self.cfg.monitor_channel is None:
            raise ValueError("this H-bridge's current monitor is not wired")
        return self.adc.read_volts(self.cfg.monitor_channel) / self.cfg.monitor_v_per_a
