"""Amplifier drivers: a linear transconductance amplifier (DAC command, PIO enable/fault,
ADC current monitor) and an H-bridge (PIO PWM, direction, brake, faults, ADC monitor)."""

from hal.amplifiers.hbridge import HBridgeAmp, HBridgeConfig, duty_for_current, duty_for_current_array
from hal.amplifiers.linear import (
    AmplifierFault,
    LinearAmp,
    LinearAmpConfig,
    clamp_current,
    command_volts,
)

__all__ = ["AmplifierFault", "HBridgeAmp", "HBridgeConfig", "LinearAmp", "LinearAmpConfig", "clamp_current",
           "command_volts", "duty_for_current", "duty_for_current_array"]
