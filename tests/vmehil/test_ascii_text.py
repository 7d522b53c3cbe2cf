"""One transliteration for 7-bit lines (serial terminals, MAVLink STATUSTEXT)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from vmehil.writers.ascii_text import to_ascii


def test_the_projects_symbols_read_as_an_engineer_would_type_them() -> None:
    assert to_ascii("Kp·T² ≤ 4 … ω ≥ 0.12 rad/s, ±0.74°, j1 ← j2 — done") == \
        "Kp*T^2 <= 4 ... w >= 0.12 rad/s, +/-0.74 deg, j1 <- j2 - done"
    assert to_ascii("s⁻¹ µm naïve") == "s^-1 um naive"


@given(st.text())
def test_any_text_comes_out_ascii_and_ascii_text_unchanged(text: str) -> None:
    out = to_ascii(text)
    assert out.isascii()
    if text.isascii():
        assert out == text
