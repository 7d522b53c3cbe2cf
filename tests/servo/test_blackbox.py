"""The black box's ring (servo.blackbox): what it keeps, in what order, and when it freezes.

Expected values are written from the module's contract (seconds before the stop, 2 s after the
power went off, then frozen until powered again), by hand for a 0.1 s period."""

from __future__ import annotations

import numpy as np
import pytest

from servo.blackbox import HOLDING, JOINT_SIGNALS, RUNNING, STOPPED, BlackBox

PERIOD = 0.1  # s: 10 rows a second keeps the hand counts small


def _put(box: BlackBox, k: int, state: int = RUNNING, *, theta: float | None = None, enabled: bool = True,
         stop_tick: int | None = None) -> None:
    n = box.n
    row = {} if theta is None else {"theta": np.array([theta, -theta][:n]), "theta_d": np.ones(n)}
    box.put(k, k * PERIOD, row, state, integrator_e=np.array([0.5, 0.25][:n]), integrator_v=None,
            enabled=enabled, brake_released=np.array([True, False][:n]), amp_fault=None, stop_tick=stop_tick)


def test_the_ring_holds_the_newest_seconds_plus_after_in_time_order():
    box = BlackBox(2, PERIOD, ["a", "b"], seconds=1.0, after_s=0.5)
    assert box.capacity == 15  # (1.0 + 0.5) s / 0.1 s
    for k in range(40):
        _put(box, k, theta=float(k))
    snap = box.snapshot()
    assert snap.tick.tolist() == list(range(25, 40))
    assert snap.t[0] == pytest.approx(2.5) and snap.t[-1] == pytest.approx(3.9)
    assert snap.signal("position_rad")[:, 0].tolist() == [float(k) for k in range(25, 40)]
    assert snap.signal("position_rad")[:, 1].tolist() == [-float(k) for k in range(25, 40)]


def test_error_is_target_minus_position_and_absent_values_are_nan():
    box = BlackBox(2, PERIOD, ["a", "b"], seconds=1.0)
    _put(box, 0, theta=0.25)
    _put(box, 1)  # a tick with no reading (a sensor that no longer answers)
    snap = box.snapshot()
    assert snap.signal("error_rad")[0].tolist() == [0.75, 1.25]
    assert np.isnan(snap.signal("position_rad")[1]).all() and np.isnan(snap.signal("error_rad")[1]).all()
    assert snap.signal("integral_e")[0].tolist() == [0.5, 0.25]
    assert np.isnan(snap.signal("integral_edot_rad")[0]).all()  # not given
    assert snap.signal("brake_released")[0].tolist() == [1.0, 0.0]
    assert snap.signal("amp_enable")[0].tolist() == [1.0, 1.0]
    assert snap.joints.shape == (2, len(JOINT_SIGNALS), 2)


def test_it_freezes_after_the_power_was_off_for_after_s_and_records_again_when_powered():
    box = BlackBox(1, PERIOD, ["a"], seconds=1.0, after_s=0.3)
    for k in range(5):
        _put(box, k)
    for k in range(5, 20):  # power off from tick 5: kept are ticks 5..8 (0.3 s after the first off tick)
        _put(box, k, STOPPED, enabled=False, stop_tick=5)
    snap = box.snapshot()
    assert snap.tick.tolist() == list(range(0, 9))
    assert snap.stop_state.tolist() == [RUNNING] * 5 + [STOPPED] * 4
    assert snap.stop_tick == 5 and snap.seconds_before_stop == pytest.approx(0.5)
    assert box.frozen
    _put(box, 20, HOLDING)  # powered again (a resume): recording goes on
    assert box.snapshot().tick.tolist()[-2:] == [8, 20] and not box.frozen


def test_a_box_of_no_seconds_is_refused():
    with pytest.raises(ValueError, match="positive"):
        BlackBox(1, PERIOD, ["a"], seconds=0.0)
