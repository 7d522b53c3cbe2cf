"""Volts ↔ code conversions of the ADC and DAC boards (the drivers'; docs/boards/adc.md and dac.md
state the formulas, and the emulators compute them their own way).

Both boards are 12-bit (codes 0..4095). Coding:

* ADC bipolar range (±10 V / gain): **offset binary** — code 0 = −FS, 0x800 = 0 V,
  0xFFF = +FS − 1 LSB, with FS = 10 V / gain and LSB = 2·FS / 4096.
* ADC unipolar range (0..10 V / gain): **straight binary** — code 0 = 0 V, 0xFFF = FS − 1 LSB,
  with FS = 10 V / gain and LSB = FS / 4096.
* DAC (±10 V): offset binary like the ADC bipolar range at gain 1 (LSB = 4.8828 mV).

Quantization rounds to the nearest code (transitions half an LSB either side of each code's
centre), so a volts → code → volts round trip is within ½ LSB inside the range. Clipping rule:
an input beyond the range reads as the end code (0 or 0xFFF) — the converter saturates at the
rails, it never wraps. :func:`dac_volts_to_code` reports whether it had to clip so the DAC
driver can refuse or count it.
"""

from __future__ import annotations

import enum
import math

import numpy as np

from hal.errors import HalError
from hal.vme.errors import BoardIdError as VmeBoardIdError

BITS = 12
N_CODES = 1 << BITS  #: 4096
CODE_MAX = N_CODES - 1  #: 0xFFF
CODE_MID = N_CODES // 2  #: 0x800, 0 V in offset binary
ADC_GAINS = (1, 2, 4, 8)  #: programmable gains; the input range is divided by the gain
ADC_FULL_SCALE_V = 10.0
DAC_FULL_SCALE_V = 10.0
DAC_LSB_V = 2 * DAC_FULL_SCALE_V / N_CODES  #: 4.8828125 mV
DAC_V_MIN = -DAC_FULL_SCALE_V  #: volts of code 0
DAC_V_MAX = DAC_FULL_SCALE_V - DAC_LSB_V  #: volts of code 0xFFF (+9.99512 V)


class AdcDacError(HalError):
    """Base class of the ADC/DAC driver errors."""


class BoardIdError(AdcDacError, VmeBoardIdError):
    """The board at the given address did not answer with the expected ID register value."""


class AdcRange(enum.Enum):
    """ADC input range (CSR.RANGE bit): ±10 V offset binary, or 0–10 V straight binary."""

    BIPOLAR_10V = "bipolar"
    UNIPOLAR_10V = "unipolar"

    @classmethod
    def parse(cls, value: AdcRange | str) -> AdcRange:
        if isinstance(value, AdcRange):
            return value
        s = str(value).strip().lower()
        for r in cls:
            if s in (r.value, r.name.lower()):
                return r
        raise ValueError(f"unknown ADC range {value!r}; expected 'bipolar' (±10 V) or 'unipolar' (0..10 V)")


def check_gain(gain: int) -> int:
    """Return ``gain`` if it is one of 1, 2, 4, 8; ``ValueError`` otherwise."""
    if gain not in ADC_GAINS:
        raise ValueError(f"ADC gain {gain!r} is not one of {ADC_GAINS}")
    return int(gain)


def gain_code(gain: int) -> int:
    """The 2-bit register code of a gain (1→0, 2→1, 4→2, 8→3)."""
    return ADC_GAINS.index(check_gain(gain))


def gain_from_code(code: int) -> int:
    return ADC_GAINS[code & 0x3]


def adc_lsb(rng: AdcRange, gain: int = 1) -> float:
    """Volts per code of the ADC in ``rng`` at ``gain`` (bipolar gain 1: 4.8828 mV)."""
    span = (2 if rng is AdcRange.BIPOLAR_10V else 1) * ADC_FULL_SCALE_V / check_gain(gain)
    return span / N_CODES


def adc_span(rng: AdcRange, gain: int = 1) -> tuple[float, float]:
    """Volts of code 0 and of code 0xFFF (the ends of the representable range)."""
    lsb = adc_lsb(rng, gain)
    v0 = -ADC_FULL_SCALE_V / gain if rng is AdcRange.BIPOLAR_10V else 0.0
    return v0, v0 + CODE_MAX * lsb


def adc_volts_to_code(volts: float, rng: AdcRange, gain: int = 1) -> int:
    """Input volts → 12-bit code: round to nearest, clip to 0..0xFFF (saturation, no wrap).

    A NaN input is a modelling bug, not a voltage: it is rejected with ``ValueError``.
    """
    if math.isnan(volts):
        raise ValueError("ADC input is NaN")
    v0, _ = adc_span(rng, gain)
    code = math.floor((volts - v0) / adc_lsb(rng, gain) + 0.5)
    return min(max(code, 0), CODE_MAX)


def adc_code_to_volts(code: int, rng: AdcRange, gain: int = 1) -> float:
    """12-bit code → volts at the code centre."""
    if not 0 <= code <= CODE_MAX:
        raise ValueError(f"ADC code {code} is outside 0..0x{CODE_MAX:X}")
    v0, _ = adc_span(rng, gain)
    return v0 + code * adc_lsb(rng, gain)


def adc_codes_to_volts(codes, rng: AdcRange, gains=1) -> np.ndarray:
    """Array form of :func:`adc_code_to_volts` (``gains`` a scalar or one per code)."""
    c = np.asarray(codes, dtype=float)
    g = np.broadcast_to(np.asarray(gains, dtype=float), c.shape)
    if rng is AdcRange.BIPOLAR_10V:
        lsb = 2 * ADC_FULL_SCALE_V / g / N_CODES
        return -ADC_FULL_SCALE_V / g + c * lsb
    return c * (ADC_FULL_SCALE_V / g / N_CODES)


def dac_volts_to_code(volts: float) -> tuple[int, bool]:
    """DAC output volts → (offset-binary code, clipped).

    ``clipped`` is ``True`` when ``volts`` lies outside [−10 V − ½ LSB, +9.99512 V + ½ LSB]
    (a NaN is rejected with ``ValueError``); the code is then the nearer end code.
    """
    if math.isnan(volts):
        raise ValueError("DAC command is NaN")
    code = math.floor((volts - DAC_V_MIN) / DAC_LSB_V + 0.5)
    if code < 0:
        return 0, True
    if code > CODE_MAX:
        return CODE_MAX, True
    return code, False


def dac_volts_to_codes(volts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Array form of :func:`dac_volts_to_code`, element by element with the same float math (so
    the same codes, bit for bit): ``(codes, clipped, invalid)`` — int64, bool and bool arrays of
    ``volts``' shape. ``invalid`` marks the elements the scalar form rejects (NaN: ``ValueError``;
    ±inf, or a value whose code overflows a float: ``OverflowError``); they get the 0 V code
    0x800, unclipped."""
    v = np.asarray(volts, dtype=float)
    with np.errstate(invalid="ignore", over="ignore"):
        code = np.floor((v - DAC_V_MIN) / DAC_LSB_V + 0.5)
    invalid = ~np.isfinite(code)
    code = np.where(invalid, CODE_MID, code)
    low, high = code < 0, code > CODE_MAX
    codes = np.where(low, 0, np.where(high, CODE_MAX, code)).astype(np.int64)
    return codes, low | high, invalid


def dac_code_to_volts(code: int) -> float:
    """Offset-binary code → ideal DAC output volts (0x800 = 0 V)."""
    if not 0 <= code <= CODE_MAX:
        raise ValueError(f"DAC code {code} is outside 0..0x{CODE_MAX:X}")
    return DAC_V_MIN + code * DAC_LSB_V
