"""servo.gain_guard: the validation every live gain change goes through."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servo.control.law import PidLaw, SwitchOffConfig
from servo.control.linear import continuous_poles, sampled_loop_matrix
from servo.gain_guard import GainRejected, check_gain_change, loop_poles, spectral_radius
from vmehil.mavlink import stability

T = 0.008


def test_paper_gains_poles_match_the_sampled_loop_without_the_structural_eigenvalue():
    poles = np.sort_complex(loop_poles(100, 5000, 50, 1000, T))
    full = np.linalg.eigvals(sampled_loop_matrix(100, 5000, 50, 1000, T))
    # the full matrix has exactly one more eigenvalue, at z = 1
    rest = [z for z in full if abs(z - 1.0) > 1e-9]
    assert len(rest) == 3 and len(full) == 4
    assert np.allclose(np.sort_complex(np.array(rest)), poles)
    assert spectral_radius(100, 5000, 50, 1000, T) < 0.96


def test_poles_converge_to_the_continuous_loop_for_a_short_period():
    dt = 1e-4
    z = np.sort_complex(loop_poles(100, 5000, 50, 1000, dt))
    s = np.sort_complex(np.log(z) / dt)
    assert np.allclose(s, np.sort_complex(continuous_poles(100, 5000, 50, 1000)), rtol=0.02)


def test_slow_but_stable_integrator_pole_is_not_mistaken_for_the_structural_one():
    # a tiny Kpi puts a genuine pole just inside z = 1; it must be kept (and judged stable)
    assert spectral_radius(100, 1e-3, 50, 1000, T) < 1.0
    check_gain_change(PidLaw(1, T), 0, {"kpi": 1e-3}, T, 0.0)


def test_accepts_paper_gains_and_changes_nothing():
    law = PidLaw(3, T)
    before = law.gains.as_dict()
    check_gain_change(law, None, {"kp": 120.0, "kv": 55.0}, T, 0.5)
    check_gain_change(law, 1, {"kpi": 4000}, T, 1.0)
    assert law.gains.as_dict() == before


@pytest.mark.parametrize("changes, fragment", [
    ({"kp": math.nan}, "finite"),
    ({"kv": math.inf}, "finite"),
    ({"kpi": -1.0}, ">= 0"),
    ({"kq": 1.0}, "unknown gain"),
    ({"kp": "100"}, "number"),
    ({"kp": True}, "number"),
    ({}, "no gain"),
    ({"kp": 5e4}, "unstable"),
    ({"kp": 1e6}, "limited"),
    ({"kv": 600.0}, "unstable"),
    ({"kp": 0.0, "kpi": 0.0, "kvi": 0.0}, "unstable"),
])
def test_rejects_bad_or_destabilising_changes(changes, fragment):
    law = PidLaw(2, T)
    with pytest.raises(GainRejected) as ei:
        check_gain_change(law, 0, changes, T, 0.0)
    assert fragment in str(ei.value)
    assert "nothing was changed" in str(ei.value)


def test_rejects_bad_joint_and_delay():
    law = PidLaw(2, T)
    with pytest.raises(GainRejected, match="joint index"):
        check_gain_change(law, 2, {"kp": 1.0}, T)
    with pytest.raises(GainRejected, match="delay"):
        check_gain_change(law, 0, {"kp": 1.0}, T, 1.5)


def test_delay_matters():
    # a gain set that is stable without computation delay but not with a whole period of it
    kv = next(k for k in np.arange(50, 400, 5.0)
              if spectral_radius(100, 5000, k, 1000, T, 0.0) < 1 <= spectral_radius(100, 5000, k, 1000, T, 1.0))
    law = PidLaw(1, T, switch_off=SwitchOffConfig.disabled(1))
    check_gain_change(law, 0, {"kv": kv}, T, 0.0)
    with pytest.raises(GainRejected, match="unstable"):
        check_gain_change(law, 0, {"kv": kv}, T, 1.0)


def test_switched_off_loop_is_checked_when_switch_off_is_enabled():
    # the paper's gains are fine while integrating; a large explicit Kp boost is not when switched off
    assert spectral_radius(100, 5000, 50, 1000, T) < 1 <= spectral_radius(100 * 200, 0, 50, 0, T)
    law = PidLaw(1, T, switch_off=SwitchOffConfig.make(1, kp_boost=200.0))
    with pytest.raises(GainRejected, match="switched off"):
        check_gain_change(law, 0, {"kp": 100.0}, T)
    check_gain_change(PidLaw(1, T, switch_off=SwitchOffConfig.disabled(1)), 0, {"kp": 100.0}, T)


def test_kpi_zero_with_kvi_is_marginal_and_rejected_but_pd_is_fine():
    law = PidLaw(1, T)
    assert abs(spectral_radius(100, 0, 50, 1000, T) - 1.0) < 1e-9
    with pytest.raises(GainRejected, match="z = 1"):
        check_gain_change(law, 0, {"kpi": 0.0}, T)
    check_gain_change(law, 0, {"kpi": 0.0, "kvi": 0.0}, T)


def test_staged_gains_count_as_current():
    law = PidLaw(1, T, switch_off=SwitchOffConfig.disabled(1))
    law.set_gains(kv=5.0)  # staged, not applied yet
    # kp that is fine with kv=50 but not with the staged kv=5
    kp = next(k for k in np.arange(100, 20000, 100.0)
              if spectral_radius(k, 5000, 50, 1000, T) < 1 <= spectral_radius(k, 5000, 5, 1000, T))
    with pytest.raises(GainRejected):
        check_gain_change(law, 0, {"kp": kp}, T)


def test_upper_limits_and_min_margin():
    law = PidLaw(1, T)
    with pytest.raises(GainRejected, match="limited"):
        check_gain_change(law, 0, {"kv": 2e4}, T)
    r = spectral_radius(100, 5000, 50, 1000, T)
    check_gain_change(law, 0, {"kp": 100.0}, T, min_margin=(1 - r) * 0.9)
    with pytest.raises(GainRejected, match="unstable"):
        check_gain_change(law, 0, {"kp": 100.0}, T, min_margin=(1 - r) * 1.1)


def test_same_verdicts_as_mavlink_live_tuning():
    """The console and MAVLink must accept and refuse the same gain sets (within the parameter ranges).

    Known difference: Kpi = 0 with KvI > 0 puts a pole at exactly z = 1; gain_guard always refuses
    it, mavlink's margin test sees 1 − ρ ≈ ±1e-16 and decides by rounding — excluded here."""
    rng = np.random.default_rng(11)
    disagreements = []
    for _ in range(300):
        kp, kpi, kv, kvi = (float(x) for x in rng.choice([0.0, 1.0], 4) * 10 ** rng.uniform(0, 4.0, 4))
        if kpi == 0.0 and kvi > 0.0:
            continue
        delay = float(rng.choice([0.0, 0.5, 1.0]))
        boost_on = bool(rng.integers(2))
        law = PidLaw(1, T, switch_off=SwitchOffConfig.make(1, enabled=boost_on))
        try:
            check_gain_change(law, 0, {"kp": kp, "kpi": kpi, "kv": kv, "kvi": kvi}, T, delay)
            ours = True
        except GainRejected:
            ours = False
        theirs = stability.check_gains(kp, kpi, kv, kvi, T, delay=delay,
                                       kp_off=(kp + kvi) if boost_on else None).ok
        if ours != theirs:
            disagreements.append((kp, kpi, kv, kvi, delay, boost_on, ours, theirs))
    assert not disagreements
