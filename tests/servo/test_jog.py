"""servo.jog: the jog's deadman runs on its sample times (the loop's ticks), speeds are clamped to
the velocity limit, targets stop inside the soft limits. Expected values by hand: a ramp of
10 rad/s² in 10 ms ticks changes the speed by 0.1 rad/s per tick."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servo.jog import LIMIT_ALLOWANCE_DEG, JogTrajectory
from servo.trajectory import TrajectoryError

INF = np.array([np.inf])


def _jog(lo=-INF, hi=INF) -> JogTrajectory:
    return JogTrajectory(np.zeros(1), v_max=np.array([0.5]), accel=np.array([10.0]), lo=lo, hi=hi, deadman_s=0.5)


def test_a_jog_not_renewed_stops_after_its_deadman_of_sample_time():
    j = _jog()
    assert j.command({0: 1.0}) == {0: 0.5}  # clamped to the velocity limit
    for k in range(1, 60):
        s = j.sample(k * 0.01)
        if k == 50:
            assert s.omega_d[0] == pytest.approx(0.5)  # t = 0.50: still within the deadman
        if k == 51:
            assert s.omega_d[0] == pytest.approx(0.4) and j.expired  # t = 0.51: braking
    # ramp 0.1..0.5 (0.015 rad), 45 ticks at 0.5 (0.225), ramp 0.4..0 (0.010)
    assert j.theta[0] == pytest.approx(0.25)
    assert j.duration == pytest.approx(0.55) and not j.running


def test_a_renewed_jog_goes_on_and_a_command_of_zero_ends_it():
    j = _jog()
    j.command({0: 0.5})
    for k in range(1, 101):
        j.sample(k * 0.01)
        if k % 40 == 0:
            j.command({0: 0.5})  # renewed every 0.4 s
    assert j.running and j.v[0] == pytest.approx(0.5)
    j.command({0: 0.0})
    for k in range(101, 110):
        j.sample(k * 0.01)
    assert not j.running and j.duration == pytest.approx(1.05) and not j.expired


def test_the_target_stops_inside_the_soft_limit_and_comes_back_from_beyond_it():
    hi = 0.1
    j = _jog(hi=np.array([hi]))
    peak = 0.0
    for k in range(1, 400):
        if k % 20 == 1:
            j.command({0: 0.5})
        peak = max(peak, j.sample(k * 0.01).theta_d[0])
    assert peak == pytest.approx(hi - math.radians(LIMIT_ALLOWANCE_DEG))
    # a jog that starts beyond the limit (the joint was put there) may only come back
    j = JogTrajectory(np.array([0.2]), np.array([0.5]), np.array([10.0]), -INF, np.array([hi]))
    j.command({0: 0.5})
    assert all(j.sample(k * 0.01).theta_d[0] == 0.2 for k in range(1, 20))
    j.command({0: -0.5})
    assert j.sample(0.2).theta_d[0] < 0.2


def test_a_jog_toward_an_obstacle_stops_before_a_link_reaches_it():
    # the arm's default geometry (hal.kinematics): at j1 = φ, the links run radially from the
    # shoulder (0, 0, 0.30 m) out to 1.15 m. A box x 0.5..1.0, y 0.4..0.8, z 0.2..0.4: the arm first
    # touches its corner (1.0, 0.4) at φ = atan(0.4/1.0) = 21.80° (r = 1.077 m < 1.15 m)
    from hal.kinematics import ArmModel
    from servo.scene import Obstacle, Scene
    from servo.trajectory import MotionBounds

    box = Obstacle.make("box", (0.5, 0.4, 0.2), (1.0, 0.8, 0.4))
    bounds = MotionBounds(("j1", "j2", "j3", "j4", "j5", "j6", "hand"), np.full(7, -3.0), np.full(7, 3.0),
                          ArmModel(), Scene([box]))
    j = JogTrajectory(np.zeros(7), np.full(7, math.radians(20.0)), np.full(7, math.radians(400.0)),
                      np.full(7, -np.inf), np.full(7, np.inf), bounds=bounds)
    for k in range(1, 250):  # 2 s at 20°/s, renewed: it would reach 40°
        if k % 25 == 1 and j.refusal is None:
            j.command({0: math.radians(20.0)})
        theta = j.sample(k * 0.008).theta_d
        assert not bounds.collisions_at(theta), math.degrees(theta[0])
    assert j.refusal is not None and "obstacle box" in j.refusal
    assert 19.0 < math.degrees(j.theta[0]) < 21.80
    with pytest.raises(TrajectoryError, match="obstacle box"):
        j.command({0: math.radians(20.0)})
