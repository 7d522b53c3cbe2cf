"""Long runs stay memory-flat: the recorder keeps its last ``max_rows`` ticks in a ring and the
loop's change log keeps its newest ``LOG_MAX`` notes — while a run within the bounds records
exactly what it always did."""

from __future__ import annotations

import numpy as np
import pytest

from servo.loop import Recorder, ServoLoop
from tests.support.fakes import fake_loop


def test_a_run_within_max_rows_records_every_tick_in_order() -> None:
    a, _, ra = fake_loop(2, n_ticks=300)
    a.recorder = Recorder(300, 2, max_rows=None)
    b, _, rb = fake_loop(2, n_ticks=300)  # the default bound (2**15 rows) is far above 300
    ra.run(300)
    rb.run(300)
    ta, tb = a.recorder.trimmed(), b.recorder.trimmed()
    assert b.recorder.rows == 300 and b.recorder.dropped == 0
    assert ta.keys() == tb.keys()
    for k in ta.keys() - {"compute_s"}:
        np.testing.assert_array_equal(ta[k], tb[k])
    assert len(tb["t"]) == 300 and np.all(np.diff(tb["t"]) > 0)


def test_a_run_past_max_rows_keeps_its_last_ticks_in_time_order() -> None:
    full, _, rf = fake_loop(2, n_ticks=500)
    full.recorder = Recorder(500, 2, max_rows=None)
    ring, _, rr = fake_loop(2, n_ticks=500)
    ring.recorder = Recorder(500, 2, max_rows=128)
    rf.run(500)
    rr.run(500)
    rec = ring.recorder
    assert rec.rows == 128 and rec.count == 500 and rec.dropped == 500 - 128
    assert all(v.shape[0] == 128 for v in rec.data.values())  # the arrays never grew
    kept, every = rec.trimmed(), full.recorder.trimmed()
    for k in every.keys() - {"compute_s"}:  # compute_s is wall-clock time, different in every run
        np.testing.assert_array_equal(kept[k], every[k][-128:])
    assert np.all(np.isfinite(kept["compute_s"]))
    assert np.all(np.diff(kept["t"]) > 0)


def test_ticks_beyond_n_ticks_are_ignored_as_before() -> None:
    rec = Recorder(4, 1, max_rows=2)
    for k in range(6):
        rec.put(k, t=float(k))
    assert rec.count == 4
    np.testing.assert_array_equal(rec.trimmed()["t"], [2.0, 3.0])


@pytest.mark.parametrize("bad", [0, -3])
def test_a_recorder_bound_below_one_row_is_refused(bad: int) -> None:
    with pytest.raises(ValueError, match="max_rows"):
        Recorder(10, 1, max_rows=bad)


def test_the_change_log_keeps_its_newest_notes_and_counts_the_dropped(monkeypatch) -> None:
    monkeypatch.setattr(ServoLoop, "LOG_MAX", 5)
    loop, _, runner = fake_loop(2)
    for i in range(12):
        loop.note("api", f"change {i}")
        runner.tick()
    assert [m for _, _, m in loop.log] == [f"change {i}" for i in range(7, 12)]
    assert loop.log_dropped == 7
    times = [t for t, _, _ in loop.log]
    assert times == sorted(times)
