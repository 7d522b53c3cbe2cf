"""Loop models: the sampled model equals a brute-force simulation of the servo law, the sampled
plant matches python-control's c2d, the Bode of the sampled loop converges to the continuous one
and shows the ZOH and computation-delay lag."""

from __future__ import annotations

import math
import re

import control as ct
import numpy as np
import pytest

from servo.control.gains import Gains
from tests.support.fakes import DoubleIntegrator
from vmehil.analysis.loop_model import (
    LoopConfig,
    LoopConfigError,
    build_loop,
    closed_loop,
    closed_loop_poles,
    continuous_plant,
    disturbance_loop,
    freqresp,
    is_stable,
    open_loop,
    sampled_plant,
    tracking_loop,
)


def brute_force_step(cfg: LoopConfig, n: int, substeps: int = 8) -> np.ndarray:
    """The servo law written out by hand, the 1/s² plant integrated exactly between command changes."""
    g, T, d = cfg.gains, cfg.sample_period_s, cfg.delay_fraction
    plant = DoubleIntegrator(1, T / substeps)  # the command changes within a period: substeps
    ie = iv = a_prev = th_prev = 0.0
    out = []
    for _ in range(n):
        th, om = float(plant.theta[0]), float(plant.omega[0])
        e = 1.0 - th
        w_meas = om if cfg.velocity_source == "tach" else (th - th_prev) / T
        ed = 0.0 - w_meas
        ie += T * e
        iv += T * ed
        a = g.kp * e + g.kpi * ie + g.kv * ed + g.kvi * iv
        th_prev = th
        for j in range(substeps):
            plant.step(a_prev if j < round(d * substeps) else a)
        a_prev = a
        out.append(float(plant.theta[0]))
    return np.array(out)


@pytest.mark.parametrize("delay", [0.0, 0.25, 0.5, 1.0])
@pytest.mark.parametrize("velocity", ["tach", "encoder"])
def test_sampled_closed_loop_equals_brute_force_servo_law(delay: float, velocity: str) -> None:
    cfg = LoopConfig(delay_fraction=delay, velocity_source=velocity)
    n = 150
    expected = brute_force_step(cfg, n)
    _, y = ct.step_response(closed_loop(cfg, sampled=True), T=np.arange(n + 1) * cfg.sample_period_s)
    np.testing.assert_allclose(y[1:], expected, atol=1e-10)


def test_continuous_closed_loop_poles_are_the_papers() -> None:
    p = np.sort_complex(closed_loop_poles(LoopConfig(), sampled=False))
    g = Gains.paper()
    expected = np.sort_complex(np.roots([1.0, g.kv, g.kp + g.kvi, g.kpi]))
    np.testing.assert_allclose(p, expected, rtol=1e-8)
    assert abs(p[0].real + 22.0) < 0.1 and abs(abs(p[0].imag) - 18.7) < 0.2  # ≈ −22 ± 18.6j
    assert abs(p[2].real + 6.0) < 0.1


def test_sampled_plant_without_delay_is_c2d_zoh() -> None:
    cfg = LoopConfig(delay_fraction=0.0, amplifier_bandwidth_hz=40.0)
    ref = ct.c2d(continuous_plant(cfg), cfg.sample_period_s, "zoh")
    mine = sampled_plant(cfg)
    f = np.array([0.1, 1.0, 10.0, 40.0])
    for i in range(4):
        np.testing.assert_allclose(freqresp(mine[i, 0], f), freqresp(ref[i, 0], f), rtol=1e-9)


def test_sampled_plant_with_one_sample_delay_is_c2d_times_z_inverse() -> None:
    cfg = LoopConfig(delay_fraction=1.0)
    T = cfg.sample_period_s
    ref = ct.c2d(continuous_plant(cfg), T, "zoh")[2, 0] * ct.tf([1.0], [1.0, 0.0], T)
    f = np.array([0.1, 1.0, 10.0, 60.0])
    np.testing.assert_allclose(freqresp(sampled_plant(cfg)[2, 0], f), freqresp(ct.ss(ref), f), rtol=1e-9)


@pytest.mark.parametrize("delay", [0.0, 0.5, 1.0])
def test_sampled_plant_shows_zoh_and_delay_phase_lag(delay: float) -> None:
    """ZOH lag ωT/2 (exact for 1/s²) plus the computation delay ω·d·T."""
    cfg = LoopConfig(delay_fraction=delay)
    T = cfg.sample_period_s
    f = np.array([0.5, 2.0, 5.0, 10.0])
    w = 2 * np.pi * f
    lag = np.angle(freqresp(sampled_plant(cfg)[2, 0], f) / freqresp(continuous_plant(cfg)[2, 0], f))
    np.testing.assert_allclose(-lag, w * T * (0.5 + delay), rtol=0.02)


def test_sampled_bode_converges_to_continuous_at_low_frequency() -> None:
    cfg = LoopConfig(delay_fraction=1.0)
    f = np.array([0.01, 0.03, 0.1])
    for build in (open_loop, closed_loop, disturbance_loop, tracking_loop):
        hs, hc = freqresp(build(cfg, True), f), freqresp(build(cfg, False), f)
        np.testing.assert_allclose(np.abs(hs / hc), 1.0, atol=0.01, err_msg=build.__name__)
        assert np.all(np.abs(np.angle(hs / hc)) < math.radians(1.0)), build.__name__
    # and the sampled loop has more phase lag near crossover (about 9 Hz) than the ideal
    fc = np.array([5.0, 9.0])
    assert np.all(np.angle(freqresp(open_loop(cfg, True), fc) / freqresp(open_loop(cfg, False), fc)) < 0)


def test_disturbance_leaves_no_static_error_and_tracking_follows_the_command() -> None:
    for sampled in (False, True):
        cfg = LoopConfig()
        assert abs(freqresp(disturbance_loop(cfg, sampled), np.array([1e-4]))[0]) < 1e-6
        assert abs(freqresp(closed_loop(cfg, sampled), np.array([1e-4]))[0] - 1) < 1e-3


def test_low_velocity_gain_is_unstable_when_sampled() -> None:
    g = Gains(kp=100, kpi=5000, kv=5, kvi=1000)
    assert is_stable(LoopConfig(gains=g), sampled=False)
    assert not is_stable(LoopConfig(gains=g), sampled=True)


def test_loop_config_rejects_out_of_range_parameters() -> None:
    with pytest.raises(LoopConfigError, match="delay"):
        LoopConfig(delay_fraction=1.5)
    with pytest.raises(LoopConfigError, match="tach"):
        LoopConfig(velocity_source="resolver")  # type: ignore[arg-type]
    with pytest.raises(LoopConfigError, match="Hz"):
        LoopConfig(amplifier_bandwidth_hz=-3.0)


def _interconnected(cfg, sampled, break_at):
    """The loop as python-control's interconnect closes it (the reference for build_loop)."""
    from vmehil.analysis.loop_model import (
        continuous_controller,
        continuous_plant,
        sampled_controller,
        sampled_plant,
    )

    if sampled:
        P, K = sampled_plant(cfg), sampled_controller(cfg.gains, cfg.sample_period_s, cfg.velocity_source)
    else:
        P, K = continuous_plant(cfg), continuous_controller(cfg.gains)
    p_in, k_in, extra, x_sig = {"u": "a", "w": "d"}, {"thin": "ths", "win": "ws"}, [], None
    if break_at == "actuator":
        p_in["u"], x_sig = "v", "a"
    elif break_at == "position_sensor":
        k_in["thin"], x_sig = "v", "ths"
    elif break_at == "velocity_sensor":
        k_in["win"], x_sig = "v", "ws"
    elif break_at == "friction":
        p_in["w"], x_sig = "wf", "om"
        extra.append(ct.summing_junction(inputs=["d", "-v"], output="wf", name="F"))
    P = ct.ss(P.A, P.B, P.C, P.D, P.dt, inputs=[p_in["u"], p_in["w"]], outputs=["ths", "ws", "th", "om"])
    K = ct.ss(K.A, K.B, K.C, K.D, K.dt, inputs=["r", "rv", k_in["thin"], k_in["win"]], outputs=["a"])
    inputs = ["r", "rv", "d"] + (["v"] if break_at else [])
    outputs = ["th", "om", "a"] + ([x_sig] if x_sig else [])
    return ct.ss(ct.interconnect([P, K, *extra], inplist=inputs, outlist=outputs))


def _direct_cfg(velocity: str) -> LoopConfig:
    return LoopConfig(gains=Gains(kp=120.0, kpi=4000.0, kv=45.0, kvi=900.0), velocity_source=velocity,
                      amplifier_bandwidth_hz=300.0, position_filter_hz=200.0, velocity_filter_hz=150.0,
                      viscous_damping=0.7, delay_fraction=0.125)


#: the break points a configuration does not have, each refused with its reason (no skip: a new
#: refusal of a valid case would otherwise pass silently)
NO_SUCH_BREAK = {
    (True, "friction", "tach"): "friction acts in continuous time",
    (True, "friction", "encoder"): "friction acts in continuous time",
    (True, "velocity_sensor", "encoder"): "needs velocity_source='tach'",
    (False, "velocity_sensor", "encoder"): "needs velocity_source='tach'",
}


@pytest.mark.parametrize(("sampled", "break_at", "velocity"), list(NO_SUCH_BREAK))
def test_a_break_point_the_configuration_does_not_have_is_refused(sampled, break_at, velocity) -> None:
    with pytest.raises(LoopConfigError, match=re.escape(NO_SUCH_BREAK[(sampled, break_at, velocity)])):
        build_loop(_direct_cfg(velocity), sampled, break_at)


@pytest.mark.parametrize(("sampled", "break_at", "velocity"), [
    (s, b, v) for s in (True, False) for b in (None, "actuator", "position_sensor", "velocity_sensor", "friction")
    for v in ("tach", "encoder") if (s, b, v) not in NO_SUCH_BREAK])
def test_the_directly_assembled_loop_is_the_interconnected_one(sampled, break_at, velocity) -> None:
    cfg = _direct_cfg(velocity)
    got = build_loop(cfg, sampled, break_at)
    ref = _interconnected(cfg, sampled, break_at)
    for a, b in ((got.A, ref.A), (got.B, ref.B), (got.C, ref.C), (got.D, ref.D)):
        assert a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)
    assert got.dt == ref.dt
