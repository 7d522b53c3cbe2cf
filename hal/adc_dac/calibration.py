"""Per-channel offset/gain calibration of the ADC and DAC boards.

A calibration records each channel's measured straight-line error model:

* ADC channel: ``reading = gain · true_input + offset_v``
* DAC channel: ``actual_output = gain · commanded + offset_v``

and the driver inverts it with :meth:`Calibration.correct` (``(v − offset_v) / gain``): on an ADC
the reading is corrected into the true input; on a DAC the wanted output is turned into the
command that produces it. Identity: ``offset_v = 0``, ``gain = 1``. Units: volts, gain
dimensionless.

Dictionary form (TOML-friendly, used by the calibration store)::

    {"offset_v": [0.0012, -0.0004, ...], "gain": [1.0005, 0.9991, ...]}
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.adc_dac.conversions import AdcDacError


class CalibrationError(AdcDacError, ValueError):
    """A calibration table is malformed (wrong length, non-finite or non-positive gain)."""


@dataclass(frozen=True)
class Calibration:
    """Per-channel offset (V) and gain of one board; index = channel."""

    offset_v: tuple[float, ...]
    gain: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.offset_v) != len(self.gain):
            raise CalibrationError(
                f"calibration has {len(self.offset_v)} offsets but {len(self.gain)} gains; give one of each per channel"
            )
        for ch, (o, g) in enumerate(zip(self.offset_v, self.gain, strict=True)):
            if not math.isfinite(o):
                raise CalibrationError(f"calibration channel {ch}: offset_v {o!r} is not a finite number of volts")
            if not (math.isfinite(g) and g > 0):
                raise CalibrationError(f"calibration channel {ch}: gain {g!r} must be a finite number > 0")

    @classmethod
    def identity(cls, channels: int) -> Calibration:
        return cls((0.0,) * channels, (1.0,) * channels)

    @property
    def channels(self) -> int:
        return len(self.gain)

    def correct(self, channel: int, volts: float) -> float:
        """Invert the channel's error model: ``(volts − offset_v) / gain``."""
        return (volts - self.offset_v[channel]) / self.gain[channel]

    def correct_array(self, channels: Sequence[int], volts) -> np.ndarray:
        """Vector form of :meth:`correct` for ``volts[i]`` measured on ``channels[i]``."""
        idx = np.asarray(channels, dtype=int)
        return (np.asarray(volts, dtype=float) - np.asarray(self.offset_v)[idx]) / np.asarray(self.gain)[idx]

    def apply(self, channel: int, volts: float) -> float:
        """The error model itself: ``gain · volts + offset_v`` (what the channel does)."""
        return self.gain[channel] * volts + self.offset_v[channel]

    def to_dict(self) -> dict[str, list[float]]:
        return {"offset_v": list(self.offset_v), "gain": list(self.gain)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], channels: int | None = None) -> Calibration:
        """Build from ``{"offset_v": [...], "gain": [...]}``; either key may be omitted (identity),
        but then ``channels`` must say how many. ``channels`` also checks the lengths."""
        unknown = set(data) - {"offset_v", "gain"}
        if unknown:
            raise CalibrationError(f"calibration has unknown keys {sorted(unknown)}; expected offset_v and gain")
        offs = data.get("offset_v")
        gains = data.get("gain")
        n = channels
        for key, seq in (("offset_v", offs), ("gain", gains)):
            if seq is None:
                continue
            if not isinstance(seq, Sequence) or isinstance(seq, str) or not all(
                isinstance(x, int | float) and not isinstance(x, bool) for x in seq
            ):
                raise CalibrationError(f"calibration key {key!r}: expected a list of numbers, got {seq!r}")
            if n is None:
                n = len(seq)
            if len(seq) != n:
                raise CalibrationError(
                    f"calibration key {key!r}: expected {n} values (one per channel), got {len(seq)}"
                )
        if n is None:
            raise CalibrationError("calibration has neither offset_v nor gain; cannot tell the channel count")
        return cls(
            tuple(float(x) for x in offs) if offs is not None else (0.0,) * n,
            tuple(float(x) for x in gains) if gains is not None else (1.0,) * n,
        )
