"""The JPL grounding lesson: while the H-bridge switches, its noise shows in the ADC readings."""

from __future__ import annotations

import numpy as np

from vmehil.rig_setup.system import build_emulated_rig


def _reference_readings(system, n: int = 400) -> np.ndarray:
    adc = system.io.adc["adc1"]
    return np.array([adc.read_volts(12) for _ in range(n)])  # the +5 V precision reference


def test_hbridge_switching_raises_adc_noise() -> None:
    system = build_emulated_rig(None, seed=11)
    quiet = _reference_readings(system)
    hand = next(j for j in system.rig.joints if j.amplifier == "hbridge")
    pio = system.io.pio[hand.wiring["pwm"].board]
    pio.pwm_enable(True)
    pio.set_pwm(0.4, direction_line=hand.net("direction"))
    noisy = _reference_readings(system)
    pio.set_pwm(0.0, direction_line=hand.net("direction"))
    again = _reference_readings(system)
    level = system.rig.table.table("rig").get_float("hbridge_noise_v")
    # quiet: board noise + quantization only; switching adds the coupled rms in quadrature
    expected = np.hypot(np.std(quiet), level)
    assert 0.75 * expected < np.std(noisy) < 1.3 * expected
    assert np.std(noisy) > 2 * np.std(quiet)
    assert np.std(again) < 1.3 * np.std(quiet)  # coupling stops with the switching
    assert abs(np.mean(noisy) - np.mean(quiet)) < 0.002  # noise, not an offset
