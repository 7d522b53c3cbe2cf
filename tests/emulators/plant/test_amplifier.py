"""Amplifier power stages in the plant: transconductance amplifier and H-bridge."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from emulators.plant import Plant, PlantParams, load_plant_params
from emulators.plant.amplifier import FAULT_COMPLIANCE, FAULT_OVERCURRENT, FAULT_THERMAL
from emulators.plant.motor import rl_step

T = 0.008


def _lin(**amp):
    j = load_plant_params("jpl-arm").joints[0]
    return replace(j, linear_amp=replace(j.linear_amp, **amp)) if amp else j


def _hand(**hb):
    j = load_plant_params("jpl-arm").joints[6]
    return replace(j, hbridge=replace(j.hbridge, **hb)) if hb else j


def _plant(j):
    return Plant(PlantParams(joints=[j]), seed=2)


def _lin_cmd(p, volts, enable=True, reset=False):
    c = p.idle_command()
    c.amp_enable[0] = enable
    c.amp_command_v[0] = volts
    c.fault_reset[0] = reset
    return c


def test_transconductance_first_order_current_response():
    j = _lin()
    p = _plant(j)
    h = 1.0 / p.rate_hz
    s = p.step_period(_lin_cmd(p, 0.5), h)  # 1.5 A: below breakout, the rotor stays still
    expect = 1.5 * (1.0 - math.exp(-2 * math.pi * j.linear_amp.bandwidth_hz * h))
    assert math.isclose(s.truth["current_a"][0], expect, rel_tol=1e-12)
    s = p.step_period(_lin_cmd(p, 0.5), T)
    assert math.isclose(s.truth["current_a"][0], 1.5, rel_tol=1e-9)


def test_current_limit_clips_the_reference():
    p = _plant(_lin())
    p.set_external_torque(np.array([-1000.0]))  # hold the joint still against 30 A
    s = p.step_period(_lin_cmd(p, 20.0), T)
    assert math.isclose(s.truth["current_a"][0], 30.0, rel_tol=1e-9)
    p.set_external_torque(np.array([1000.0]))
    s = p.step_period(_lin_cmd(p, -20.0), T)
    assert math.isclose(s.truth["current_a"][0], -30.0, rel_tol=1e-9)


def test_compliance_limits_the_current_slew_to_the_rail_solution():
    j = _lin()
    j = replace(j, motor=replace(j.motor, inductance_h=0.05))  # L·di/dt needs more than 28 V
    p = _plant(j)
    h = 1.0 / p.rate_hz
    s = p.step_period(_lin_cmd(p, 1.0), h)
    rail = rl_step(np.array([0.0]), np.array([28.0]), np.array([0.0]), np.array([0.8]),
                   np.exp(-h * np.array([0.8]) / 0.05))
    assert math.isclose(s.truth["current_a"][0], rail[0], rel_tol=1e-12)
    assert s.truth["current_a"][0] < 3.0 * (1.0 - math.exp(-2 * math.pi * 1000 * h))


def test_compliance_bounds_current_at_speed_by_the_back_emf():
    """Spinning freely at full command the motor reaches the speed where Ke·ω + R·i = supply."""
    j = _lin(saturation_fault_s=0.0, continuous_current_a=100.0)
    j = replace(
        j,
        friction=replace(j.friction, viscous_nm_s_per_rad=2.5e-4),
        link=replace(j.link, inertia_kg_m2=0.01, lower_stop_rad=-1e6, upper_stop_rad=1e6),
    )
    p = _plant(j)
    for _ in range(400):
        s = p.step_period(_lin_cmd(p, 10.0), T)
    i, w = s.truth["current_a"][0], s.truth["omega_motor"][0]
    assert i < 29.0  # far below the 30 A asked for
    assert math.isclose(0.8 * i + 0.028 * w, 28.0, rel_tol=1e-3)
    assert bool(p.amp_state.saturated[0])


def test_disable_lets_the_current_decay_to_zero_and_enable_restores_it():
    p = _plant(_lin())
    p.step_period(_lin_cmd(p, 0.5), T)
    s = p.step_period(_lin_cmd(p, 0.5, enable=False), T)
    assert s.truth["current_a"][0] == 0.0
    assert abs(s.imon_v[0] - 0.002) < 0.01
    s = p.step_period(_lin_cmd(p, 0.5), T)
    assert math.isclose(s.truth["current_a"][0], 1.5, rel_tol=1e-9)


def test_current_monitor_scales_volts_per_amp():
    p = _plant(_lin())
    p.set_external_torque(np.array([-100.0]))
    s = p.step_period(_lin_cmd(p, 2.0), T)
    assert math.isclose(s.imon_v[0], 6.0 / 3.0 + 0.002, abs_tol=0.006)  # 6 A · (1/3 V/A) + offset


def test_thermal_fault_latches_and_needs_a_rising_reset_edge_after_cooling():
    p = _plant(_lin(continuous_current_a=1.0, thermal_time_constant_s=0.05))
    p.set_external_torque(np.array([-100.0]))
    for _ in range(20):
        s = p.step_period(_lin_cmd(p, 1.0), T)  # 3 A against a 1 A rating
    assert bool(s.amp_fault[0]) and s.truth["amp_fault_cause"][0] & FAULT_THERMAL
    assert s.truth["current_a"][0] == 0.0
    s = p.step_period(_lin_cmd(p, 1.0, reset=True), T)  # still hot: trips again at once
    assert bool(s.amp_fault[0])
    for _ in range(60):
        s = p.step_period(_lin_cmd(p, 1.0, reset=True), T)  # reset held high: no new edge
    assert bool(s.amp_fault[0]) and s.truth["amp_thermal"][0] < 0.5
    p.step_period(_lin_cmd(p, 0.1, reset=False), T)
    s = p.step_period(_lin_cmd(p, 0.1, reset=True), T)  # rising edge, cool: cleared
    assert not bool(s.amp_fault[0])
    assert s.truth["current_a"][0] > 0.29


def test_held_compliance_saturation_latches_a_fault():
    j = _lin(saturation_fault_s=0.1)
    j = replace(j, motor=replace(j.motor, resistance_ohm=2.0))  # 30 A would need 60 V
    p = _plant(j)
    p.set_external_torque(np.array([-1000.0]))
    faults = [bool(p.step_period(_lin_cmd(p, 10.0), T).amp_fault[0]) for _ in range(20)]
    assert not faults[10] and faults[-1]
    assert p.amp_state.cause[0] & FAULT_COMPLIANCE


def _hb_cmd(p, duty=0.0, direction=True, brake=False, enable=True, reset=False):
    c = p.idle_command()
    c.amp_enable[0] = enable
    c.pwm_duty[0] = duty
    c.pwm_direction[0] = direction
    c.brake[0] = brake
    c.fault_reset[0] = reset
    return c


def test_hbridge_duty_sets_average_voltage_less_dead_time():
    j = _hand()
    p = _plant(j)
    p.reset(np.array([0.0]))
    p.set_external_torque(np.array([-10.0]))  # stalled against the closed stop
    for duty, direction in ((0.2, True), (0.1, False)):
        s = p.step_period(_hb_cmd(p, duty, direction), T)
        v = (duty - 1e-6 * 20000.0) * 24.0 * (1 if direction else -1)
        stalled = s.truth["omega_motor"][0] == 0.0
        assert stalled
        assert math.isclose(s.truth["current_a"][0], v / 3.0, rel_tol=1e-6)
        assert bool(s.switching[0])


def test_hbridge_chops_at_the_current_limit():
    p = _plant(_hand())
    p.set_external_torque(np.array([-10.0]))
    s = p.step_period(_hb_cmd(p, 1.0), T)
    assert math.isclose(s.truth["current_a"][0], 2.0, rel_tol=1e-12)
    assert not bool(s.amp_fault[0])


def _spin(p, steps=25):
    for _ in range(steps):
        s = p.step_period(_hb_cmd(p, 0.8), T)
    return s


def test_brake_stops_faster_than_coast():
    j = _hand()
    j = replace(j, link=replace(j.link, upper_stop_rad=1e3, lower_stop_rad=-1e3, initial_angle_rad=0.0))
    speeds = {}
    for mode in ("brake", "coast"):
        p = _plant(j)
        s0 = _spin(p)
        w0 = s0.truth["omega_motor"][0]
        s = p.step_period(_hb_cmd(p, 0.0, brake=(mode == "brake")), T)
        speeds[mode] = s.truth["omega_motor"][0]
        if mode == "coast":
            assert s.truth["current_a"][0] == 0.0  # open winding: no current at all
        else:
            assert s.truth["current_a"][0] < 0.0  # shorted winding: generator current opposes
        assert 0.0 <= speeds[mode] < w0
    assert speeds["brake"] < speeds["coast"]


def test_hbridge_overcurrent_fault_latches_and_resets():
    j = _hand(overcurrent_trip_a=1.0, current_limit_a=5.0)  # chopping above the trip level
    p = _plant(j)
    p.set_external_torque(np.array([-10.0]))
    s = p.step_period(_hb_cmd(p, 0.5), T)
    assert bool(s.amp_fault[0]) and s.truth["amp_fault_cause"][0] & FAULT_OVERCURRENT
    assert s.truth["current_a"][0] == 0.0  # faulted bridge coasts
    s = p.step_period(_hb_cmd(p, 0.0, reset=True), T)
    assert not bool(s.amp_fault[0])


def test_mixed_amplifier_types_step_together():
    params = load_plant_params("jpl-arm")
    p = Plant(params, seed=4)
    c = p.idle_command()
    c.amp_enable[:] = True
    c.amp_command_v[:6] = 0.3
    c.pwm_duty[6] = 0.3
    s = p.step_period(c, T)
    assert s.truth["current_a"][6] > 0.0
    assert np.all(s.truth["current_a"][:6] > 0.0)
    assert not s.switching[:6].any() and bool(s.switching[6])
    assert np.all(s.switching_noise_v[:6] == 0.0) and s.switching_noise_v[6] == 0.02
    c.pwm_duty[6] = 0.0
    s = p.step_period(c, T)
    assert not bool(s.switching[6]) and s.switching_noise_v[6] == 0.0


def test_fast_linear_path_equals_the_general_amplifier_step():
    from emulators.plant.amplifier import AmpState, current_step, current_step_linear

    p = Plant(load_plant_params("jpl-arm"), seed=1)
    lin = p.amp.is_lin
    rng = np.random.default_rng(0)
    c = p.idle_command()
    c.amp_enable[:] = True
    k = p._step_consts(1.0 / p.rate_hz).amp
    for _ in range(200):
        c.amp_command_v = rng.uniform(-12, 12, p.n_joints)
        drv = p._drive(c)
        i0 = rng.uniform(-35, 35, p.n_joints)
        w = rng.uniform(-900, 900, p.n_joints)
        a, b = AmpState(p.n_joints), AmpState(p.n_joints)
        i_gen = current_step(p.amp, a, drv, i0, w, k)
        i_fast = current_step_linear(b, drv.i_ref * (1.0 - k.loop), i0, w, k)
        assert np.allclose(i_gen[lin], i_fast[lin], rtol=1e-12, atol=1e-12)
        assert np.array_equal(a.saturated[lin], b.saturated[lin])
