"""A worker's result is checked against the point it was computed for (sweep.check_row), and no
finished row is lost when one is refused or a task fails (#30 item 13: a worker that rewrote every
row to index 0 gave exit 0 with 1 row of 4; a row that was a string lost every finished row)."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest

from vmehil.analysis.parallel import TaskFailed
from vmehil.analysis.sweep import SweepResultError, SweepTask, check_row, evaluate_points

GAINS = {"kp": 100.0, "kpi": 5000.0, "kv": 50.0, "kvi": 1000.0}


def _task(i: int) -> SweepTask:
    return SweepTask(i, "jpl-arm", 1, {**GAINS, "kp": 80.0 + 10 * i}, simulate=False)


def _row(i: int) -> dict[str, Any]:
    """The row a margins-only point makes (the columns of docs/sweeps.md, written out by hand)."""
    return {"index": i, "kp": 80.0 + 10 * i, "kpi": 5000.0, "kv": 50.0, "kvi": 1000.0, "status": "margins only",
            "stable": True, "unstable_reason": None, "sampled_stable": True, "phase_margin_deg": 83.6,
            "gain_margin_db": 16.95, "crossover_hz": 7.17, "bandwidth_hz": 1.04, "continuous_phase_margin_deg": 95.3,
            "lc_amplitude_deg": None, "lc_frequency_hz": None, "lc_amplitude_pot_deg": None,
            "rms_tracking_error_deg": None, "max_tracking_error_deg": None, "max_tracking_error_true_deg": None,
            "settling_time_s": None, "final_error_deg": None, "fault": None, "wall_s": 0.1, "switch_off": False,
            "sample": None}


class Scripted:
    """An engine whose tasks 'complete' with the given results, all in one batch."""

    name = "scripted"

    def __init__(self, results: dict[int, Any]) -> None:
        self.results = results
        self.left = True
        self.interrupted = False

    def start(self, fn, items) -> None:
        pass

    def pending(self) -> int:
        return int(self.left)

    def completed(self, timeout: float) -> list[tuple[int, Any]]:
        self.left = False
        return sorted(self.results.items())

    def interrupt(self) -> None:
        self.interrupted = True

    def close(self) -> None:
        pass


def test_a_valid_row_is_accepted_as_it_is() -> None:
    row = _row(2)
    assert check_row(row, _task(2)) is row


def test_a_worker_that_gives_every_row_index_0_stops_the_sweep_keeping_the_true_rows() -> None:
    seen: list[int] = []
    bad = {**_row(1), "index": 0}
    engine = Scripted({0: _row(0), 1: bad, 2: _row(2), 3: _row(3)})
    with pytest.raises(SweepResultError, match="point 1 was refused: index = 0, but the point has 1"):
        evaluate_points([_task(i) for i in range(4)], engine=engine,
                        on_result=lambda row, rows: seen.append(row["index"]))
    assert seen == [0, 2, 3] and engine.interrupted


@pytest.mark.parametrize(("change", "why"), [
    (lambda r: {**r, "index": 99}, "index = 99"),
    (lambda r: {**r, "phase_margin_deg": math.nan}, "phase_margin_deg = nan is not a finite number"),
    (lambda r: {**r, "gain_margin_db": math.inf}, "gain_margin_db = inf is not a finite number"),
    (lambda r: {**r, "kp": -1e308}, "kp = -1e+308, but the point has 100.0"),
    (lambda r: "ok", "not a row but a str"),
    (lambda r: {k: v for k, v in r.items() if k != "status"}, "missing status"),
    (lambda r: {**r, "status": None}, "status = None is not a text"),
    (lambda r: {**r, "lc_amplitude_deg": -1.0}, "lc_amplitude_deg = -1.0 is negative"),
    (lambda r: {**r, "stable": "yes"}, "stable = 'yes' is not true/false"),
    (lambda r: {**r, "extra": 1}, "unknown extra"),
])
def test_a_rewritten_row_is_refused_saying_why(change, why) -> None:
    with pytest.raises(SweepResultError) as e:
        check_row(change(_row(2)), _task(2))
    assert why in str(e.value)


def test_a_task_that_raised_loses_none_of_the_rows_of_its_batch() -> None:
    seen: list[int] = []
    engine = Scripted({0: _row(0), 1: TaskFailed(ZeroDivisionError("in the worker")), 2: _row(2)})
    with pytest.raises(ZeroDivisionError):
        evaluate_points([_task(i) for i in range(3)], engine=engine,
                        on_result=lambda row, rows: seen.append(row["index"]))
    assert seen == [0, 2]


def _rewriting_point(task: SweepTask) -> dict[str, Any]:
    """A worker that rewrites rows: point 0 is true, every later one claims index 0."""
    return {**_row(task.index), "kp": task.gains["kp"], "kpi": task.gains["kpi"], "kv": task.gains["kv"],
            "kvi": task.gains["kvi"], "index": 0}


def test_tune_sweep_refuses_a_rewritten_row_with_exit_1_keeping_the_finished_rows(tmp_path, monkeypatch,
                                                                                     capsys) -> None:
    import vmehil.analysis.sweep as sweep
    from vmehil import cli

    monkeypatch.setattr(sweep, "evaluate_point", _rewriting_point)  # the forked worker has it too
    out = tmp_path / "s"
    code = cli.main(["tune", "sweep", "--grid", "kp=80;90;100;110", "--margins-only", "--jobs", "1", "--quiet",
                     "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1, err
    assert "was refused: index = 0, but the point has 1" in err and "--resume" in err
    stored = json.loads((out / "sweep.json").read_text())
    assert [r["index"] for r in stored["rows"]] == [0] and not stored["finished"]


class UnpicklableError(Exception):
    """Pickles, but does not unpickle as an exception (a worker-side object of a preload, say):
    what made Dask's client handler assert and the sweep wait forever (#30 item 12)."""

    def __init__(self, what: str, code: int) -> None:
        super().__init__(f"{what} ({code})")

    def __reduce__(self):
        return (str, ("not an exception",))


def _raises(_item: int) -> None:
    try:
        raise KeyError("the cause")
    except KeyError as e:
        raise UnpicklableError("the plant diverged", 7) from e


def test_a_task_error_travels_to_the_client_as_plain_text_only() -> None:
    import pickle

    from vmehil.analysis.dask_engine import call_with_plain_errors
    from vmehil.analysis.parallel import EngineError

    assert call_with_plain_errors(lambda i: i + 1, 1) == 2
    with pytest.raises(EngineError) as e:
        call_with_plain_errors(_raises, 0)
    err = e.value
    assert str(err) == "the task raised UnpicklableError: the plant diverged (7)"
    assert err.__cause__ is None and err.__context__ is None  # nothing of the worker's objects travels
    back = pickle.loads(pickle.dumps(err))
    assert isinstance(back, EngineError) and str(back) == str(err)
