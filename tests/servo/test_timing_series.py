"""The real-time runner's per-tick timing series stay memory-flat on long runs: a preallocated
ring of the newest values, with the count and the maximum over all of them."""

from __future__ import annotations

import numpy as np

from servo.runner import TickSeries, TimingStats


def test_a_short_series_keeps_every_value_like_a_list() -> None:
    s = TickSeries(capacity=8)
    for x in (3.0, 1.0, 2.0):
        s.append(x)
    assert len(s) == 3 and s.total == 3 and s.peak == 3.0
    np.testing.assert_array_equal(s.values(), [3.0, 1.0, 2.0])


def test_a_long_series_keeps_its_newest_values_in_order_and_the_overall_max() -> None:
    s = TickSeries(capacity=4)
    for x in [100.0, *range(10)]:
        s.append(float(x))
    assert len(s) == 4 and s.total == 11 and s.peak == 100.0
    np.testing.assert_array_equal(s.values(), [6.0, 7.0, 8.0, 9.0])
    buf = s._a
    s.append(1.0)
    assert s._a is buf  # the storage never grows
    s.clear()
    assert len(s) == 0 and s.total == 0 and s.values().size == 0


def test_summary_counts_every_tick_and_reports_the_overall_max() -> None:
    t = TimingStats(*(TickSeries(capacity=10) for _ in range(2)))
    for i in range(25):
        t.compute_s.append(0.001 if i else 0.05)  # the slow tick is no longer in the ring
        t.lateness_s.append(0.0)
    s = t.summary(0.008)
    assert s["ticks"] == 25
    assert s["compute_max_ms"] == 50.0 and s["compute_p50_ms"] == 1.0
