"""Parallel I/O board: register map (:mod:`hal.pio.pio_regs`) and driver (:mod:`hal.pio.pio`)."""

from hal.pio.pio import (
    LineDirectionError,
    LineStuckError,
    PioBoardIdError,
    PioDriver,
    PioError,
    PwmRangeError,
    UnknownLineError,
)
from hal.pio.pio_regs import PIO_REGS, PWM_CLOCK_HZ

__all__ = [
    "PIO_REGS",
    "PWM_CLOCK_HZ",
    "LineDirectionError",
    "LineStuckError",
    "PioBoardIdError",
    "PioDriver",
    "PioError",
    "PwmRangeError",
    "UnknownLineError",
]
