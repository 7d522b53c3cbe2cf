"""Limit-cycle and settling measurements on synthetic signals with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from vmehil.reports.metrics import limit_cycle, settling_time


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


POT_STEP_RAD = 5.934 / 4096  # one code of jpl-arm's 12-bit pot ADC over its 340° travel


def _quantized(x: np.ndarray, step: float) -> np.ndarray:
    return np.round(x / step) * step


def test_adc_noise_on_a_still_joint_is_not_a_limit_cycle() -> None:
    """A still joint read through a 12-bit pot with ±1.5 codes of noise: half peak-to-peak ≈ 3 codes
    (0.25°, what the first run's table used to call a cycle) with its spectrum peak anywhere up
    to Nyquist — no cycle by the rule."""
    rng = np.random.default_rng(0)
    t = np.arange(0, 12, 0.008)
    x = _quantized(0.3 + rng.normal(0.0, 0.9 * POT_STEP_RAD, t.size), POT_STEP_RAD)
    lc = limit_cycle(t, x, 2.0, quantum_rad=POT_STEP_RAD)
    assert lc.amplitude_rad is not None and 2 * POT_STEP_RAD <= lc.amplitude_rad <= 4 * POT_STEP_RAD
    assert not lc.cycle and lc.frequency_hz is None
    assert lc.spectrum_peak_hz is not None and lc.spectrum_peak_hz > 12.5  # white noise peaks high up


def test_a_real_cycle_read_through_the_same_pot_is_reported() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(0, 12, 0.008)
    true = 0.3 + np.radians(0.74) * np.sin(2 * np.pi * 1.5 * t)
    x = _quantized(true + rng.normal(0.0, 0.9 * POT_STEP_RAD, t.size), POT_STEP_RAD)
    lc = limit_cycle(t, x, 2.0, quantum_rad=POT_STEP_RAD)
    assert lc.cycle
    assert lc.frequency_hz == pytest.approx(1.5, rel=0.05)
    # half peak-to-peak of the reading: the cycle plus the noise's extremes (≤ 3 codes)
    assert 0.74 <= lc.amplitude_deg <= 0.74 + 3 * np.degrees(POT_STEP_RAD)


def test_a_small_slow_motion_below_four_sensor_steps_is_not_a_cycle() -> None:
    t = np.arange(0, 12, 0.008)
    x = _quantized(np.radians(0.2) * np.sin(2 * np.pi * 1.5 * t), POT_STEP_RAD)  # ±2.4 codes
    assert not limit_cycle(t, x, 2.0, quantum_rad=POT_STEP_RAD).cycle
    assert limit_cycle(t, x, 2.0).cycle  # the same motion on an unquantized reading is one


def test_a_fast_oscillation_near_nyquist_is_not_a_limit_cycle() -> None:
    t = np.arange(0, 12, 0.008)  # Nyquist 62.5 Hz
    x = np.radians(0.8) * np.sin(2 * np.pi * 28.0 * t)
    lc = limit_cycle(t, x, 2.0)
    assert lc.spectrum_peak_hz == pytest.approx(28.0, abs=0.2) and not lc.cycle


def test_a_hold_too_short_to_measure_has_no_amplitude() -> None:
    t = np.arange(0, 1.0, 0.008)
    lc = limit_cycle(t, np.zeros_like(t), 2.0)  # the window starts after the run ended
    assert lc.amplitude_rad is None and lc.amplitude_deg is None and not lc.cycle


def test_run_table_prints_a_dash_for_no_cycle_and_states_the_rule() -> None:
    from vmehil.reports.run_report import table

    def joint(name: str, amp, freq, cycle):
        lc = {"amplitude_deg": amp, "frequency_hz": freq, "cycle": cycle}
        return {"name": name, "final_error_deg": 0.1, "max_tracking_error_deg": 0.2, "limit_cycle": lc,
                "limit_cycle_pot": dict(lc)}

    joints = [joint("j1", 0.74, 1.5, True), joint("j2", 0.249, None, False), joint("j3", None, None, False)]
    summary = {"rig": "r", "mode": "lockstep", "ticks": 1, "duration_s": 0.008, "overruns": 0, "faults": [],
               "joints": joints}
    lines = table(summary).splitlines()
    j1, j2, j3 = (next(line for line in lines if line.startswith(n)) for n in ("j1", "j2", "j3"))
    assert "0.740" in j1 and "1.50" in j1
    assert "0.249" not in j2 and j2.split()[3:] == ["—", "—", "—"]
    assert "0.000" not in j3 and j3.split()[3:] == ["—", "—", "—"]
    assert any("4 sensor steps" in line and "Nyquist" in line for line in lines)


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_irregular_hunting_whose_crossings_disagree_with_its_spectrum_is_not_a_cycle(seed: int) -> None:
    """A slow random wander of ±0.04° (high-passed random walk): big enough, slow enough, but not
    periodic — its crossing rate and its spectrum peak disagree by more than a factor of 2."""
    t = np.arange(0, 12, 0.008)
    w = np.cumsum(np.random.default_rng(seed).normal(0, 1, t.size))
    w -= np.convolve(w, np.ones(250) / 250, "same")
    x = np.radians(0.04) * w / np.max(np.abs(w[250:-250]))
    lc = limit_cycle(t, x, 2.0, t_end=10.0)
    assert lc.amplitude_deg is not None and lc.amplitude_deg > 0.02
    assert not lc.cycle
