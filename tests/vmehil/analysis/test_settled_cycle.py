"""A simulated limit cycle that still grows through its window is said to be not settled."""

from __future__ import annotations

import math

import numpy as np

from vmehil.analysis.report import unsettled_note
from vmehil.analysis.simulate import SETTLED_FRACTION, window_thirds


def test_window_thirds_are_the_half_peak_to_peak_of_the_first_and_last_third() -> None:
    t = np.arange(0.0, 9.0, 0.008)
    growing = (0.2 + 0.1 * t) * np.sin(2 * math.pi * 1.5 * t)  # ±0.2 … ±1.1 over 0–9 s
    first, last = window_thirds(t, growing, 0.0)
    # by hand: the envelope at the thirds' ends, 0.2 + 0.1·3 = 0.5 and 0.2 + 0.1·9 = 1.1 (peaks
    # of a 1.5 Hz sine fall within 1/6 s of them)
    assert 0.45 <= first <= 0.5 and 1.05 <= last <= 1.1
    assert abs(last - first) > SETTLED_FRACTION * max(first, last)
    steady = 0.7 * np.sin(2 * math.pi * 1.5 * t)
    a, b = window_thirds(t, steady, 0.0)
    assert abs(a - 0.7) < 0.01 and abs(b - 0.7) < 0.01
    assert window_thirds(t[:10], steady[:10], 0.0) is None


def test_the_text_says_not_settled_only_when_the_simulation_says_so() -> None:
    sim = {"settled": False, "amplitude_first_third_deg": 0.393, "amplitude_last_third_deg": 0.692}
    assert "NOT SETTLED: ±0.393° in the window's first third, ±0.692° in its last" in unsettled_note(sim)
    assert unsettled_note({"settled": True}) == "" and unsettled_note({"settled": None}) == ""
