"""The JPL law on an ideal sampled double integrator: linear-model agreement, disturbance rejection,
integrator switch-off and live gain changes."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest

from servo.control import (
    GainError,
    PidLaw,
    SwitchOffConfig,
    continuous_poles,
    sampled_loop_matrix,
    simulate_sampled_loop,
)
from tests.support.fakes import DoubleIntegrator

T = 0.008
KP, KPI, KV, KVI = 100.0, 5000.0, 50.0, 1000.0


def run(law: PidLaw, plant: DoubleIntegrator, ticks: int, theta_d, omega_d, alpha_d=None, done=None, dist=None):
    """Close the loop for ``ticks`` ticks; reference/disturbance args are callables of k or constants."""
    def val(f, k, default):
        if f is None:
            return default
        return f(k) if callable(f) else f
    out = []
    for k in range(ticks):
        a = law.update(plant.theta, plant.omega, val(theta_d, k, 0.0), val(omega_d, k, 0.0),
                       val(alpha_d, k, 0.0), val(done, k, False))
        out.append(plant.theta.copy())
        plant.step(a, val(dist, k, 0.0))
    return np.array(out)


def no_switch_off(n: int = 1) -> PidLaw:
    return PidLaw(n, T, switch_off=SwitchOffConfig.disabled(n))


def test_paper_gains_give_the_papers_continuous_roots():
    poles = sorted(continuous_poles(KP, KPI, KV, KVI), key=lambda p: p.imag)
    assert poles[1].real == pytest.approx(-6.0, abs=0.1) and abs(poles[1].imag) < 1e-9
    for p in (poles[0], poles[2]):
        assert p.real == pytest.approx(-22.0, abs=0.1)
        assert abs(p.imag) == pytest.approx(18.6, abs=0.25)


def _numeric_loop_matrix(period: float) -> np.ndarray:
    """A of the closed loop, derived by running the implemented law one tick from each basis state."""
    A = np.zeros((4, 4))
    for i in range(4):
        x = np.zeros(4)
        x[i] = 1.0
        law = PidLaw(1, period, switch_off=SwitchOffConfig.disabled(1))
        law.state.ie[:] = x[2]
        law.state.iv[:] = x[3]
        plant = DoubleIntegrator(1)
        plant.theta[:] = x[0]
        plant.omega[:] = x[1]
        a = law.update(plant.theta, plant.omega, np.zeros(1), np.zeros(1))
        plant.step(a, period_s=period)
        A[:, i] = [plant.theta[0], plant.omega[0], law.state.ie[0], law.state.iv[0]]
    return A


@pytest.mark.parametrize("period", [T, 0.001])
def test_sampled_loop_poles_are_near_exp_sT(period):
    A_num = _numeric_loop_matrix(period)
    np.testing.assert_allclose(A_num, sampled_loop_matrix(KP, KPI, KV, KVI, period), atol=1e-12)
    z = np.linalg.eigvals(A_num)
    # one eigenvalue is exactly 1: the unobservable mode Kpi·Ie + KvI·Iv = const with θ = ω = 0
    assert np.min(np.abs(z - 1.0)) < 1e-9
    # the backward-Euler integrators add Kpi·T to Kp and KvI·T to Kv: close at 125 Hz, converging as T → 0
    tol = 0.06 if period == T else 0.002
    for s in continuous_poles(KP, KPI, KV, KVI):
        assert np.min(np.abs(z - np.exp(s * period))) < tol
    assert np.all(np.abs(z[np.abs(z - 1.0) > 1e-9]) < 1.0)


def test_step_response_matches_linear_models():
    ticks = 250
    y = run(no_switch_off(), DoubleIntegrator(1), ticks, 1.0, 0.0)[:, 0]
    # the sampled linear model (independent state-space form) agrees to rounding
    y_lin = simulate_sampled_loop(KP, KPI, KV, KVI, T, np.ones(ticks), np.zeros(ticks))
    np.testing.assert_allclose(y, y_lin, atol=1e-10)
    # the continuous model θ/θd = (Kp·s + Kpi)/(s³ + Kv·s² + (Kp+KvI)·s + Kpi) (ωd = 0 for a step)
    t = np.arange(ticks) * T
    _, yc = ct.step_response(ct.tf([KP, KPI], [1.0, KV, KP + KVI, KPI]), t)
    assert np.max(np.abs(y - yc)) < 0.04
    assert y[-1] == pytest.approx(1.0, abs=1e-3)


def test_ramp_response_matches_linear_model_and_tracks_without_lag():
    ticks, rate = 400, 0.5  # rad/s
    y = run(no_switch_off(), DoubleIntegrator(1), ticks, lambda k: rate * k * T, rate)[:, 0]
    t = np.arange(ticks) * T
    y_lin = simulate_sampled_loop(KP, KPI, KV, KVI, T, rate * t, np.full(ticks, rate))
    np.testing.assert_allclose(y, y_lin, atol=1e-10)
    G = ct.tf([KV, KP + KVI, KPI], [1.0, KV, KP + KVI, KPI])  # ė = ωd − ω with ωd consistent
    _, yc = ct.forced_response(G, t, rate * t)
    assert np.max(np.abs(y - yc)) < 0.01 * rate
    assert abs(rate * t[-1] - y[-1]) < 1e-5  # type-3 loop: no steady ramp error


def test_feedforward_acceleration_gives_exact_tracking_of_a_consistent_trajectory():
    ticks = 300
    t = np.arange(ticks) * T
    # a quadratic path, consistent samples: θ(t) = t², ω = 2t, α = 2
    law, plant = no_switch_off(), DoubleIntegrator(1)
    out = run(law, plant, ticks, lambda k: (k * T) ** 2, lambda k: 2 * k * T, 2.0)[:, 0]
    # with ZOH the plant integrates a = α exactly; the error stays at rounding level
    assert np.max(np.abs(out - t**2)) < 1e-9


def test_disturbance_step_is_rejected_to_zero_final_error():
    d = 1.4  # rad/s² (= T_F/J)
    y = run(no_switch_off(), DoubleIntegrator(1), 1000, 0.0, 0.0, dist=lambda k: d if k >= 50 else 0.0)[:, 0]
    assert np.max(np.abs(y[50:])) > 1e-4  # the disturbance did move the joint
    assert abs(y[-1]) < 1e-7


def test_without_integrators_the_static_error_is_disturbance_over_kp():
    d = 1.4
    law = PidLaw(1, T, switch_off=SwitchOffConfig.disabled(1))
    law.set_gains(kpi=0.0, kvi=0.0)
    y = run(law, DoubleIntegrator(1), 1000, 0.0, 0.0, dist=d)[:, 0]
    assert y[-1] == pytest.approx(d / KP, rel=1e-6)  # θ = T_F/(J·Kp)


# ---- integrator switch-off ------------------------------------------------------------------------------
def _settled_law(n=1, **so):
    """A law that tracked a step to rest (motion running), integrators populated."""
    law = PidLaw(n, T, switch_off=SwitchOffConfig.make(n, **so))
    plant = DoubleIntegrator(n)
    run(law, plant, 400, 0.1, 0.0, done=False, dist=0.7)
    return law, plant


def test_switch_off_freezes_integrators_and_boosts_kp():
    law, plant = _settled_law(inner_band=1e-3, outer_band=0.02, kp_boost=3.0)
    assert law.integrating[0] and law.state.ie[0] != 0.0
    ie0, iv0 = law.state.ie.copy(), law.state.iv.copy()
    # motion done and settled → off at the first tick
    a = law.update(plant.theta, plant.omega, 0.1, 0.0, motion_done=True, tick=1000)
    assert not law.integrating[0]
    assert law.events[-1].tick == 1000 and law.events[-1].integrating is False
    assert law.events[-1].reason == "settled"
    assert law.kp_eff()[0] == pytest.approx(300.0)
    # holding with a small error: integrator values do not move, a uses the boosted Kp
    for k in range(50):
        theta = plant.theta + 5e-4 * math.sin(k)  # error inside the outer band
        a = law.update(theta, plant.omega, 0.1, 0.0, motion_done=True)
        np.testing.assert_array_equal(law.state.ie, ie0)
        np.testing.assert_array_equal(law.state.iv, iv0)
        e = 0.1 - theta
        expect = 300.0 * e + KPI * ie0 + KV * (0.0 - plant.omega) + KVI * iv0
        np.testing.assert_allclose(a, expect, rtol=1e-12)


def test_auto_boost_restores_the_position_stiffness_lost_with_kvi():
    law, plant = _settled_law(inner_band=1e-3, outer_band=0.02)
    law.update(plant.theta, plant.omega, 0.1, 0.0, motion_done=True)
    assert not law.integrating[0]
    assert law.kp_eff()[0] == pytest.approx(KP + KVI)


def test_switch_off_hysteresis_and_reenable_on_large_error():
    law, plant = _settled_law(inner_band=1e-3, outer_band=0.01)
    law.update(plant.theta, plant.omega, 0.1, 0.0, motion_done=True)
    assert not law.integrating[0]
    # error between the bands: stays off
    law.update(np.array([0.1 - 0.008]), plant.omega, 0.1, 0.0, motion_done=True)
    assert not law.integrating[0]
    ie_before = law.state.ie.copy()
    # error beyond the outer band: back on, and integrates this very tick
    law.update(np.array([0.1 - 0.012]), plant.omega, 0.1, 0.0, motion_done=True, tick=77)
    assert law.integrating[0]
    assert law.events[-1].reason == "error_outside_band" and law.events[-1].tick == 77
    assert law.state.ie[0] == pytest.approx(ie_before[0] + T * 0.012)
    assert law.kp_eff()[0] == KP
    # between the bands again, still motion done: stays on (needs the inner band to switch off)
    law.update(np.array([0.1 - 0.005]), plant.omega, 0.1, 0.0, motion_done=True)
    assert law.integrating[0]


def test_switch_on_at_next_motion():
    law, plant = _settled_law(inner_band=1e-3, outer_band=0.01)
    law.update(plant.theta, plant.omega, 0.1, 0.0, motion_done=True)
    assert not law.integrating[0]
    law.update(plant.theta, plant.omega, 0.1, 0.0, motion_done=False, tick=500)
    assert law.integrating[0]
    assert (law.events[-1].tick, law.events[-1].joint, law.events[-1].reason) == (500, 0, "new_motion")


def test_settle_time_requires_staying_in_the_band():
    law, plant = _settled_law(inner_band=1e-3, outer_band=0.01, settle_time=0.04)
    for k in range(5):  # 5 ticks = 0.04 s accumulated before the switch
        law.update(plant.theta, plant.omega, 0.1, 0.0, motion_done=True)
        assert law.integrating[0], k
    law.update(plant.theta, plant.omega, 0.1, 0.0, motion_done=True)
    assert not law.integrating[0]


def test_zero_crossing_counts_as_in_band():
    law = PidLaw(1, T, switch_off=SwitchOffConfig.make(1, inner_band=1e-4, outer_band=0.1))
    law.update(np.array([-0.002]), np.zeros(1), 0.0, 0.0, motion_done=True)
    assert law.integrating[0]
    law.update(np.array([0.002]), np.zeros(1), 0.0, 0.0, motion_done=True)  # e went from + to −
    assert not law.integrating[0]
    law2 = PidLaw(1, T, switch_off=SwitchOffConfig.make(1, inner_band=1e-4, outer_band=0.1, zero_crossing=False))
    law2.update(np.array([-0.002]), np.zeros(1), 0.0, 0.0, motion_done=True)
    law2.update(np.array([0.002]), np.zeros(1), 0.0, 0.0, motion_done=True)
    assert law2.integrating[0]


def test_switch_off_is_per_joint_and_can_be_disabled():
    law = PidLaw(2, T, switch_off=SwitchOffConfig.make(2, enabled=[True, False]))
    for _ in range(3):
        law.update(np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2), motion_done=True)
    np.testing.assert_array_equal(law.integrating, [False, True])
    assert [(e.joint, e.integrating) for e in law.events] == [(0, False)]
    law.set_switch_off(SwitchOffConfig.disabled(2))
    law.update(np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2), motion_done=True, tick=9)
    np.testing.assert_array_equal(law.integrating, [True, True])
    assert (law.events[-1].tick, law.events[-1].reason) == (9, "disabled")


def test_switch_off_config_validation():
    with pytest.raises(GainError, match="outer_band"):
        SwitchOffConfig.make(1, inner_band=0.01, outer_band=0.005)
    with pytest.raises(GainError, match="kp_boost"):
        SwitchOffConfig.make(1, kp_boost=0.5)
    with pytest.raises(GainError, match=r"inner_band\[1\]"):
        SwitchOffConfig.make(2, inner_band=[0.001, -1.0])


# ---- live gain changes ----------------------------------------------------------------------------------
def test_set_gains_takes_effect_at_the_next_tick():
    law = no_switch_off(2)
    law.set_gains(kp=[10.0, 20.0])
    np.testing.assert_array_equal(law.gains.kp, [KP, KP])  # staged only
    a = law.update(np.zeros(2), np.zeros(2), np.array([1.0, 1.0]), np.zeros(2))
    np.testing.assert_array_equal(law.gains.kp, [10.0, 20.0])
    np.testing.assert_allclose(a, np.array([10.0, 20.0]) + KPI * T)
    law.set_gains(kv=7.0, joint=1)
    law.update(np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2))
    np.testing.assert_array_equal(law.gains.kv, [KV, 7.0])


@pytest.mark.parametrize(("kwargs", "pattern"), [
    ({"kp": float("nan")}, r"kp\[0\] = nan"),
    ({"kpi": -1.0}, r"kpi\[0\] = -1.0"),
    ({"kv": [1.0, float("inf")]}, r"kv\[1\] = inf"),
    ({"kvi": [1.0, 2.0, 3.0]}, r"kvi = \[1.0, 2.0, 3.0\].*2 numbers"),
    ({"kp": "fast"}, r"kp = 'fast'"),
    ({"kp": -3.0, "joint": 1}, r"kp\[1\] = -3.0"),
    ({"kp": 3.0, "joint": 5}, r"joint = 5"),
])
def test_set_gains_rejects_bad_values_and_changes_nothing(kwargs, pattern):
    law = no_switch_off(2)
    with pytest.raises(GainError, match=pattern):
        law.set_gains(**kwargs)
    law.update(np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2))
    assert law.gains.as_dict() == {"kp": [KP, KP], "kpi": [KPI, KPI], "kv": [KV, KV], "kvi": [KVI, KVI]}


def test_the_switched_off_kp_follows_new_gains_and_a_new_switch_off_config_at_the_next_tick():
    """The boosted Kp is kept between ticks; staged gains or a new switch-off configuration
    change it from the tick they take effect (and the copy handed out cannot change it)."""
    law, plant = _settled_law(inner_band=1e-3, outer_band=0.02, kp_boost=3.0)
    law.update(plant.theta, plant.omega, 0.1, 0.0, motion_done=True, tick=1000)
    assert not law.integrating[0] and law.kp_eff()[0] == pytest.approx(3.0 * KP)
    law.kp_off()[0] = -1.0  # a caller's copy
    assert law.kp_off()[0] == pytest.approx(3.0 * KP)
    law.set_gains(kp=150.0)
    assert law.kp_eff()[0] == pytest.approx(3.0 * KP)  # staged: not yet
    law.update(plant.theta, plant.omega, 0.1, 0.0, motion_done=True)
    assert law.kp_eff()[0] == pytest.approx(3.0 * 150.0)
    law.set_switch_off(SwitchOffConfig.make(1, inner_band=1e-3, outer_band=0.02, kp_boost=None))
    law.update(plant.theta, plant.omega, 0.1, 0.0, motion_done=True)
    assert law.kp_off()[0] == pytest.approx(150.0 + KVI)


# ---- construction and settings refused, with their texts --------------------------------------------------
def test_law_refuses_a_joint_count_or_period_that_is_not_positive():
    for n in (0, -1, 2.0, True):
        if n is True:
            continue  # bool is an int: PidLaw(True) is one joint, as Python counts
        with pytest.raises(GainError, match=rf"^gain n_joints = {float(n)!r}: expected a positive integer; "):
            PidLaw(n)
    for period in (0.0, -0.008, float("inf"), float("nan")):
        with pytest.raises(GainError, match=r"^gain period = .*: expected a positive number of seconds; nothing was "
                                            r"changed, fix the value and retry$") as ei:
            PidLaw(2, period)
        assert (ei.value.name, ei.value.joint) == ("period", None)
    law = PidLaw(2)
    assert (law.n, law.period) == (2, 0.008)
    assert isinstance(PidLaw(1, 1).period, float)


def test_switch_off_settings_refused_name_the_setting_and_joint():
    with pytest.raises(GainError, match=r"^gain switch_off\.outer_band\[1\] = 0\.001: expected a band wider than "
                                        r"inner_band \(0\.002 rad\) for hysteresis; "):
        SwitchOffConfig.make(2, inner_band=[0.001, 0.002], outer_band=[0.01, 0.001])
    with pytest.raises(GainError, match=r"^gain switch_off\.outer_band\[0\] = 0\.002: expected a band wider"):
        SwitchOffConfig.make(1, inner_band=0.002, outer_band=0.002)  # equal is not wider
    with pytest.raises(GainError, match=r"^gain switch_off\.kp_boost\[1\] = 0\.99: expected a factor >= 1 \(or auto\)"):
        SwitchOffConfig.make(2, kp_boost=[1.0, 0.99])
    cfg = SwitchOffConfig.make(3, kp_boost=[None, 1.0, 2.5])  # None: auto, kept as NaN
    assert np.isnan(cfg.kp_boost[0]) and list(cfg.kp_boost[1:]) == [1.0, 2.5]
    for name in ("enabled", "zero_crossing"):
        with pytest.raises(GainError, match=rf"^gain switch_off\.{name} = .*: expected true/false or a list of 2 "
                                            r"of them; "):
            SwitchOffConfig.make(2, **{name: [True, 1.5]})
        with pytest.raises(GainError, match=rf"^gain switch_off\.{name} = .*: expected true/false or a list of 2"):
            SwitchOffConfig.make(2, **{name: [True, False, True]})
    cfg = SwitchOffConfig.make(2, enabled=[True, False], zero_crossing=False, settle_time=0.05,
                               inner_band=0.001, outer_band=0.01)
    assert cfg.enabled.tolist() == [True, False] and cfg.zero_crossing.tolist() == [False, False]
    assert cfg.settle_time.tolist() == [0.05, 0.05] and cfg.enabled.dtype == np.bool_
    default = SwitchOffConfig.make(1)
    assert (bool(default.enabled[0]), bool(default.zero_crossing[0])) == (True, True)
    assert float(default.settle_time[0]) == 0.0
    assert np.isnan(default.kp_boost[0])
    np.testing.assert_allclose([default.inner_band[0], default.outer_band[0]], [math.pi / 1800, math.pi / 180])
    assert SwitchOffConfig.disabled(2).enabled.tolist() == [False, False]
