"""The calibration procedures ``vmehil calibrate`` (and the console's ``calibrate``) can run.

:data:`PROCEDURES` is the built-in table plus the entry points of group
``vmehil.calibration_procedures``: each names a :class:`~vmehil.calibration.base.ProcedureSpec`.
The plant's ``friction`` procedure comes that way (this project's ``pyproject.toml``), as a
third-party one would: it runs the servo loop on an emulated rig, which is built on this package,
so the table cannot import it.
"""

from __future__ import annotations

from typing import Any

from hal.plugins import PluginTable
from vmehil.calibration.adc import AdcProcedure
from vmehil.calibration.amplifier import AmplifierProcedure
from vmehil.calibration.base import (
    CalibrationAbort,
    CalibrationContext,
    Check,
    ProcedureResult,
    ProcedureSpec,
)
from vmehil.calibration.dac import DacProcedure
from vmehil.calibration.encoder import EncoderProcedure
from vmehil.calibration.home import HomeProcedure
from vmehil.calibration.pot import PotProcedure
from vmehil.calibration.store import (
    CalibrationFileError,
    CalibrationStore,
    default_store_path,
    load_store,
)

#: ``calibrate all``: every procedure with ``in_all``, in order; no procedure may take the name.
ALL = "all"

# Order in `calibrate all`: converters first (everything else is measured through them), then
# the encoder and the amplifiers (the servo loop uses them), then the pots (moved by the loop).
BUILTIN_PROCEDURES: dict[str, ProcedureSpec] = {spec.name: spec for spec in (
    ProcedureSpec("adc", AdcProcedure, order=10, help="ADC offset/gain from references (+ loopback linearity)"),
    ProcedureSpec("dac", DacProcedure, order=20, help="DAC offset/gain through the loopback, with the calibrated ADC"),
    ProcedureSpec("encoder", EncoderProcedure, order=30, help="encoder counts/rev index to index, index, direction"),
    ProcedureSpec("amplifier", AmplifierProcedure, order=40,
                  help="amplifier transconductance and offset from the current monitor, current limit"),
    ProcedureSpec("pot", PotProcedure, order=50, help="potentiometers: nine points 45° apart, eight segments",
                  asks_operator=True),
    # not in `all`: homing references the encoders for this session only (the record is written,
    # never put in force at start), and it needs the pots calibrated first
    ProcedureSpec("home", HomeProcedure, order=60, help="home the encoders to the motor index the calibrated pot "
                  "chooses (this session; recorded)", in_all=False),
)}


def _spec(name: str, obj: Any) -> ProcedureSpec:
    if not isinstance(obj, ProcedureSpec):
        raise TypeError(f"a calibration procedure entry point names a ProcedureSpec, not {type(obj).__name__}")
    if name == ALL:
        raise ValueError(f"{ALL!r} means every procedure; choose another name")
    if obj.name != name:
        raise ValueError(f"the entry point is named {name!r} but its ProcedureSpec {obj.name!r}")
    return obj


PROCEDURES: PluginTable[ProcedureSpec] = PluginTable("vmehil.calibration_procedures", "calibration procedure",
                                                     BUILTIN_PROCEDURES, _spec)


def procedures_in_order() -> list[ProcedureSpec]:
    """Every procedure, in the order of ``calibrate all`` (for ``--help`` and the console)."""
    return sorted(PROCEDURES.values(), key=lambda p: p.order)


def procedures_for_all() -> list[ProcedureSpec]:
    """What ``calibrate all`` runs, in order."""
    return [p for p in procedures_in_order() if p.in_all]


__all__ = [
    "ALL",
    "BUILTIN_PROCEDURES",
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
    "HomeProcedure",
    "PotProcedure",
    "ProcedureResult",
    "default_store_path",
    "load_store",
    "procedures_for_all",
    "procedures_in_order",
]
