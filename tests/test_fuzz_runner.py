"""The fuzz framework itself (tests/fuzz/harness.py, python -m tests.fuzz): an example that hangs
is stopped and reported with its harness and input, escapes and failures are counted apart,
typed refusals are counted by kind, and the runner picks up every tests/fuzz/test_*.py."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from tests.fuzz import harness
from tests.fuzz.__main__ import _targets


@pytest.fixture
def counts():
    saved = dict(harness.COUNTS)
    harness.COUNTS.clear()
    yield harness.COUNTS
    harness.COUNTS.clear()
    harness.COUNTS.update(saved)


def test_a_hanging_example_is_stopped_and_reported_with_its_input(counts) -> None:
    never = threading.Event()

    def inner(x: int) -> None:
        never.wait()  # blocks until the alarm interrupts it

    run = harness.bounded("h::hangs", inner, timeout_s=0.2)
    with pytest.raises(harness.FuzzHang):
        run(x=12345)
    c = counts["h::hangs"]
    assert c.hangs == 1 and c.examples == 1 and c.escaped == 0
    assert "x=12345" in c.first_problem and "hang" in c.first_problem


def test_escapes_failures_and_refusals_are_counted_apart(counts) -> None:
    def inner(kind: str) -> None:
        if kind == "refuse":
            harness.refused("SomeError")
        elif kind == "fail":
            raise AssertionError("property")
        elif kind == "crash":
            raise KeyError("boom")

    run = harness.bounded("h::mixed", inner, timeout_s=30.0)
    run(kind="refuse")
    run(kind="ok")
    with pytest.raises(AssertionError):
        run(kind="fail")
    with pytest.raises(KeyError):
        run(kind="crash")
    c = counts["h::mixed"]
    assert (c.examples, c.escaped, c.failed, c.hangs) == (4, 1, 1, 0)
    assert c.refused == {"SomeError": 1}
    assert "property" in c.first_problem


def test_the_runner_takes_every_harness_file_or_the_ones_named() -> None:
    every = _targets([])
    files = sorted(p.name for p in (Path(__file__).parent / "fuzz").glob("test_*.py"))
    assert sorted(Path(t).name for t in every) == files and len(files) >= 4
    assert _targets(["console_lines"]) == ["tests/fuzz/test_console_lines.py"]
    with pytest.raises(SystemExit, match="no harness 'nope'"):
        _targets(["nope"])
