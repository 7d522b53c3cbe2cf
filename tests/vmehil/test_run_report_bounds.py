"""A run report says when a long run outgrew the recorder or the change log; a run within the
bounds reports exactly as before (no extra keys)."""

from __future__ import annotations

import pytest

from servo.control.normalize import unit_chain
from servo.control.objects import build_controller
from servo.loop import Recorder, ServoLoop
from servo.motion import WaitMove
from servo.trajectory import JointLimits
from tests.support.fakes import (
    DoubleIntegrator,
    DoubleIntegratorLockstepRunner,
    _started_loop,
    fake_loop,
)
from vmehil.reports.run_report import summarize, table


def _report(loop) -> dict:
    return summarize(loop, rig="fake", seed=0, realtime=False, overruns=0)


def test_a_run_within_the_bounds_reports_no_extra_keys() -> None:
    loop, _, runner = fake_loop(2, n_ticks=200)
    loop.note("api", "a change")
    runner.run(200)
    out = _report(loop)
    assert "recorded" not in out and "changes_dropped" not in out and len(out["changes"]) == 1


def test_a_run_past_the_bounds_says_what_was_kept(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ServoLoop, "LOG_MAX", 3)
    loop, _, runner = fake_loop(2, n_ticks=200)
    loop.recorder = Recorder(200, 2, max_rows=50)
    for i in range(5):
        loop.note("api", f"change {i}")
    runner.run(200)
    out = _report(loop)
    assert out["changes_dropped"] == 2 and [c["change"] for c in out["changes"]] == ["change 2", "change 3", "change 4"]
    assert out["recorded"]["ticks_kept"] == 50 and out["recorded"]["ticks_dropped"] == 150
    assert out["recorded"]["from_s"] == pytest.approx(150 * loop.period_s)


def test_a_run_without_moves_reports_no_tracking_error_and_the_table_names_both_errors() -> None:
    # `--motion none`: "max track err" was the first sample's error (0.002–0.07°) beside a final
    # error of 0.25–0.46°, and read as a contradiction
    io = DoubleIntegrator(2, 0.008)
    controller = build_controller({"objects": ["pid"]}, unit_chain(2), 0.008)
    loop = _started_loop(io, controller, [WaitMove(1.0)], JointLimits.make(2, 0.5), 0.5, recorder=Recorder(100, 2))
    DoubleIntegratorLockstepRunner(loop, io).run(100)
    out = _report(loop)
    assert [j["max_tracking_error_deg"] for j in out["joints"]] == [None, None]
    head = table(out).splitlines()[2]
    assert "err at end °" in head and "max err in moves °" in head


def test_a_fault_of_no_joint_is_printed_without_a_joint_and_every_fault_is_listed() -> None:
    # "fault: overrun at 1.680 s (None)"; and a run with two stops (a resume between) listed one
    loop, _, runner = fake_loop(2, n_ticks=100)
    runner.run(10)
    loop.safe_stop("overrun", "tick 10 took 9.1 ms")
    loop.resume()
    runner.run(10)
    loop.safe_stop("following_error", "0.6 rad", joint=1)
    out = _report(loop)
    assert [(f["cause"], f["joint"]) for f in out["faults"]] == [("overrun", None), ("following_error", "j2")]
    text = table(out)
    assert "fault: overrun at 0.080 s: tick 10 took 9.1 ms" in text and "(None)" not in text
    assert "fault: following_error at 0.160 s (j2): 0.6 rad" in text
