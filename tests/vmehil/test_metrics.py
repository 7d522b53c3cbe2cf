"""Limit-cycle and settling measurements on synthetic signals with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from vmehil.metrics import limit_cycle, settling_time


@pytest.mark.parametrize("amp_deg,freq", [(0.75, 2.0), (0.3, 1.2), (1.0, 3.1)])
def test_limit_cycle_of_a_sine_recovers_amplitude_and_frequency(amp_deg: float, freq: float) -> None:
    t = np.arange(0, 12, 0.008)
    x = 0.1 + np.radians(amp_deg) * np.sin(2 * np.pi * freq * t + 0.3)
    lc = limit_cycle(t, x, 2.0)
    assert lc.amplitude_deg == pytest.approx(amp_deg, rel=0.01)
    assert lc.frequency_hz == pytest.approx(freq, rel=0.02)
    assert lc.spectrum_peak_hz == pytest.approx(freq, abs=0.15)
    assert lc.mean_rad == pytest.approx(0.1, abs=1e-3)


def test_no_cycle_gives_null_frequency() -> None:
    t = np.arange(0, 10, 0.008)
    x = np.full_like(t, 0.2) + np.radians(0.005) * np.sin(2 * np.pi * 2 * t)
    lc = limit_cycle(t, x, 1.0)
    assert lc.frequency_hz is None
    assert lc.amplitude_deg < 0.01


def test_settling_time_finds_last_exit_from_band() -> None:
    t = np.arange(0, 5, 0.01)
    err = np.exp(-t)
    ts = settling_time(t, err, 0.0, 0.05)
    assert ts == pytest.approx(-np.log(0.05), abs=0.011)
    assert settling_time(t, np.ones_like(t), 0.0, 0.5) is None
