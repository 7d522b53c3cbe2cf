"""Holding brakes in the plant (issue #29), on both integration paths (numpy and the compiled
kernel): a spring-applied, power-released brake on the motor shaft with a holding torque,
engage and release delays, slip beyond the holding torque, and its line dropped by the enable
watchdog. Expected values are hand calculations from the parameters (stated at each test).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from emulators.plant import (
    FrictionParams,
    GearParams,
    HoldingBrakeParams,
    JointParams,
    LinkParams,
    MotorParams,
    Plant,
    PlantParams,
    load_plant_params,
)
from emulators.plant.amplifier import WATCHDOG_EXPIRED
from hal.config import ConfigError

T = 0.008  # servo period (s)
KERNELS = ("numpy", "numba")
GRAVITY_JOINTS = ("j2", "j3", "j4", "j6")  # jpl-arm's gravity-loaded joints (the preset's brakes)


def _jpl(kernel: str, *, brakes: bool = True) -> Plant:
    params = load_plant_params("jpl-arm")
    if not brakes:
        for j in params.joints:
            j.holding_brake = HoldingBrakeParams()
    return Plant(params, seed=0, kernel=kernel)


def _run(p: Plant, periods: int, line: bool, delay_s: float = 0.0) -> np.ndarray:
    """Amplifiers off, every brake line at ``line``; returns the true joint angles per period."""
    cmd = p.idle_command()
    cmd.holding_brake[:] = line
    return np.array([p.step_period(cmd, T, delay_s).truth["theta_joint"].copy() for _ in range(periods)])


@pytest.mark.parametrize("kernel", KERNELS)
def test_an_engaged_brake_holds_a_gravity_loaded_joint_with_the_amplifiers_off(kernel: str) -> None:
    # 2 s of simulated time, power off. Holding torque 2 × gravity (18, 8, 2, 0.6 N·m) > the load:
    # the brakes hold (< 1°); without them each joint falls (its gravity exceeds N·T_s: j3 4 N·m
    # against 80 · 0.0135 · (1 ± 0.2) ≤ 1.3 N·m, etc.).
    held, fell = _jpl(kernel), _jpl(kernel, brakes=False)
    idx = [held.index_of(n) for n in GRAVITY_JOINTS]
    th0 = held.joint_angle()[idx]
    a = _run(held, 250, line=False)[:, idx]
    b = _run(fell, 250, line=False)[:, idx]
    moved_held = np.degrees(np.max(np.abs(a - th0), axis=0))
    moved_free = np.degrees(np.max(np.abs(b - th0), axis=0))
    assert np.all(moved_held < 1.0), moved_held
    assert np.all(moved_free > 5.0), moved_free  # the difference the brakes make


def _one_joint(kernel: str, *, hold_nm: float = 10.0, engage_s: float = 0.04, release_s: float = 0.06) -> Plant:
    # A frictionless rigid joint: N = 100, rotor 1e-4 kg·m², link 1 kg·m² → J at the joint
    # 1e-4 · 100² + 1 = 2 kg·m²; a brake of ``hold_nm`` at the joint (hold_nm/100 at the motor).
    j = JointParams(
        name="j", motor=MotorParams(rotor_inertia_kg_m2=1e-4), gear=GearParams(ratio=100.0),
        friction=FrictionParams(breakout_nm=0.0, coulomb_nm=0.0, viscous_nm_s_per_rad=0.0, ripple_fraction=0.0),
        link=LinkParams(inertia_kg_m2=1.0, lower_stop_rad=-100.0, upper_stop_rad=100.0),
        holding_brake=HoldingBrakeParams(present=True, holding_torque_nm=hold_nm, engage_delay_s=engage_s,
                                         release_delay_s=release_s),
    )
    j.tach.present = False
    return Plant(PlantParams(joints=[j]), seed=1, kernel=kernel)


@pytest.mark.parametrize("kernel", KERNELS)
def test_a_load_below_the_holding_torque_is_held_and_one_above_slips_at_the_holding_torque(kernel: str) -> None:
    below = _one_joint(kernel)
    below.set_external_torque(np.array([9.9]))  # < 10 N·m: held exactly
    assert np.all(_run(below, 125, line=False) == 0.0)
    above = _one_joint(kernel)
    above.set_external_torque(np.array([14.0]))  # slips: α = (14 − 10)/2 = 2 rad/s²
    theta = _run(above, 125, line=False)  # 1 s: θ = ½·2·1² = 1 rad, ω = 2 rad/s
    assert theta[-1, 0] == pytest.approx(1.0, rel=1e-9)
    assert above.joint_speed()[0] == pytest.approx(2.0, rel=1e-9)


@pytest.mark.parametrize("kernel", KERNELS)
def test_the_brake_releases_its_release_delay_after_the_line_rises_and_engages_its_engage_delay_after_it_drops(
        kernel: str) -> None:
    # 8 N·m pushes the joint (J = 2 kg·m²), the brake holds 10 N·m. The line rises at t = 0: free
    # from 0.06 s, α = 4 rad/s². It drops at t = 0.2 s: engaged from 0.24 s, where ω = 4·0.18 =
    # 0.72 rad/s; then the brake's 10 N·m decelerates it at (10 − 8)/2 = 1 rad/s² until it stops
    # at 0.96 s and holds.
    p = _one_joint(kernel)
    p.set_external_torque(np.array([8.0]))
    cmd = p.idle_command()
    cmd.holding_brake[:] = True
    omega, engaged = [], []
    for k in range(150):
        if k == 25:  # the period starting at 0.2 s (no computation delay: the line changes at its start)
            cmd.holding_brake[:] = False
        s = p.step_period(cmd, T, 0.0)
        omega.append(float(s.truth["omega_joint"][0]))
        engaged.append(bool(s.truth["brake_engaged"][0]))
    t_end = T * (np.arange(150) + 1)  # each period's end
    assert omega[6] == 0.0 and engaged[6]  # 0.056 s: still held
    assert omega[7] == pytest.approx(4.0 * (0.064 - 0.06), rel=1e-6) and not engaged[7]
    assert omega[29] == pytest.approx(0.72, rel=1e-9)  # 0.24 s: the brake engages now (period 30's start)
    assert engaged[30] and not engaged[29]
    assert omega[30] == pytest.approx(0.72 - 1.0 * (t_end[30] - 0.24), rel=1e-9)
    assert omega[-1] == 0.0 and engaged[-1]  # stopped (at 0.96 s) and held


@pytest.mark.parametrize("kernel", KERNELS)
def test_a_line_that_returns_before_the_armature_moved_cancels_the_move(kernel: str) -> None:
    p = _one_joint(kernel)
    p.set_external_torque(np.array([8.0]))
    cmd = p.idle_command()
    cmd.holding_brake[:] = True
    for _ in range(4):  # 32 ms < the 60 ms release delay
        p.step_period(cmd, T, 0.0)
    cmd.holding_brake[:] = False
    theta = [p.step_period(cmd, T, 0.0).truth["theta_joint"][0] for _ in range(20)]
    assert np.all(np.array(theta) == 0.0) and p.brakes_engaged()[0]


@pytest.mark.parametrize("kernel", KERNELS)
def test_the_enable_watchdog_drops_the_brake_lines_when_the_controller_stops_toggling(kernel: str) -> None:
    # jpl-arm with its 50 ms enable watchdog: amplifiers enabled at 0 V, brake lines high, the line
    # toggled every period → brakes released after 60 ms. The toggling stops: 50 ms after the
    # last edge the pump is out, every line drops and the brakes hold 40 ms later, enables and
    # lines still high in the command.
    params = load_plant_params("jpl-arm")
    params.watchdog_timeout_s = 0.05
    p = Plant(params, seed=0, kernel=kernel)
    braked = np.array([j.holding_brake.present for j in params.joints])
    cmd = p.idle_command()
    cmd.amp_enable[:] = True
    cmd.holding_brake[:] = True
    for _ in range(20):
        cmd.watchdog_line = not cmd.watchdog_line
        s = p.step_period(cmd, T, 0.001)
    assert not s.truth["brake_engaged"].any()
    last_edge = 19 * T + 0.001
    engaged_at = []
    for _ in range(20, 40):
        s = p.step_period(cmd, T, 0.001)
        engaged_at.append(bool(s.truth["brake_engaged"][braked].all()))
        assert np.array_equal(s.truth["brake_engaged"][~braked], np.zeros(int((~braked).sum()), bool))
    # pump out at last_edge + 0.05 = 0.203 s, brakes hold from 0.243 s: the period ending 0.248 s
    first = 20 + engaged_at.index(True)
    assert (first + 1) * T == pytest.approx(math.ceil((last_edge + 0.05 + 0.04) / T) * T)
    assert (s.truth["amp_watchdog_cause"] == WATCHDOG_EXPIRED).all()


@pytest.mark.parametrize("kernel", KERNELS)
def test_the_plant_nodes_command_timeout_engages_every_brake_at_once(kernel: str) -> None:
    p = _jpl(kernel)
    cmd = p.idle_command()
    cmd.amp_enable[:] = True
    cmd.holding_brake[:] = True
    for _ in range(10):
        p.step_period(cmd, T, 0.001)
    braked = p.brakes.present
    assert not p.brakes_engaged().any()
    p.hold_amplifiers_off(2)
    assert np.array_equal(p.brakes_engaged(), braked)
    s = p.step_period(cmd, T, 0.001)  # the controller back, its lines high: the latched stay held
    assert np.array_equal(s.truth["brake_engaged"], braked)


def test_both_paths_agree_through_release_fall_and_engage() -> None:
    out = []
    for kernel in KERNELS:
        p = _jpl(kernel)
        cmd = p.idle_command()
        cmd.holding_brake[:] = True
        th = []
        for k in range(60):
            if k == 20:
                cmd.holding_brake[:] = False
            th.append(p.step_period(cmd, T, 0.001).truth["theta_joint"].copy())
        out.append(np.array(th))
    assert np.ptp(out[0], axis=0).max() > 0.005  # the joints fell between release and engage
    np.testing.assert_allclose(out[0], out[1], rtol=0, atol=1e-12)


def test_a_brake_without_a_holding_torque_is_refused() -> None:
    from emulators.plant import plant_params_from_config
    from hal.config import ConfigTable

    cfg = ConfigTable({"joint": [{"name": "j", "holding_brake": {"present": True}}]}, "rig.toml")
    with pytest.raises(ConfigError, match="holding_torque_nm"):
        plant_params_from_config(cfg)
    cfg = ConfigTable({"joint": [{"name": "j", "holding_brake": {"present": True, "holding_torque_nm": 2.0,
                                                                  "engage_delay_s": 0.04, "slip": 1.0}}]}, "rig.toml")
    with pytest.raises(ConfigError, match="slip"):
        plant_params_from_config(cfg)
