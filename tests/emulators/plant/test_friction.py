"""Harmonic Drive friction: exact stiction, passivity, and the paper's joint-1 figures."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from emulators.plant import Plant, PlantParams, load_plant_params
from emulators.plant.friction import FrictionArrays, stick_slip_step
from emulators.plant.friction_metrics import breakout_from_ramp, running_torque_metrics
from hal.si import nm_to_oz_in

T = 0.008


def _j1(**friction):
    j1 = load_plant_params("jpl-arm").joints[0]
    if friction:
        j1 = replace(j1, friction=replace(j1.friction, **friction))
    return j1


def _plant(j, seed=0):
    return Plant(PlantParams(joints=[j]), seed=seed)


def _hold_torque(plant: Plant, torque_nm: float, seconds: float):
    """Command a steady motor torque through the linear amplifier."""
    jp = plant.params.joints[0]
    cmd = plant.idle_command()
    cmd.amp_enable[0] = True
    cmd.amp_command_v[0] = torque_nm / jp.motor.kt_nm_per_a / jp.linear_amp.gain_a_per_v
    s = None
    for _ in range(round(seconds / T)):
        s = plant.step_period(cmd, T)
    return s


def test_stiction_holds_exactly_below_breakout_and_releases_above():
    j = _j1()
    ts = j.friction.breakout_nm  # θm = 0 and ripple phase 0: the local breakout is exactly T_s
    held = _plant(j)
    s = _hold_torque(held, 0.99 * ts, 1.0)
    assert s.truth["theta_motor"][0] == 0.0 and s.truth["omega_motor"][0] == 0.0
    assert bool(s.truth["stuck"][0])
    assert math.isclose(s.truth["friction_torque_nm"][0], 0.99 * ts, rel_tol=1e-9)
    moved = _plant(j)
    s = _hold_torque(moved, 1.01 * ts, 1.0)
    assert s.truth["theta_motor"][0] > 0.0 and s.truth["omega_motor"][0] > 0.0


def test_breakout_depends_on_wave_generator_angle_within_the_papers_range():
    """The local breakout is T_s·(1 + m·sin 2θm): 5–9 oz-in measured on the input shaft."""
    j = _j1()
    found = []
    for theta_m in np.linspace(0.0, math.pi, 7):
        p = _plant(j)
        p.reset(np.array([theta_m / j.gear.ratio]))
        start = float(p.theta_m[0])
        ramp = np.linspace(0.5, 1.5, 201) * j.friction.breakout_nm
        cmd = p.idle_command()
        cmd.amp_enable[0] = True
        torque, moved = [], []
        for tq in ramp:
            cmd.amp_command_v[0] = tq / j.motor.kt_nm_per_a / j.linear_amp.gain_a_per_v
            s = p.step_period(cmd, T)
            torque.append(s.truth["motor_torque_nm"][0])
            moved.append(s.truth["theta_motor"][0] != start)
        found.append(nm_to_oz_in(breakout_from_ramp(np.array(torque), np.array(moved))))
    assert 5.0 <= min(found) < max(found) <= 9.0
    assert max(found) - min(found) > 1.5  # the position dependence is real


def test_output_shaft_breakout_is_about_600_oz_in():
    """Backdriving the unpowered joint with a torque at the link (a torque gauge)."""
    j = _j1(ripple_fraction=0.0)
    p = _plant(j)
    moved_at = None
    for tq in np.linspace(500.0, 800.0, 151):
        p.set_external_torque(np.array([tq * 0.0070615518]))
        s = p.step_period(p.idle_command(), T)
        if s.truth["theta_joint"][0] != 0.0:
            moved_at = tq
            break
    assert moved_at is not None
    assert 600.0 <= moved_at <= 700.0
    assert math.isclose(moved_at, nm_to_oz_in(j.breakout_at_output_nm()), abs_tol=2.1)


def _free_coast(ripple: float):
    j = _j1(ripple_fraction=ripple)
    p = _plant(j)
    p.omega_m = np.array([60.0])  # motor rad/s, amplifier disabled: no current can flow
    ke = []
    for _ in range(200):
        s = p.step_period(p.idle_command(), T / 8)
        ke.append(0.5 * p.J_m[0] * s.truth["omega_motor"][0] ** 2)
    return np.array(ke)


def test_free_coast_energy_never_increases_with_or_without_ripple():
    for ripple in (0.0, 0.22, 0.9):
        ke = _free_coast(ripple)
        assert ke[0] > 0.0
        assert np.all(np.diff(ke) <= 0.0)
        assert ke[-1] == 0.0  # captured at zero speed, exactly


@settings(max_examples=300, deadline=None)
@given(
    omega=st.floats(-300.0, 300.0),
    theta=st.floats(-50.0, 50.0),
    t_drive=st.floats(-0.5, 0.5),
    ripple=st.floats(0.0, 0.95),
    viscous=st.sampled_from([0.0, 1e-4, 0.0104, 0.5]),
    coulomb=st.floats(0.0, 0.1),
    breakout=st.floats(0.0, 0.1),
    h=st.sampled_from([2.5e-4, 1.25e-4, 1e-3]),
)
def test_friction_never_does_positive_work_in_a_step(omega, theta, t_drive, ripple, viscous, coulomb, breakout, h):
    """Over any step: ΔE_kinetic ≤ work of the applied torque (friction only dissipates)."""
    fr = FrictionArrays(
        breakout=np.array([breakout]),
        coulomb=np.array([coulomb]),
        stribeck_w=np.array([0.5]),
        viscous=np.array([viscous]),
        ripple=np.array([ripple]),
        ripple_phase=np.array([0.3]),
    )
    J = np.array([3e-4])
    w1, dth, _ = stick_slip_step(np.array([omega]), np.array([theta]), np.array([t_drive]), J, fr, h)
    d_e = 0.5 * J[0] * (w1[0] ** 2 - omega**2)
    work_in = t_drive * dth[0]
    assert d_e <= work_in + 1e-12 * (1.0 + abs(work_in) + 0.5 * J[0] * omega**2)
    if t_drive == 0.0:
        assert abs(w1[0]) <= abs(omega) and w1[0] * omega >= 0.0


def test_stick_slip_step_is_exact_for_pure_viscous_motion():
    """No Coulomb friction: ω(t) = ω0·e^{−bt/J} + (T/b)(1 − e^{−bt/J}) exactly."""
    fr = FrictionArrays(*(np.array([v]) for v in (0.0, 0.0, 0.5, 0.01, 0.0, 0.0)))
    J, w0, tq, h = 3e-4, 5.0, 0.02, 2.5e-4
    w1, dth, tf = stick_slip_step(np.array([w0]), np.array([0.0]), np.array([tq]), np.array([J]), fr, h)
    a = 0.01 / J
    w_exact = w0 * math.exp(-a * h) + tq / 0.01 * (1 - math.exp(-a * h))
    th_exact = tq / 0.01 * h + (w0 - tq / 0.01) * (1 - math.exp(-a * h)) / a
    assert math.isclose(w1[0], w_exact, rel_tol=1e-12)
    assert math.isclose(dth[0], th_exact, rel_tol=1e-12)
    assert math.isclose(tf[0], 0.01 * w1[0], rel_tol=1e-12)


def test_reversal_inside_a_step_continues_with_the_remaining_time():
    """A large opposing torque reverses the motion within one step instead of sticking."""
    fr = FrictionArrays(*(np.array([v]) for v in (0.01, 0.01, 0.5, 0.0, 0.0, 0.0)))
    J, h = 1e-4, 1e-3
    w1, dth, _ = stick_slip_step(np.array([0.1]), np.array([0.0]), np.array([-0.05]), np.array([J]), fr, h)
    # decelerates at (0.05 + 0.01)/J, crosses at tc = 0.1·J/0.06, then accelerates at 0.04/J
    tc = 0.1 * J / 0.06
    assert math.isclose(w1[0], -(0.04 / J) * (h - tc), rel_tol=1e-9)
    assert math.isclose(dth[0], 0.5 * 0.1 * tc - 0.5 * (0.04 / J) * (h - tc) ** 2, rel_tol=1e-9)


def _paper_test(seed: int = 1):
    """0.06 Hz ±0.4 rad on joint 1 under a stiff PD loop on the encoder (the friction CLI's way)."""
    j = _j1()
    p = _plant(j, seed)
    J, N, Kt = j.inertia_at_joint(), j.gear.ratio, j.motor.kt_nm_per_a
    cpr = 4 * j.encoder.lines_per_rev
    A, f = 0.4, 0.06
    cmd = p.idle_command()
    cmd.amp_enable[0] = True
    x4 = x4_prev = 0
    rec = []
    for k in range(round(1.0 / f / T) + 2):
        t = k * T
        w = 2 * math.pi * f
        thd, wd, ad = A * math.sin(w * t), A * w * math.cos(w * t), -A * w * w * math.sin(w * t)
        th = x4 / cpr * 2 * math.pi / N
        om = (x4 - x4_prev) / cpr * 2 * math.pi / N / T
        a = ad + 400.0 * (thd - th) + 40.0 * (wd - om)
        cmd.amp_command_v[0] = J * a / (N * Kt) / j.linear_amp.gain_a_per_v
        s = p.step_period(cmd, T)
        x4_prev, x4 = x4, x4 + s.encoder[0].counts
        i_meas = (s.imon_v[0] - j.linear_amp.monitor_offset_v) / j.linear_amp.monitor_v_per_a
        rec.append((t + T, Kt * i_meas, x4 / cpr * 2 * math.pi, wd))
    r = np.array(rec)
    return running_torque_metrics(r[:, 0], r[:, 1], r[:, 2], r[:, 3], J / N**2)


def test_paper_running_torque_ripple_and_its_frequency():
    m = _paper_test()
    mean, ripple = nm_to_oz_in(m.mean_nm), nm_to_oz_in(m.ripple_amplitude_nm)
    print(f"running torque {mean:.2f} oz-in, ripple ±{ripple:.2f} oz-in at {m.ripple_frequency_hz:.2f} Hz")
    assert 22.0 <= mean <= 26.0
    assert 4.0 <= ripple <= 6.0
    assert 4.2 <= m.ripple_frequency_hz <= 5.4
    assert m.strokes >= 2
