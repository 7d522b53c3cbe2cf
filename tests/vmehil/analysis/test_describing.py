"""Describing-function analysis: DF formulas, analytic known answers, the sampled evaluation
against brute-force time simulation, and the JPL velocity dead-band cycle (docs/jpl-figures.md)."""

from __future__ import annotations

import math

import control as ct
import numpy as np
import pytest
from scipy.optimize import brentq

from servo.control.gains import Gains
from vmehil.analysis.describing import (
    DeadZone,
    Quantizer,
    Relay,
    Saturation,
    gain_loop_poles,
    headline,
    hybrid_response,
    linear_response,
    measure_cycle,
    predict_cycles,
    predict_joint_velocity,
    predict_lure,
    simulate_joint,
    simulate_sampled,
)
from vmehil.analysis.loop_model import LoopConfig

S = ct.tf("s")


def fourier_df(nl, a: float, n: int = 20000) -> float:
    """First-harmonic gain of a static map by numerical quadrature (independent of .df)."""
    ph = (np.arange(n) + 0.5) * 2 * np.pi / n
    return float(2.0 / n * np.sum(nl(a * np.sin(ph)) * np.sin(ph)) / a)


@pytest.mark.parametrize("nl", [DeadZone(0.14), Saturation(2.0), Relay(1.5), Quantizer(1.45e-3)])
def test_describing_functions_match_fourier_quadrature(nl) -> None:
    scale = {DeadZone: 0.14, Saturation: 2.0, Relay: 1.0, Quantizer: 1.45e-3}[type(nl)]
    for a in scale * np.array([0.3, 0.6, 0.9, 1.3, 2.2, 4.7, 11.0]):
        assert nl.df(a) == pytest.approx(fourier_df(nl, a), abs=2e-4), a


def test_relay_on_third_order_plant_matches_the_textbook_answer() -> None:
    """K/(s(s+1)(s+2)) with a relay ±M: ω = √2, G(j√2) = −K/6, A = 4MK/(6π)."""
    K, M = 10.0, 1.0
    (c,) = predict_lure(K / (S * (S + 1) * (S + 2)), Relay(M))
    assert c.frequency_hz == pytest.approx(math.sqrt(2) / (2 * math.pi), rel=1e-9)
    assert c.amplitude_x == pytest.approx(4 * M * K / (6 * math.pi), rel=1e-9)
    assert c.stable


def test_saturation_on_third_order_plant_matches_the_analytic_balance() -> None:
    """Linear loop unstable for K > 6; the saturation settles where N(A) = 6/K, at ω = √2."""
    K, L = 20.0, 1.0
    (c,) = predict_lure(K / (S * (S + 1) * (S + 2)), Saturation(L))
    r = brentq(lambda r: (2 / math.pi) * (math.asin(r) + r * math.sqrt(1 - r * r)) - 6 / K, 1e-9, 1)
    assert c.frequency_hz == pytest.approx(math.sqrt(2) / (2 * math.pi), rel=1e-9)
    assert c.amplitude_x == pytest.approx(L / r, rel=1e-9)
    assert c.stable
    assert predict_lure(5.0 / (S * (S + 1) * (S + 2)), Saturation(L)) == []  # stable linear loop: no cycle


def _simulate_lure(Gd: ct.StateSpace, nl, n: int = 20000) -> tuple[float, float]:
    """Brute force x = −G·N(x) in discrete time (exact for a sampled nonlinearity)."""
    g = ct.ss(Gd)
    xi = np.zeros(g.nstates)
    xi[0] = 0.5
    xs = np.empty(n)
    for k in range(n):
        x = float((g.C @ xi)[0])
        xs[k] = x
        xi = g.A @ xi - g.B[:, 0] * float(nl(np.array([x]))[0])
    return measure_cycle(np.arange(n) * g.dt, xs)


@pytest.mark.parametrize("nl", [Relay(1.0), Saturation(1.0)])
def test_sampled_describing_function_matches_time_simulation(nl) -> None:
    """With a coarse sample (T = 0.4 s) the sampled prediction matches the brute-force cycle;
    the continuous prediction (what a continuous-time DF tool gives) is far off."""
    G = 10.0 / (S * (S + 1) * (S + 2))
    Gd = ct.c2d(ct.ss(G), 0.4, "zoh")
    (pred,) = predict_lure(Gd, nl)
    (cont,) = predict_lure(G, nl)
    amp, freq = _simulate_lure(Gd, nl)
    assert pred.frequency_hz == pytest.approx(freq, rel=0.02)
    assert pred.amplitude_x == pytest.approx(amp, rel=0.05)
    assert abs(cont.frequency_hz / freq - 1) > 0.2 and abs(cont.amplitude_x / amp - 1) > 0.3


def _harmonic_balance(deadband_rad_s: float, g: Gains) -> tuple[float, float]:
    """Analytic harmonic balance of the continuous loop with a velocity dead band, independent of
    :func:`predict_cycles`: G(s) = s(Kv·s + KvI)/(s³ + Kp·s + Kpi) is real where
    Kv·Ω²(Kp − Ω²) = −KvI·Kpi; there the dead zone's DF must equal −1/G. Returns (joint-angle
    amplitude rad, Ω rad/s) for the dead band."""
    x = (g.kp + math.sqrt(g.kp**2 + 4 * g.kvi * g.kpi / g.kv)) / 2
    w = math.sqrt(x)
    s = 1j * w
    G = s * (g.kv * s + g.kvi) / (s**3 + g.kp * s + g.kpi)
    assert abs(G.imag) < 1e-9 * abs(G) and G.real < 0
    k = -1 / G.real
    r = brentq(lambda r: 1 - (2 / math.pi) * (math.asin(r) + r * math.sqrt(1 - r * r)) - k, 1e-12, 1 - 1e-12)
    a_vel = deadband_rad_s / r  # the rate amplitude whose dead-zone gain is k
    return a_vel / w, w  # θ = ω/s on the continuous plant


def test_continuous_velocity_dead_band_prediction_against_harmonic_balance_and_simulation() -> None:
    """docs/jpl-figures.md: a 0.15 rad/s tach dead band on the normalized loop with the paper's
    gains. The DF prediction agrees with the analytic harmonic balance (two derivations), and —
    the check that fails if the loop or the DF is wrong — with a brute-force simulation of the
    nearly continuous loop (T = 1 ms, no delay) within the DF's approximation (15 %)."""
    g = Gains.paper()
    delta = 0.15
    amp_rad, w = _harmonic_balance(delta, g)
    (c,) = predict_cycles(LoopConfig(gains=g), DeadZone(delta), sampled=False)
    assert c.stable
    assert c.frequency_hz == pytest.approx(w / (2 * math.pi), rel=1e-7)
    assert c.amplitude_rad == pytest.approx(amp_rad, rel=1e-6)
    fine = LoopConfig(gains=g, sample_period_s=1e-3, delay_fraction=0.0)
    sim = simulate_sampled(fine, DeadZone(delta), 8000, kick=1.0)
    amp, freq = measure_cycle(sim["t"], sim["theta"])
    assert amp is not None and freq is not None
    assert c.amplitude_rad == pytest.approx(amp, rel=0.15)  # DF ±0.73°, simulated ±0.80°
    assert c.frequency_hz == pytest.approx(freq, rel=0.15)  # DF 3.06 Hz, simulated 2.82 Hz
    assert 0.5 <= math.degrees(amp) <= 1.0 and 1.0 <= freq <= 3.0  # the paper's band


def test_sampled_velocity_dead_band_cycle_matches_simulation_of_the_sampled_loop() -> None:
    cfg = LoopConfig()
    nl = DeadZone(0.15)
    c = headline(predict_cycles(cfg, nl, sampled=True))
    assert c is not None and c.stable
    sim = simulate_sampled(cfg, nl, 12000, kick=1.0)
    amp, freq = measure_cycle(sim["t"], sim["theta"])
    assert c.amplitude_rad == pytest.approx(amp, rel=0.15)
    assert c.frequency_hz == pytest.approx(freq, rel=0.15)


def test_harmonic_balance_puts_a_gain_loop_pole_on_the_unit_circle() -> None:
    """At the predicted equivalent gain the linearized sampled loop has poles at e^{±jωT}."""
    cfg = LoopConfig(delay_fraction=1.0)
    (c,) = predict_cycles(cfg, DeadZone(0.15), sampled=True)
    p = gain_loop_poles(cfg, "velocity_sensor", c.equivalent_gain, sampled=True)
    target = np.exp(1j * 2 * np.pi * c.frequency_hz * cfg.sample_period_s)
    assert np.min(np.abs(p - target)) < 1e-6


def test_frozen_integrator_loop_without_friction_still_cycles_near_sqrt_kp() -> None:
    """docs/jpl-figures.md: with the integrators frozen (and Kp raised) the dead band alone still
    leaves a cycle near √Kp/2π, smaller than with integrators — friction is what stops it."""
    g = Gains(kp=1100, kpi=0, kv=50, kvi=0)
    cfg = LoopConfig(gains=g)
    c = headline(predict_cycles(cfg, DeadZone(0.15), sampled=True))
    assert c is not None
    assert c.frequency_hz == pytest.approx(math.sqrt(g.kp) / (2 * math.pi), rel=0.05)
    with_integrators = headline(predict_cycles(LoopConfig(), DeadZone(0.15), sampled=True))
    assert c.amplitude_rad < 0.6 * with_integrators.amplitude_rad
    sim = simulate_sampled(cfg, DeadZone(0.15), 8000, kick=1.0)
    amp, freq = measure_cycle(sim["t"], sim["theta"])
    assert c.amplitude_rad == pytest.approx(amp, rel=0.15)
    assert c.frequency_hz == pytest.approx(freq, rel=0.05)


def test_actuator_saturation_cycle_of_the_conditionally_stable_loop_is_unstable() -> None:
    """The phase crossover with |L| > 1 gives a DF solution that is a divergence threshold."""
    cycles = predict_cycles(LoopConfig(), Saturation(28.2), sampled=True)
    assert cycles and not any(c.stable for c in cycles)


def test_hybrid_response_agrees_with_the_exact_sampled_loop_well_below_nyquist() -> None:
    cfg = LoopConfig(delay_fraction=0.5)
    f = np.array([0.5, 1.0, 3.0, 6.0])
    exact, _ = linear_response(cfg, "actuator", f, sampled=True)
    approx, _ = hybrid_response(cfg, f, "actuator")
    np.testing.assert_allclose(approx, exact, rtol=0.03)


def test_coulomb_friction_alone_predicts_no_isolated_cycle() -> None:
    """Pure Coulomb friction with PID: G = ω/d never crosses the negative real axis at a finite
    frequency — the integrator hunting is a stick-slip effect outside single-harmonic balance."""
    for sampled in (False, True):
        assert predict_cycles(LoopConfig(), Relay(4.24 / 3.0), sampled=sampled) == []


def test_equivalent_gain_solver_matches_harmonic_balance_for_one_nonlinearity() -> None:
    for sampled in (False, True):
        (a,) = predict_cycles(LoopConfig(), DeadZone(0.15), sampled=sampled)
        (b,) = predict_joint_velocity(LoopConfig(), [DeadZone(0.15)], sampled=sampled)
        assert b.frequency_hz == pytest.approx(a.frequency_hz, rel=1e-6)
        assert b.amplitude_x == pytest.approx(a.amplitude_x, rel=1e-6)
        assert b.amplitude_rad == pytest.approx(a.amplitude_rad, rel=0.005)
        assert a.stable and b.stable


JOINT1 = [DeadZone(0.15, name="tach dead band"), Relay(4.24 / 3.0, name="Coulomb friction")]


def test_dead_band_with_friction_cycle_matches_the_reduced_joint_simulation() -> None:
    """Paper gains: ±¾° at 1–3 Hz (docs/jpl-figures.md), predicted and simulated."""
    cfg = LoopConfig()
    c = headline(predict_joint_velocity(cfg, JOINT1, sampled=True))
    assert c is not None and 0.6 < c.amplitude_deg < 0.85 and 2.0 < c.frequency_hz < 3.2
    sim = simulate_joint(cfg, 30.0, deadband_rad_s=0.15, coulomb_accel=4.24 / 3.0)
    amp, freq = measure_cycle(sim["t"], sim["theta"])
    assert c.amplitude_rad == pytest.approx(amp, rel=0.15)
    assert c.frequency_hz == pytest.approx(freq, rel=0.15)


def test_switch_off_with_friction_predicts_and_simulates_no_cycle() -> None:
    """Integrators frozen, Kp raised: no cycle predicted; the reduced joint stops within T_F/(J·Kp)."""
    cfg = LoopConfig(gains=Gains(kp=1100, kpi=0, kv=50, kvi=0))
    assert headline(predict_joint_velocity(cfg, JOINT1, sampled=True)) is None
    sim = simulate_joint(cfg, 20.0, deadband_rad_s=0.15, coulomb_accel=4.24 / 3.0)
    tail = sim["theta"][len(sim["theta"]) // 2:]
    assert np.ptp(tail) < 1e-9  # stuck: no motion at all in the second half
    assert abs(tail[-1]) <= (4.24 / 3.0) / 1100 * (1 + 1e-9)


def test_quantizer_df_at_many_amplitudes_at_once_equals_one_at_a_time() -> None:
    from vmehil.analysis.describing import Quantizer

    q = Quantizer(0.001449)
    lo, hi = q.amplitude_range()
    a = np.concatenate([[0.1 * q.step, 0.5 * q.step], np.logspace(np.log10(lo), np.log10(hi), 997)])
    np.testing.assert_allclose(q.df_array(a), [q.df(x) for x in a], rtol=0, atol=1e-14)
    assert q.df_array(a)[0] == 0.0
