"""ServoLoop.resume(): a safe-stopped loop servos again, holding where the joints are, with the
watchdog's memory and the integrators of before the stop forgotten."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servo.stops import HoldingLoad, StopSettings
from servo.trajectory import JointLimits, PlanContext, Sequencer
from tests.support.fakes import make_loop, tick


def test_safe_stopped_loop_resumes_and_holds_the_measured_position():
    loop = make_loop(2)
    tick(loop, n=20)
    loop.safe_stop("operator_stop", "test")
    assert not loop.enabled and not loop.io.enabled
    # the joints move while stopped: far more than the watchdog's one-tick jump limit
    loop.io.theta = np.array([0.5, -0.4])
    held = loop.resume()
    assert loop.fault is None and loop.enabled and loop.io.enabled
    np.testing.assert_allclose(held, [0.5, -0.4])
    np.testing.assert_allclose(loop.sequencer.current.end, [0.5, -0.4])
    tick(loop, n=250)
    assert loop.fault is None, loop.fault
    np.testing.assert_allclose(loop.last["theta"], [0.5, -0.4], atol=1e-6)
    np.testing.assert_allclose(loop.last["theta_d"], [0.5, -0.4])


def test_resume_forgets_the_watchdog_memory_and_the_integrators():
    loop = make_loop(1)
    loop.set_motion(Sequencer([], np.array([0.01]), loop.plan_context))
    tick(loop, n=100)  # integrators build up while the joint settles
    assert np.any(loop.law.state.ie != 0.0) and np.all(np.isfinite(loop.law.state.e_prev))
    loop.safe_stop("operator_stop", "test")
    loop.cross_checks._stale_count[:] = 99
    loop.io.theta = np.array([0.3])
    loop.resume()
    assert loop._last_theta is None and not loop.cross_checks._stale_count.any()
    state = loop.law.export_state()
    assert not state.ie.any() and not state.iv.any() and np.all(np.isnan(state.e_prev))
    tick(loop)
    assert loop.fault is None  # no 0.29 rad "jump" against the position from before the stop


def test_resume_without_hold_keeps_the_target_and_a_failed_read_changes_nothing():
    loop = make_loop(1)
    loop.set_motion(Sequencer([], np.array([0.2]), loop.plan_context))
    loop.safe_stop("operator_stop", "test")
    loop.io.read_error = OSError("bus error")
    with pytest.raises(OSError):
        loop.resume()
    assert loop.fault is not None and loop.fault.cause == "operator_stop" and not loop.enabled
    loop.io.read_error = None
    assert loop.resume(hold_measured=False) is None
    np.testing.assert_allclose(loop.sequencer.current.end, [0.2])
    assert loop.enabled and loop.fault is None


def test_resume_that_cannot_enable_stops_again():
    loop = make_loop(1)
    loop.safe_stop("operator_stop", "test")

    def broken(on=True):
        raise OSError("amplifier enable line stuck")

    loop.io.enable = broken
    with pytest.raises(OSError):
        loop.resume()
    assert not loop.enabled and loop.fault is not None and loop.fault.cause == "driver_error"
    assert "amplifier enable line stuck" in loop.fault.detail


def test_resume_plans_with_the_loops_plan_context_else_the_sequencers():
    loop = make_loop(1)
    assert loop.vision is None
    slow = PlanContext(JointLimits.make(1, 0.1))
    loop.plan_context = slow
    loop.safe_stop("operator_stop", "test")
    loop.resume()
    assert loop.sequencer.ctx is slow
    loop.plan_context = None
    loop.safe_stop("operator_stop", "test")
    loop.resume()
    assert loop.sequencer.ctx is slow  # the sequencer's own, carried on


def test_resume_starts_each_joint_at_its_stated_holding_load_where_it_is_held():
    # joint 0 states a gravity load of 9 N·m (cos θ); held at 60° it needs 9·cos 60° = 4.5 N·m.
    # Joint 1 states none and (a fake JointIO) has no torque from the stop: it starts at 0.
    loop = make_loop(2)
    loop.stop_settings = StopSettings(decel_rad_s2=(1.0, 1.0),
                                      load=HoldingLoad(gravity_nm=(9.0, math.nan), phase_rad=(0.0, 0.0)))
    tick(loop, n=5)
    loop.safe_stop("estop", "test")
    loop.io.theta = np.array([math.radians(60.0), 0.2])  # where the brakes held the joints
    loop.resume()
    loop.tick()  # zero error, at rest: the law's output is its preload alone
    np.testing.assert_allclose(loop.io.torque, [4.5, 0.0], atol=1e-9)
