"""run_parallel's hooks for the tools' speed: the caller's own work beside the tasks
(``meanwhile``), a periodic ``on_idle``, every task told to stop when the caller fails; and the
sweep's batched result writes (at most one per interval, none lost)."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest

from vmehil.analysis.parallel import run_parallel
from vmehil.analysis.sweep import BatchedWrites

_started = threading.Event()
_caller_done = threading.Event()


def _waits_for_the_caller(i: int) -> tuple[int, bool]:
    _started.set()
    return i, _caller_done.wait(timeout=60)  # the condition, with a generous bound


def test_meanwhile_runs_while_the_tasks_run() -> None:
    """A task that can only finish once the caller's ``meanwhile`` ran proves they overlap."""
    _started.clear()
    _caller_done.clear()
    seen: list[bool] = []

    def meanwhile() -> None:
        seen.append(_started.wait(timeout=60))  # the task is running while the caller works
        _caller_done.set()

    with ThreadPoolExecutor(1) as ex:
        out = run_parallel(_waits_for_the_caller, [7], executor=ex, meanwhile=meanwhile)
    assert seen == [True]
    assert out == [(7, True)]


class _Engine:
    """An engine whose one task never finishes by itself: only ``interrupt`` ends it."""

    name = "fake"

    def __init__(self) -> None:
        self.calls: list[str] = []

    def start(self, fn: Any, items: list[Any]) -> None:
        self.calls.append("start")

    def pending(self) -> int:
        return 0 if "interrupt" in self.calls else 1

    def completed(self, timeout: float) -> list[tuple[int, Any]]:
        return []

    def interrupt(self) -> None:
        self.calls.append("interrupt")

    def close(self) -> None:
        self.calls.append("close")


def test_an_error_of_the_caller_stops_the_running_tasks() -> None:
    engine = _Engine()

    def meanwhile() -> None:
        raise RuntimeError("prediction failed")

    with pytest.raises(RuntimeError, match="prediction failed"):
        run_parallel(abs, [1], engine=engine, meanwhile=meanwhile)
    assert engine.calls == ["start", "interrupt", "close"]


def test_on_idle_is_called_while_tasks_run() -> None:
    engine = _Engine()
    idles: list[int] = []

    def on_idle() -> None:
        idles.append(1)
        if len(idles) == 3:
            engine.interrupt()  # ends the fake task

    run_parallel(abs, [1], engine=engine, on_idle=on_idle)
    assert len(idles) == 3


class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_batched_writes_write_at_most_once_per_interval_and_lose_no_row() -> None:
    clock = _Clock()
    written: list[int] = []
    batch = BatchedWrites(lambda rows: written.append(len(rows)), every_s=1.0, clock=clock)
    rows: list[dict[str, Any]] = []
    for i in range(5):  # five points within 0.4 s: not written yet
        rows = [*rows, {"index": i}]
        batch.result(rows)
        clock.t += 0.1
    assert written == []
    batch.idle()  # 0.5 s after the start: still not due
    assert written == []
    clock.t += 0.6
    batch.idle()  # a second after the last write: the waiting rows go out though no point ended
    assert written == [5]
    batch.idle()
    assert written == [5]  # nothing waits: no rewrite
    rows = [*rows, {"index": 5}]
    batch.result(rows)  # less than a second after the last write
    assert written == [5]
    batch.flush()  # the end (or an error): what waits is written at once
    assert written == [5, 6]
    batch.flush()
    assert written == [5, 6] and batch.writes == 2
