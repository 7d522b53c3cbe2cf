"""Control objects: normalizing chain, torque limit with anti-windup, friction and gravity feedforward,
building controllers from TOML and swapping them at run time."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from hal.config import ConfigError, ConfigTable, load_toml
from hal.si import oz_in_to_nm
from servo.control import (
    Controller,
    FrictionComp,
    GainError,
    GravityComp,
    PidLaw,
    PidObject,
    SwitchableController,
    SwitchOffConfig,
    TorqueLimit,
    build_controller,
    normalizing_chain,
    unit_chain,
)
from tests.support.fakes import DoubleIntegrator

T = 0.008


def jpl_chain(n=1):
    # joint 1 of the paper: J ≈ 3 kg·m², N = 100, Kt ≈ 0.028 N·m/A; a 2 A/V amplifier, 12-bit ±10 V DAC
    return normalizing_chain(3.0, 100.0, 0.028, 2.0, dac_volts_per_count=20.0 / 4096, n=n)


def test_normalizing_chain_numbers():
    ch = jpl_chain()
    assert ch.volts_per_accel[0] == pytest.approx(3.0 / (100 * 0.028 * 2.0))
    tau = ch.torque_from_accel(np.array([10.0]))
    assert tau[0] == pytest.approx(30.0)
    assert ch.torque_from_current(np.array([1.0]))[0] == pytest.approx(2.8)  # N·Kt = 100 · 0.028
    assert ch.torque_from_volts(np.array([1.0]))[0] == pytest.approx(5.6)  # · 2 A/V
    # 6 oz-in breakout at the motor is ~1.5 A (docs/jpl-figures.md): 6 · 0.0070615518 / 0.028
    assert oz_in_to_nm(6.0) * 100 / ch.torque_from_current(np.array([1.0]))[0] == pytest.approx(1.51, abs=0.01)
    assert ch.describe()[0]["volts_per_accel"] == pytest.approx(ch.volts_per_accel[0])
    with pytest.raises(GainError, match=r"kt\[1\] = 0.0"):
        normalizing_chain(1.0, 1.0, [0.1, 0.0], 1.0)


def test_controller_outputs_torque_through_the_chain():
    ch = jpl_chain(2)
    c = Controller([PidObject(PidLaw(2, T, switch_off=SwitchOffConfig.disabled(2)))], ch, T)
    out = c.step(0, np.zeros(2), np.zeros(2), np.array([0.01, -0.02]), np.zeros(2))
    # a = (Kp + Kpi·T)·e = (100 + 5000 · 0.008)·e = 140·e; τ = J_eff·a = 3 · a
    np.testing.assert_allclose(out.accel, [1.4, -2.8])
    np.testing.assert_allclose(out.torque, [4.2, -8.4])


def _saturating_run(objects_factory, ticks=120, step=1.0):
    """Unit chain (torque = accel) double integrator driven to a large step."""
    ch = unit_chain(1)
    c = Controller(objects_factory(), ch, T)
    plant = DoubleIntegrator(1, T)
    ies, sats, taus, ths = [], [], [], []
    for k in range(ticks):
        out = c.step(k, plant.theta, plant.omega, np.array([step]), np.zeros(1))
        plant.step(np.clip(out.torque, -20.0, 20.0))  # the plant's actuator limit either way
        ies.append(c.law.state.ie[0])
        sats.append(out.saturation[0])
        taus.append(out.torque[0])
        ths.append(plant.theta[0])
    return np.array(ies), np.array(sats), np.array(taus), np.array(ths)


def _pid():
    return PidObject(PidLaw(1, T, switch_off=SwitchOffConfig.disabled(1)))


def test_anti_windup_stops_integration_into_saturation():
    ies, sats, taus, ths = _saturating_run(lambda: [_pid(), TorqueLimit(np.array([20.0]))])
    assert sats[0] == 1 and np.all(np.abs(taus) <= 20.0 + 1e-12)
    first_free = int(np.argmax(sats == 0))
    assert first_free > 5  # it really was saturated for a while
    # while pinned at +limit with e > 0, the position integrator never grew
    assert np.all(ies[:first_free] == 0.0)
    # without the limiter object (the plant clips) the integrator winds up
    ies_w, _, _, ths_w = _saturating_run(lambda: [_pid()])
    assert ies_w[first_free - 1] > 0.05
    assert ths_w.max() > ths.max()  # windup → more overshoot


def test_anti_windup_lets_integrators_unwind():
    pid = _pid()
    c = Controller([pid, TorqueLimit(np.array([1.0]))], unit_chain(1), T)
    pid.law.state.ie[:] = 0.01  # pushing the output to the + limit
    out = c.step(0, np.array([0.001]), np.zeros(1), np.zeros(1), np.zeros(1))  # e < 0: integrate inwards
    assert out.saturation[0] == 1
    assert pid.law.state.ie[0] == pytest.approx(0.01 - T * 0.001)


def test_torque_limit_from_current_and_volts_takes_the_tightest():
    ch = jpl_chain()
    cfg = ConfigTable({"current_max_a": 6.0, "volts_max_v": 10.0}, "rig.toml", "ctl.torque_limit")
    lim = TorqueLimit.from_config(cfg, 1, ch, T)
    assert lim.tau_max[0] == pytest.approx(min(6.0 * 2.8, 10.0 * 2.0 * 2.8))
    with pytest.raises(ConfigError, match=r"rig.toml: key 'ctl.torque_limit.tau_max_nm'"):
        TorqueLimit.from_config(ConfigTable({}, "rig.toml", "ctl.torque_limit"), 1, ch, T)


def test_friction_comp_coulomb_viscous_and_dead_zone():
    ch = normalizing_chain(1.0, [100.0, 50.0], 0.03, 1.0)
    fc = FrictionComp(np.array([0.04, 0.04]), np.array([1e-4, 0.0]), np.array([0.01, 0.01]))
    c = Controller([fc], ch, T)
    out = c.step(0, np.zeros(2), np.zeros(2), np.zeros(2), np.array([0.1, -0.1]))
    np.testing.assert_allclose(out.torque, [100 * 0.04 + 100**2 * 1e-4 * 0.1, -50 * 0.04])
    out = c.step(1, np.zeros(2), np.zeros(2), np.zeros(2), np.array([0.005, -0.005]))  # inside the dead zone
    np.testing.assert_allclose(out.torque, [100**2 * 1e-4 * 0.005, 0.0])
    fm = FrictionComp(np.array([0.04, 0.04]), np.zeros(2), np.zeros(2), use_measured=True)
    out = Controller([fm], ch, T).step(0, np.zeros(2), np.array([-1.0, 1.0]), np.zeros(2), np.array([1.0, 1.0]))
    np.testing.assert_allclose(out.torque, [-4.0, 2.0])


def test_gravity_comp():
    g = GravityComp(np.array([10.0]), np.array([0.5]))
    out = Controller([g], unit_chain(1), T).step(0, np.array([1.0]), np.zeros(1), np.array([0.2]), np.zeros(1))
    assert out.torque[0] == pytest.approx(10.0 * np.cos(0.7))


RIG = """
[joint.servo.controller]
objects = ["pid", "gravity_comp", "friction_comp", "torque_limit"]
[joint.servo.controller.pid]
kp = [100.0, 120.0]
kpi = 5000
switch_off = { enabled = [true, false], inner_band_deg = 0.2, outer_band_deg = 2.0, kp_boost = 4, settle_time_s = 0.1 }
[joint.servo.controller.gravity_comp]
mass_kg = [2.0, 1.0]
com_m = 0.5
offset_deg = 90
[joint.servo.controller.friction_comp]
coulomb_motor_nm = 0.042
velocity = "measured"
[joint.servo.controller.torque_limit]
current_max_a = 6.0
"""


def _ctl_table(tmp_path, text):
    p = tmp_path / "rig.toml"
    p.write_text(text)
    return load_toml(p).table("joint").table("servo").table("controller")


def test_build_controller_from_toml(tmp_path):
    c = build_controller(_ctl_table(tmp_path, RIG), jpl_chain(2), T)
    assert [o.name for o in c.objects] == ["pid", "gravity_comp", "friction_comp", "torque_limit"]
    np.testing.assert_array_equal(c.law.gains.kp, [100.0, 120.0])
    np.testing.assert_array_equal(c.law.gains.kvi, [1000.0, 1000.0])
    so = c.law.switch_off
    np.testing.assert_array_equal(so.enabled, [True, False])
    np.testing.assert_allclose(so.inner_band, np.radians(0.2))
    np.testing.assert_allclose(c.law.kp_off(), [400.0, 480.0])
    np.testing.assert_allclose(c.find("gravity_comp").mgl, [2.0 * 9.80665 * 0.5, 9.80665 * 0.5])
    np.testing.assert_allclose(c.find("gravity_comp").offset, np.pi / 2)
    np.testing.assert_allclose(c.find("torque_limit").tau_max, 6.0 * 2.8)
    assert c.describe()["objects"] == ["pid", "gravity_comp", "friction_comp", "torque_limit"]


def test_default_controller_is_the_paper_law():
    c = build_controller({}, unit_chain(3))
    assert [o.name for o in c.objects] == ["pid"]
    assert c.law.gains.as_dict()["kpi"] == [5000.0] * 3
    assert c.law.switch_off.enabled.all()


@pytest.mark.parametrize(("edit", "key"), [
    (('"friction_comp", "torque_limit"]', '"friction", "torque_limit"]'), "joint.servo.controller.objects[2]"),
    (("kpi = 5000", "kpi = -5000"), "joint.servo.controller.pid.kpi"),
    (("kp = [100.0, 120.0]", "kp = [100.0]"), "joint.servo.controller.pid.kp"),
    (("kp_boost = 4", "kp_boost = 0.5"), "joint.servo.controller.pid.switch_off.kp_boost"),
    (("outer_band_deg = 2.0", "outer_band_deg = 0.1"), "joint.servo.controller.pid.switch_off.outer_band_deg"),
    (('velocity = "measured"', 'velocity = "sensed"'), "joint.servo.controller.friction_comp.velocity"),
    (("com_m = 0.5", "comm_m = 0.5"), "joint.servo.controller.gravity_comp.com_m"),
    (("kpi = 5000", "kpi = 5000\nkd = 3"), "joint.servo.controller.pid.kd"),
])
def test_controller_config_errors_name_file_and_key(tmp_path, edit, key):
    text = RIG.replace(*edit)
    assert text != RIG
    with pytest.raises(ConfigError) as ei:
        build_controller(_ctl_table(tmp_path, text), jpl_chain(2), T)
    assert ei.value.source.endswith("rig.toml")
    assert ei.value.key == key


def test_swap_controller_at_tick_boundary_keeps_integrators():
    ch = unit_chain(1)
    a = build_controller({"objects": ["pid"]}, ch)
    holder = SwitchableController(a)
    th, w = np.zeros(1), np.zeros(1)

    def tick(k):
        from servo.control import ControlContext
        ctx = ControlContext(k, k * T, T, th, w, np.array([0.1]), np.zeros(1), np.zeros(1), False, ch)
        return holder.update(ctx)

    for k in range(10):
        tick(k)
    ie = a.law.state.ie.copy()
    b = build_controller(tomllib.loads('objects = ["pid", "torque_limit"]\n[torque_limit]\ntau_max_nm = 1.0'), ch)
    holder.request(b)
    assert holder.active is a  # not before the tick boundary
    out = tick(10)
    assert holder.active is b
    assert holder.swaps == [(10, ["pid"])]
    # the new law carried on from the old integrators; this tick saturates at +1 N·m, so anti-windup
    # withholds the (positive) integration and the carried value is kept exactly
    assert ie[0] > 0.0
    assert out.saturation[0] == 1 and out.torque[0] == 1.0
    assert b.law.state.ie[0] == ie[0]


def test_live_gain_change_through_the_controller():
    c = build_controller({"pid": {"switch_off": {"enabled": False}}}, unit_chain(1))
    c.law.set_gains(kp=0.0, kpi=0.0, kv=0.0, kvi=0.0)
    out = c.step(0, np.zeros(1), np.zeros(1), np.array([1.0]), np.zeros(1))
    assert out.torque[0] == 0.0


def test_demo_motion_closed_loop_on_an_ideal_plant():
    """Sequencer → controller → ZOH double integrator: tight tracking, then the switch-off engages."""
    from servo.motion import default_demo_motion
    from servo.trajectory import JointLimits, PlanContext

    n = 3
    ch = jpl_chain(n)
    c = build_controller({"objects": ["pid", "torque_limit"], "torque_limit": {"current_max_a": 6.0}}, ch)
    seq = default_demo_motion(n).sequencer(np.zeros(n), PlanContext(JointLimits.make(n, 0.5)))
    plant = DoubleIntegrator(n, T, inertia=ch.j_eff)  # the ideal plant: θ'' = τ/J
    err, done_at = [], None
    for k in range(int(4.0 / T)):
        s = seq.sample(k * T)
        if s.done and done_at is None:
            done_at = k
        err.append(s.theta_d - plant.theta)
        out = c.step(k, plant.theta, plant.omega, s.theta_d, s.omega_d, s.alpha_d, s.done)
        plant.step(out.torque)
    err = np.abs(np.array(err))
    assert done_at is not None and np.degrees(err.max()) < 1e-3  # αd feedforward: tracks the quintic closely
    offs = [e for e in c.events if not e.integrating]
    assert sorted(e.joint for e in offs) == list(range(n))
    assert all(e.tick >= done_at and e.reason == "settled" for e in offs)
    assert not c.law.integrating.any()
