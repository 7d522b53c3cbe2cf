"""`vmehil run` ends safe on every exit path, with the documented exit status, and still writes
its JSON: SIGINT → 130, SIGTERM → 143, a normal end → 0 with a verified final stop."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest

from vmehil import cli
from vmehil.exit_status import EXIT_UNEXPECTED


def _start_run(tmp_path):
    out = tmp_path / "run.json"
    proc = subprocess.Popen([sys.executable, "-m", "vmehil", "run", "--duration", "120", "--json", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=str(tmp_path))
    _wait_started(proc)
    return proc, out


def _wait_started(proc: subprocess.Popen) -> None:
    """Read the run's stderr until it says the amplifiers are enabled."""
    assert proc.stderr is not None
    seen = []
    deadline = time.monotonic() + 120  # a bound on a hang only
    for line in proc.stderr:  # the run announces that the amplifiers are enabled, then ticks
        seen.append(line)
        if "amplifiers enabled" in line:
            return
        assert time.monotonic() < deadline
    raise AssertionError(f"the run never started: {''.join(seen)}")


@pytest.mark.parametrize(("signum", "status", "name"),
                         [(signal.SIGINT, 130, "SIGINT"), (signal.SIGTERM, 143, "SIGTERM")])
def test_a_signal_ends_the_run_safe_stopped_with_its_exit_status_and_the_json(tmp_path, signum, status, name):
    proc, out = _start_run(tmp_path)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == status, err
    assert out.exists(), err
    summary = json.loads(out.read_text())
    assert summary["faults"][0]["cause"] == "interrupted" and name in summary["faults"][0]["detail"]
    assert summary["final_stop"]["reason"] == "interrupted" and name in summary["final_stop"]["detail"]
    assert summary["final_stop"]["verified"] is True and summary["safe_stop_incomplete"] == []
    assert summary["ticks"] < 120 * 125  # stopped early (possibly in its very first tick)


def test_a_normal_end_is_a_verified_stop(tmp_path):
    out = tmp_path / "run.json"
    assert cli.main(["run", "--duration", "1", "--quiet", "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    stop = summary["final_stop"]
    assert {k: stop[k] for k in ("reason", "detail", "verified", "incomplete", "interruptions", "category",
                                 "cause", "fell_to_0")} == {
        "reason": "end", "detail": "the run ended", "verified": True, "incomplete": [], "interruptions": [],
        "category": 1, "cause": "end", "fell_to_0": None}
    assert summary["faults"] == []  # the planned end is no fault
    # a category-1 stop (at most its 1.5 s bound) from tick 125, then the 2 s window (250 ticks)
    assert 125 + 250 <= stop["tick"] <= 125 + round(1.5 * 125) + 250
    names = ["j1", "j2", "j3", "j4", "j5", "j6", "hand"]
    assert list(stop["excursion_deg"]) == names and list(stop["excursion_sensor_deg"]) == names
    assert max(stop["excursion_deg"].values()) <= 1.0  # issue #29's goal, true angle


def test_an_unexpected_error_is_one_line_and_exit_status_3(monkeypatch, capsys):
    def broken(args):
        raise RuntimeError("something nobody expected")

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    run_parser = parser._subparsers._group_actions[0].choices["run"]  # type: ignore[union-attr]
    run_parser.set_defaults(func=broken)
    assert cli.main(["run"]) == EXIT_UNEXPECTED
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["vmehil run: unexpected error: RuntimeError: something nobody expected "
                   "(run with --debug or VMEHIL_DEBUG=1 for the traceback)"]
    assert cli.main(["run", "--debug"]) == EXIT_UNEXPECTED
    assert "Traceback" in capsys.readouterr().err


def test_a_stray_value_error_is_unexpected_not_bad_input(monkeypatch, capsys):
    # bad input (exit 2) is what the argument and file checks refuse with their typed errors; a
    # ValueError from anywhere else (numpy, a bug) is an unexpected error (issue #30, item 5)
    def broken(args):
        raise ValueError("All-NaN slice encountered")

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    run_parser = parser._subparsers._group_actions[0].choices["run"]  # type: ignore[union-attr]
    run_parser.set_defaults(func=broken)
    assert cli.main(["run"]) == EXIT_UNEXPECTED
    assert capsys.readouterr().err.strip() == (
        "vmehil run: unexpected error: ValueError: All-NaN slice encountered "
        "(run with --debug or VMEHIL_DEBUG=1 for the traceback)")


def test_a_board_removed_at_tick_0_ends_unverified_with_exit_4_and_writes_the_json(tmp_path, capsys):
    # the stop is in the very first tick, before any target: no true error is known, and the stop
    # report says so by leaving the figures out (it crashed on an all-NaN slice, issue #30, item 5)
    out = tmp_path / "r.json"
    code = cli.main(["run", "--duration", "0.5", "--quiet", "--fault", "board_removed:board=pio0",
                     "--json", str(out)])
    assert code == 4, capsys.readouterr().err  # the read-back could not confirm the enables low
    summary = json.loads(out.read_text())
    stop = summary["stop"]
    assert stop["stopped"] is True and stop["tick"] == 0 and stop["ticks_after_fault"] == 0
    assert stop["cause"] == "driver_error" and "safe stop incomplete" in stop["detail"]
    assert "true_error_deg" not in stop and "max_true_error_deg" not in stop
    assert summary["final_stop"]["verified"] is False
