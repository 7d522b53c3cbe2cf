"""Plant integration: step convergence, determinism, delay, stops, gravity, compliance."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from emulators.plant import Plant, PlantCommand, PlantParams, load_plant_params

T = 0.008
STEP_TOLERANCE_RAD = 5.0e-4  #: a third of a 12-bit pot count (1.45 mrad)


def _drive(p: Plant, t: float) -> PlantCommand:
    c = p.idle_command()
    c.amp_enable[:] = True
    c.holding_brake[:] = True  # powered: the holding brakes released
    c.amp_command_v[:6] = np.array([1.2, 3.0, 3.5, 2.0, 2.5, 0.8]) * np.sin(2 * math.pi * 0.3 * t + np.arange(6))
    c.pwm_duty[6] = 0.3 * abs(math.sin(2 * math.pi * 0.2 * t))
    c.pwm_direction[6] = math.sin(2 * math.pi * 0.2 * t) > 0
    return c


def _trajectory(rate_hz: float, seconds: float = 10.0, seed: int = 0, params=None):
    p = Plant(params or load_plant_params("jpl-arm"), seed=seed, rate_hz=rate_hz)
    out = []
    for k in range(round(seconds / T)):
        out.append(p.step_period(_drive(p, k * T), T))
    return out


@pytest.mark.slow
def test_halving_the_step_changes_a_10s_trajectory_by_less_than_the_tolerance():
    a = np.array([s.truth["theta_joint"] for s in _trajectory(4000.0)])
    b = np.array([s.truth["theta_joint"] for s in _trajectory(8000.0)])
    moved = np.ptp(a, axis=0)
    assert np.all(moved > 0.01)  # every joint moved (stick/slip, gravity, stops, H-bridge)
    diff = np.abs(a - b).max(axis=0)
    print("max |Δθ| per joint (rad):", diff)
    assert np.all(diff < STEP_TOLERANCE_RAD)


def test_same_seed_gives_identical_output_and_another_seed_other_noise():
    params = load_plant_params("jpl-arm")
    a = _trajectory(4000.0, 1.0, seed=11, params=params)
    b = _trajectory(4000.0, 1.0, seed=11, params=params)
    c = _trajectory(4000.0, 1.0, seed=12, params=params)
    for x, y in zip(a, b, strict=True):
        for f in ("pot_v", "tach_v", "imon_v", "amp_fault"):
            assert np.array_equal(getattr(x, f), getattr(y, f))
        assert x.encoder == y.encoder
        for k in x.truth:
            assert np.array_equal(x.truth[k], y.truth[k])
    pot_a = np.array([s.pot_v for s in a])
    pot_c = np.array([s.pot_v for s in c])
    assert not np.array_equal(pot_a, pot_c)
    # noise is on the sensors only: in open loop the motion is the same
    assert np.array_equal(a[-1].truth["theta_joint"], c[-1].truth["theta_joint"])
    noise = (pot_a - pot_c)[:, 0]
    assert 0.5e-3 < np.std(noise) / math.sqrt(2) < 3e-3  # the 1.5 mV wiper noise


def test_reset_replays_identically():
    p = Plant(load_plant_params("jpl-arm"), seed=5)
    first = [p.step_period(_drive(p, k * T), T).pot_v for k in range(20)]
    p.reset()
    again = [p.step_period(_drive(p, k * T), T).pot_v for k in range(20)]
    assert np.array_equal(np.array(first), np.array(again))


def test_adding_a_joint_does_not_change_another_joints_noise():
    params = load_plant_params("jpl-arm")
    p1 = Plant(PlantParams(joints=params.joints[:1]), seed=3)
    p2 = Plant(PlantParams(joints=params.joints[:2]), seed=3)
    for _ in range(5):
        a = p1.step_period(p1.idle_command(), T)
        b = p2.step_period(p2.idle_command(), T)
        assert a.pot_v[0] == b.pot_v[0] and a.tach_v[0] == b.tach_v[0]


def test_command_takes_effect_after_the_computation_delay():
    j = load_plant_params("jpl-arm").joints[0]
    p = Plant(PlantParams(joints=[j]))
    c = p.idle_command()
    c.amp_enable[0] = True
    c.amp_command_v[0] = 0.5
    s = p.step_period(c, T, delay_s=T)  # the whole period still runs the old (idle) command
    assert s.truth["current_a"][0] == 0.0
    s = p.step_period(c, T, delay_s=T)  # now the previous command is the enabled one
    assert math.isclose(s.truth["current_a"][0], 1.5, rel_tol=1e-9)
    q = Plant(PlantParams(joints=[j]))
    s = q.step_period(c, T, delay_s=T - 1.0 / q.rate_hz)  # on for the last substep only
    assert math.isclose(s.truth["current_a"][0], 1.5 * (1 - math.exp(-2 * math.pi * 1000 / q.rate_hz)))


def test_a_command_mutated_in_place_still_gets_its_delay_and_reset_edge():
    j = load_plant_params("jpl-arm").joints[0]
    j = replace(j, linear_amp=replace(j.linear_amp, continuous_current_a=1.0, thermal_time_constant_s=0.01))
    p = Plant(PlantParams(joints=[j]))
    c = p.idle_command()
    c.amp_enable[0] = True
    c.amp_command_v[0] = 0.1
    p.step_period(c, T)
    c.amp_command_v[0] = 0.2  # mutate the same object: the old 0.1 V must hold during the delay
    s = p.step_period(c, T, delay_s=T)
    assert math.isclose(s.truth["current_a"][0], 0.3, rel_tol=1e-9)
    c.amp_command_v[0] = 2.0  # 6 A on a 1 A rating: trips
    for _ in range(5):
        s = p.step_period(c, T)
    assert bool(s.amp_fault[0])
    c.amp_command_v[0] = 0.0
    for _ in range(20):
        p.step_period(c, T)  # cool down
    c.fault_reset[0] = True
    s = p.step_period(c, T)
    assert not bool(s.amp_fault[0])


def test_hard_stop_is_an_inelastic_clamp():
    j = load_plant_params("jpl-arm").joints[0]
    j = replace(j, link=replace(j.link, upper_stop_rad=0.05))
    p = Plant(PlantParams(joints=[j]))
    c = p.idle_command()
    c.amp_enable[0] = True
    c.amp_command_v[0] = 3.0
    for _ in range(100):
        s = p.step_period(c, T)
    assert s.truth["theta_joint"][0] == pytest.approx(0.05, abs=1e-12)
    assert s.truth["omega_joint"][0] == 0.0 and bool(s.truth["at_stop"][0])
    c.amp_command_v[0] = -3.0
    for _ in range(10):
        s = p.step_period(c, T)
    assert s.truth["theta_joint"][0] < 0.05 and not bool(s.truth["at_stop"][0])


@pytest.mark.parametrize("gravity,falls", [(3.0, False), (6.0, True)])
def test_unpowered_joint_holds_by_stiction_only_below_the_output_breakout(gravity, falls):
    j = load_plant_params("jpl-arm").joints[0]  # output breakout 4.59 N·m·(1 ± 0.22)
    j = replace(j, link=replace(j.link, gravity_torque_nm=gravity), friction=replace(j.friction, ripple_fraction=0.0))
    p = Plant(PlantParams(joints=[j]))
    for _ in range(50):
        s = p.step_period(p.idle_command(), T)
    assert bool(s.truth["theta_joint"][0] < -1e-3) == falls


def test_compliant_joint_deflects_by_torque_over_stiffness():
    j = load_plant_params("jpl-arm").joints[0]
    j = replace(j, gear=replace(j.gear, compliant=True, stiffness_nm_per_rad=2.0e4, damping_nm_s_per_rad=200.0))
    p = Plant(PlantParams(joints=[j]))
    p.set_external_torque(np.array([3.0]))  # the motor side sticks: 3/N N·m < the breakout
    for _ in range(100):
        s = p.step_period(p.idle_command(), T)
    assert s.truth["theta_motor"][0] == 0.0
    assert s.truth["theta_joint"][0] == pytest.approx(3.0 / 2.0e4, rel=1e-3)


def test_kinematic_error_is_periodic_in_twice_the_wave_generator_angle():
    j = load_plant_params("jpl-arm").joints[0]
    amp = 3e-4
    j = replace(j, gear=replace(j.gear, kinematic_error_rad=amp, kinematic_error_phase_rad=0.4))
    p = Plant(PlantParams(joints=[j]))
    c = p.idle_command()
    c.amp_enable[0] = True
    c.amp_command_v[0] = 3.0
    for _ in range(100):
        s = p.step_period(c, T)
        thm = s.truth["theta_motor"][0]
        assert s.truth["theta_joint"][0] == pytest.approx(thm / 100 + amp * math.sin(2 * thm + 0.4), abs=1e-15)
    assert s.truth["theta_motor"][0] > 2 * math.pi


def test_bad_parameters_are_rejected_with_the_joint_named():
    j = load_plant_params("jpl-arm").joints[0]
    with pytest.raises(ValueError, match="j1.*ripple"):
        Plant(PlantParams(joints=[replace(j, friction=replace(j.friction, ripple_fraction=1.0))]))
    with pytest.raises(ValueError, match="unique"):
        Plant(PlantParams(joints=[j, j]))
