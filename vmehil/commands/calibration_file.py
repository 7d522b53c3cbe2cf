"""The drivers' calibration file a command uses, said on stderr: one helper for `vmehil run` and
the simulating `vmehil tune` analyses (limit-cycle, sweep, step), so both load it the same way."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    from servo.rig import RigSpec

T = TypeVar("T")


def calibrated(calibration: str | None, rig: RigSpec, use: Callable[[str | Path], T]) -> T:
    """``use(path)`` with the drivers' calibration file (``calibration``: ``--calibration``, which must exist, or
    None: the rig's default file); a missing default file is a one-line warning (nominal values)."""
    import warnings

    from vmehil.calibration.store import CalibrationMissingWarning, default_store_path

    if calibration and not Path(calibration).exists():
        raise FileNotFoundError(f"--calibration {calibration}: no such file")
    cal = calibration or default_store_path(rig)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationMissingWarning)
        result = use(cal)
    for w in caught:
        if issubclass(w.category, CalibrationMissingWarning):
            print(f"warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if not caught:
        print(f"calibration: {cal}", file=sys.stderr)
    return result
