"""Parallel I/O boards: the reference PIO (register map :mod:`hal.pio.pio_regs`, driver :mod:`hal.pio.pio`)
and the VMIC VMIVME-2536 (:mod:`hal.pio.vmivme2536_regs`, :mod:`hal.pio.vmivme2536`)."""

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
from hal.pio.vmivme2536 import Vmi2536BoardIdError, Vmi2536Driver
from hal.pio.vmivme2536_regs import VMI2536_REGS

__all__ = [
    "PIO_REGS",
    "PWM_CLOCK_HZ",
    "VMI2536_REGS",
    "LineDirectionError",
    "LineStuckError",
    "PioBoardIdError",
    "PioDriver",
    "PioError",
    "PwmRangeError",
    "UnknownLineError",
    "Vmi2536BoardIdError",
    "Vmi2536Driver",
]
