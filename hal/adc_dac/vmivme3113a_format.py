"""The VMIVME-3113A's named conversions: jumpered input ranges, data formats, word → code → volts
(``docs/boards/vmivme-3113a.md``, "Conversion"). The servo and the driver convert through these,
never with the reference ADC's formulas (other ranges, no gain, two's complement possible).

* Range (board jumpers, not a register): ±10 V, ±5 V or 0..10 V; ``LSB = span / 4096``,
  ``V₀`` = volts of code 0 (−10 V, −5 V, 0 V).
* Offset-binary code 0..0xFFF: ``V = V₀ + code · LSB`` (the code's centre).
* Two's-complement word: bits 11:0 are the code with bit 11 inverted, bits 15:12 its sign.
"""

from __future__ import annotations

import enum

import numpy as np

CODE_MAX = 0xFFF
_MSB = 0x800


class Vmi3113aRange(enum.Enum):
    """The input range the board's jumpers select: name → (V₀, span in volts)."""

    BIPOLAR_10V = "bipolar_10v"
    BIPOLAR_5V = "bipolar_5v"
    UNIPOLAR_10V = "unipolar_10v"

    @classmethod
    def parse(cls, value: Vmi3113aRange | str) -> Vmi3113aRange:
        if isinstance(value, Vmi3113aRange):
            return value
        s = str(value).strip().lower()
        for r in cls:
            if s == r.value:
                return r
        raise ValueError(f"unknown VMIVME-3113A input range {value!r}; expected one of "
                         + ", ".join(r.value for r in cls))

    @property
    def v0(self) -> float:
        """Volts of code 0."""
        return _V0_SPAN[self][0]

    @property
    def span_v(self) -> float:
        return _V0_SPAN[self][1]

    @property
    def bipolar(self) -> bool:
        return self.v0 < 0


_V0_SPAN = {
    Vmi3113aRange.BIPOLAR_10V: (-10.0, 20.0),
    Vmi3113aRange.BIPOLAR_5V: (-5.0, 10.0),
    Vmi3113aRange.UNIPOLAR_10V: (0.0, 10.0),
}


class Vmi3113aFormat(enum.Enum):
    """The data coding CSR.TWOS_COMPLEMENT selects."""

    OFFSET_BINARY = "offset_binary"
    TWOS_COMPLEMENT = "twos_complement"

    @classmethod
    def parse(cls, value: Vmi3113aFormat | str) -> Vmi3113aFormat:
        if isinstance(value, Vmi3113aFormat):
            return value
        s = str(value).strip().lower()
        for f in cls:
            if s == f.value:
                return f
        raise ValueError(f"unknown VMIVME-3113A data format {value!r}; expected offset_binary or twos_complement")


def lsb_v(rng: Vmi3113aRange) -> float:
    """Volts of one code in ``rng`` (±10 V: 4.8828125 mV)."""
    return rng.span_v / (CODE_MAX + 1)


def code_from_word(word: int, fmt: Vmi3113aFormat) -> int:
    """A CHk word → its offset-binary code 0..0xFFF."""
    code = word & CODE_MAX
    return code ^ _MSB if fmt is Vmi3113aFormat.TWOS_COMPLEMENT else code


def codes_from_words(words: np.ndarray, fmt: Vmi3113aFormat) -> np.ndarray:
    """Array form of :func:`code_from_word`."""
    codes = np.asarray(words, dtype=np.int64) & CODE_MAX
    return codes ^ _MSB if fmt is Vmi3113aFormat.TWOS_COMPLEMENT else codes


def volts_from_code(code: int, rng: Vmi3113aRange) -> float:
    """Offset-binary code → volts at the code's centre."""
    if not 0 <= code <= CODE_MAX:
        raise ValueError(f"VMIVME-3113A code {code} is outside 0..0x{CODE_MAX:X}")
    return rng.v0 + code * lsb_v(rng)


def volts_from_codes(codes: np.ndarray, rng: Vmi3113aRange) -> np.ndarray:
    """Array form of :func:`volts_from_code`."""
    return rng.v0 + np.asarray(codes, dtype=float) * lsb_v(rng)
