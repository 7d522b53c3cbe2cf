"""Registers the built-in procedures (import this module to get them in ``PROCEDURES``)."""

from __future__ import annotations

from vmehil.calibration.adc import AdcProcedure
from vmehil.calibration.amplifier import AmplifierProcedure
from vmehil.calibration.base import (
    PROCEDURES,
    CalibrationAbort,
    CalibrationContext,
    Check,
    ProcedureResult,
    register_procedure,
)
from vmehil.calibration.dac import DacProcedure
from vmehil.calibration.encoder import EncoderProcedure
from vmehil.calibration.pot import PotProcedure
from vmehil.calibration.store import (
    CalibrationFileError,
    CalibrationStore,
    default_store_path,
    load_store,
)

# Order in `calibrate all`: converters first (everything else is measured through them), then
# the encoder and the amplifiers (the servo loop uses them), then the pots (moved by the loop).
register_procedure("adc", AdcProcedure, order=10, help="ADC offset/gain from references (+ loopback linearity)")
register_procedure("dac", DacProcedure, order=20, help="DAC offset/gain through the loopback, with the calibrated ADC")
register_procedure("encoder", EncoderProcedure, order=30, help="encoder counts/rev index to index, index, direction")
register_procedure("amplifier", AmplifierProcedure, order=40,
                   help="amplifier transconductance and offset from the current monitor, current limit")
register_procedure("pot", PotProcedure, order=50, help="potentiometers: nine points 45° apart, eight segments")

__all__ = [
    "PROCEDURES",
    "AdcProcedure",
    "AmplifierProcedure",
    "CalibrationAbort",
    "CalibrationContext",
    "CalibrationFileError",
    "CalibrationStore",
    "Check",
    "DacProcedure",
    "EncoderProcedure",
    "PotProcedure",
    "ProcedureResult",
    "default_store_path",
    "load_store",
    "register_procedure",
]
