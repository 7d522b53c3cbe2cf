"""The paper's normalized quintic point-to-point move and the stay generator."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from servo.trajectory import JointLimits, Quintic, Stay, TrajectoryError, quintic_duration

angles = st.lists(st.floats(-3.0, 3.0, allow_nan=False), min_size=3, max_size=3)
vmax = st.lists(st.floats(0.05, 2.0), min_size=3, max_size=3)


def test_endpoints_have_zero_velocity_and_acceleration():
    q = Quintic(np.array([0.0, 1.0]), np.array([1.0, -0.5]), 2.0)
    s0 = q.sample(0.0)
    np.testing.assert_array_equal(s0.theta_d, [0.0, 1.0])
    np.testing.assert_allclose(s0.omega_d, 0.0, atol=1e-15)
    np.testing.assert_allclose(s0.alpha_d, 0.0, atol=1e-15)
    # approaching the end from inside the move: velocity and acceleration go to 0 continuously
    s1 = q.sample(2.0 - 1e-6)
    np.testing.assert_allclose(s1.theta_d, [1.0, -0.5], atol=1e-12)
    np.testing.assert_allclose(s1.omega_d, 0.0, atol=1e-9)
    np.testing.assert_allclose(s1.alpha_d, 0.0, atol=1e-4)
    assert not s1.done
    s2 = q.sample(2.0)
    assert s2.done
    np.testing.assert_array_equal(s2.theta_d, [1.0, -0.5])


@settings(max_examples=60, deadline=None)
@given(start=angles, target=angles, v=vmax, speed=st.floats(0.05, 1.0))
def test_joints_finish_together_and_the_slowest_hits_its_max_velocity(start, target, v, speed):
    lim = JointLimits.make(3, v)
    start, target = np.array(start), np.array(target)
    q = Quintic.plan(start, target, lim, speed)
    delta = target - start
    if np.all(np.abs(delta) < 1e-6):
        # a negligible move is (almost) instant: at most the time the slowest joint needs for 1e-6 rad
        assert q.duration <= 1.875e-6 / (speed * np.min(lim.v_max)) * (1 + 1e-9)
        return
    T = q.duration
    # the normalized progress is the same for every moving joint at every instant
    for t in np.linspace(0, T, 7)[1:-1]:
        s = q.sample(t)
        moving = np.abs(delta) > 1e-6
        u = (s.theta_d - start)[moving] / delta[moving]
        np.testing.assert_allclose(u, u[0], rtol=1e-9, atol=1e-12)
        assert not s.done
    assert q.sample(T).done
    # peak velocity at T/2; the limiting joint sits exactly at speed·v_max, the others below
    peak = np.abs(q.sample(T / 2).omega_d)
    ratio = peak / (speed * lim.v_max)
    assert np.max(ratio) == pytest.approx(1.0, rel=1e-12)
    assert np.all(ratio <= 1.0 + 1e-12)


def test_speed_factor_scales_the_duration():
    lim = JointLimits.make(2, [0.5, 1.0])
    d = np.array([0.3, -0.9])
    t1 = quintic_duration(d, lim, 1.0)
    assert t1 == pytest.approx(1.875 * 0.9 / 1.0)
    assert quintic_duration(d, lim, 0.5) == pytest.approx(2 * t1)
    # with an acceleration limit the time scaling still holds exactly
    lim_a = JointLimits.make(2, [0.5, 1.0], [0.2, 0.2])
    ta = quintic_duration(d, lim_a, 1.0)
    assert ta == pytest.approx(np.sqrt(10 / np.sqrt(3) * 0.9 / 0.2))
    assert quintic_duration(d, lim_a, 0.25) == pytest.approx(4 * ta)
    still = Quintic.plan(np.ones(2), np.ones(2), lim)
    assert still.duration == 0.0 and still.sample(0.0).done
    with pytest.raises(TrajectoryError, match="speed factor"):
        quintic_duration(d, lim, 0.0)
    with pytest.raises(TrajectoryError, match="speed factor"):
        quintic_duration(d, lim, 1.5)


def test_velocity_and_acceleration_are_the_derivatives_of_position():
    q = Quintic(np.array([0.2]), np.array([-0.7]), 1.3)
    h = 1e-6
    for t in np.linspace(0.05, 1.25, 9):
        p0, p1 = q.sample(t - h).theta_d, q.sample(t + h).theta_d
        v0, v1 = q.sample(t - h).omega_d, q.sample(t + h).omega_d
        np.testing.assert_allclose(q.sample(t).omega_d, (p1 - p0) / (2 * h), rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose(q.sample(t).alpha_d, (v1 - v0) / (2 * h), rtol=1e-4, atol=1e-6)


def test_acceleration_limit_is_respected():
    lim = JointLimits.make(1, 10.0, 0.5)
    q = Quintic.plan(np.zeros(1), np.array([1.0]), lim)
    peak = max(abs(q.sample(t).alpha_d[0]) for t in np.linspace(0, q.duration, 2001))
    assert peak == pytest.approx(0.5, rel=1e-4)


def test_stay_holds_and_is_done():
    s = Stay(np.array([0.1, 0.2]), 3.0)
    for t in (0.0, 1.0, 10.0):
        smp = s.sample(t)
        np.testing.assert_array_equal(smp.theta_d, [0.1, 0.2])
        np.testing.assert_array_equal(smp.omega_d, 0.0)
        assert smp.done
    assert s.duration == 3.0


def test_bad_inputs():
    lim = JointLimits.make(2, 1.0)
    with pytest.raises(TrajectoryError, match="target"):
        Quintic.plan(np.zeros(2), np.zeros(3), lim)
    with pytest.raises(TrajectoryError, match="v_max"):
        JointLimits.make(2, [1.0, 0.0])
