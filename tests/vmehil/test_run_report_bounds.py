"""A run report says when a long run outgrew the recorder or the change log; a run within the
bounds reports exactly as before (no extra keys)."""

from __future__ import annotations

import pytest

from servo.loop import Recorder, ServoLoop
from tests.support.fakes import fake_loop
from vmehil.run_report import summarize


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
