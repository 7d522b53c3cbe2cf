"""servo.gain_guard: the one check every gain set goes through (console, MAVLink, run, tune, sweeps)."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from servo.control.gains import GAIN_NAMES, Gains
from servo.control.law import PidLaw, SwitchOffConfig
from servo.control.linear import continuous_poles, sampled_loop_matrix, simulate_sampled_loop
from servo.gain_guard import (
    GAIN_MAX,
    MIN_MARGIN_FLOOR,
    GainRejected,
    check_gain_change,
    judge,
    loop_poles,
    spectral_radius,
)

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
    ({"kpi": -1.0}, "negative"),
    ({"kq": 1.0}, "unknown gain"),
    ({"kp": "100"}, "number"),
    ({"kp": True}, "number"),
    ({}, "no gain"),
    ({"kp": 5e4}, "unstable"),
    ({"kp": 1e6}, "limited"),
    ({"kv": 600.0}, "unstable"),
    ({"kp": 0.0, "kpi": 0.0, "kvi": 0.0}, "marginal"),  # Kv alone: no position stiffness
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
    with pytest.raises(GainRejected, match="required"):
        check_gain_change(law, 0, {"kp": 100.0}, T, min_margin=(1 - r) * 1.1)


def _diverges(kp, kpi, kv, kvi, delay=0.0, ticks=4000) -> bool:
    """Step response of the linear sampled loop: does it blow up (or fail to settle)?"""
    with np.errstate(over="ignore", invalid="ignore"):
        y = simulate_sampled_loop(kp, kpi, kv, kvi, T, np.ones(ticks), np.zeros(ticks), delay=delay)
    return not np.all(np.isfinite(y)) or abs(y[-1] - 1.0) > 1e-3 or np.abs(y[-200:] - 1.0).max() > 1e-3


VERDICTS: set[bool] = set()


@pytest.mark.parametrize("delay", [0.0, 0.5])
@pytest.mark.parametrize("kp,kpi,kv,kvi", [
    (100, 5000, 50, 1000), (1000, 5000, 20, 1000), (100, 5000, 10, 1000), (1000, 5000, 5, 1000),
    (2000, 0, 50, 0), (20000, 0, 50, 0), (60000, 0, 200, 0), (100, 5000, 240, 1000), (100, 5000, 260, 1000),
    (3000, 5000, 5, 1000),
])
def test_verdict_agrees_with_a_simulation_of_the_sampled_loop(kp, kpi, kv, kvi, delay):
    v = judge(Gains(kp=kp, kpi=kpi, kv=kv, kvi=kvi), T, delay)
    VERDICTS.add(v.ok)
    assert abs(v.margin_integrating) > 2e-3  # cases chosen away from the boundary, where a finite simulation decides
    assert v.ok == (not _diverges(kp, kpi, kv, kvi, delay))
    assert v.kind == ("ok" if v.ok else "unstable")


def test_the_simulated_cases_include_both_verdicts():
    assert VERDICTS == {True, False}


def test_paper_gains_margin_matches_the_slowest_continuous_pole():
    # the slowest pole −6.0 rad/s maps to about exp(−6·T): margin ≈ 1 − exp(−6·T)
    v = judge(Gains.paper(), T, kp_off=1100.0)
    assert v.ok and v.reason == "stable"
    assert v.margin_integrating == pytest.approx(1 - math.exp(-6.0 * T), rel=0.05)
    assert v.margin_switched_off > 0
    assert math.isnan(judge(Gains.paper(), T).margin_switched_off)  # switch-off not judged
    assert not judge(Gains.paper(), T, min_margin=0.1).ok


@pytest.mark.parametrize(("name", "value", "words"), [
    ("kp", -1.0, "negative"),
    ("kv", -0.0 - 1e-300, "negative"),
    ("kpi", math.nan, "not finite"),
    ("kvi", math.inf, "not finite"),
    ("kpi", 5e-324, "subnormal"),
    ("kp", sys.float_info.min / 2, "subnormal"),
    ("kp", 1e30, "limited"),
    ("kv", 1e30, "limited"),
    ("kp", "100", "not a number"),
    ("kp", None, "not a number"),
])
def test_values_no_gain_may_have_are_refused_with_a_reason_naming_the_gain(name, value, words):
    law = PidLaw(1, T)
    with pytest.raises(GainRejected) as ei:
        check_gain_change(law, 0, {name: value}, T, 0.125)
    e = ei.value
    assert e.kind == "invalid" and e.name == name and words in e.reason and name in e.reason
    try:
        g = Gains.paper().replace(**{name: value})
    except ValueError:
        return  # not even a Gains (negative, NaN, not a number): the type refuses it too
    v = judge(g, T, 0.125)
    assert (v.ok, v.kind, v.reason) == (False, "invalid", e.reason)  # the same reason, however asked


def test_zero_gains_are_judged_by_the_loop_they_give():
    assert judge(Gains(kp=100, kpi=0, kv=50, kvi=0), T, 0.125).ok  # PD: fine
    assert judge(Gains(kp=0, kpi=5000, kv=50, kvi=1000), T, 0.125).ok  # s³+50s²+1000s+5000: Routh-stable
    v = judge(Gains(kp=0, kpi=0, kv=50, kvi=0), T, 0.125)  # no stiffness: a pole at z = 1
    assert not v.ok and v.kind == "unstable" and "marginal" in v.reason
    v = judge(Gains(kp=0, kpi=0, kv=0, kvi=0), T, 0.125)
    assert not v.ok and v.kind == "unstable"


@pytest.mark.parametrize("delay", [0.0, 0.125, 0.5, 1.0])
@pytest.mark.parametrize(("kp", "kv", "kvi"), [(100, 50, 1000), (3, 7, 1e-3), (1000, 40, 500)])
def test_kpi_zero_with_kvi_is_refused_for_its_pole_at_z_1_not_by_rounding(kp, kv, kvi, delay):
    # the pole sits exactly on the circle; 1 − ρ comes out as ±1e-16 and must not decide
    v = judge(Gains(kp=kp, kpi=0, kv=kv, kvi=kvi), T, delay)
    assert abs(v.margin_integrating) < 1e-9
    assert not v.ok and v.kind == "unstable" and "z = 1" in v.reason


def test_a_tiny_normal_kpi_is_marginal_but_a_small_one_is_a_slow_stable_pole():
    v = judge(Gains(kp=100, kpi=1e-300, kv=50, kvi=1000), T, 0.125)
    assert not v.ok and "marginal" in v.reason and "raise kp or kpi" in v.reason
    assert judge(Gains(kp=100, kpi=1e-3, kv=50, kvi=1000), T, 0.125).ok


def test_unstable_reasons_say_which_loop_and_what_to_do():
    v = judge(Gains(kp=5e4, kpi=5000, kv=50, kvi=1000), T, 0.125)
    assert v.reason.startswith("the sampled loop would be unstable (pole radius ")
    assert "T = 8 ms, delay 0.125 T" in v.reason and v.reason.endswith("lower the gains")
    v = judge(Gains.paper(), T, kp_off=100 * 200.0)
    assert v.reason.startswith("the loop with its integrators switched off (Kp_eff = 20000) would be unstable")
    assert v.margin_integrating > 0 > v.margin_switched_off


finite_gain = st.floats(min_value=0.0, max_value=1e31, allow_nan=False, allow_infinity=False, allow_subnormal=True)


@given(st.tuples(finite_gain, finite_gain, finite_gain, finite_gain), st.sampled_from([0.0, 0.125, 1.0]),
       st.one_of(st.none(), finite_gain))
def test_judge_gives_a_verdict_for_every_gain_set_and_never_raises(values, delay, kp_off):
    g = Gains(**dict(zip(GAIN_NAMES, values, strict=True)))
    v = judge(g, T, delay, kp_off=kp_off)
    over = [k for k, x in zip(GAIN_NAMES, values, strict=True) if x > GAIN_MAX[k] or 0 < x < sys.float_info.min]
    assert v.kind == ("invalid" if over else "ok" if v.ok else "unstable")
    if over:
        assert over[0] in v.reason
    if v.ok:
        assert v.margin_integrating > MIN_MARGIN_FLOOR and v.reason == "stable"
        assert kp_off is None or v.margin_switched_off > MIN_MARGIN_FLOOR
