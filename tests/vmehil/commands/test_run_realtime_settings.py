"""`vmehil run --realtime --rt-priority P --lock-memory`: the settings are tried, what the system
allowed and refused is reported (never fatal), the process's own scheduler is put back after the
run, and the run still ends in a verified safe stop."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from vmehil.cli import main

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="no sched_getscheduler here")


def test_run_reports_each_realtime_setting_as_applied_or_refused_and_restores_the_scheduler(tmp_path: Path) -> None:
    before = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
    out = tmp_path / "run.json"
    status = main(["run", "--realtime", "--duration", "0.1", "--rt-priority", "5", "--lock-memory",
                   "--quiet", "--json", str(out)])
    summary = json.loads(out.read_text())
    settings = summary["realtime_settings"]
    asked = {"SCHED_FIFO", "mlockall"}
    applied = {name for name in asked if any(a.startswith(name) for a in settings["applied"])}
    assert applied | set(settings["refused"]) == asked
    assert not applied & set(settings["refused"])
    assert all(reason for reason in settings["refused"].values())
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before
    assert summary["final_stop"]["verified"] is True
    assert status in (0, 1)  # a loaded machine may overrun (exit 1); either way the stop was verified


def test_a_lockstep_run_asks_for_no_realtime_settings(tmp_path: Path) -> None:
    out = tmp_path / "run.json"
    assert main(["run", "--duration", "0.05", "--rt-priority", "5", "--quiet", "--json", str(out)]) == 0
    assert "realtime_settings" not in json.loads(out.read_text())


@pytest.mark.parametrize("value", ["0", "100", "x"])
def test_an_out_of_range_priority_is_refused_before_anything_runs(
        value: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["run", "--realtime", "--rt-priority", value])
    assert e.value.code == 2
    assert "--rt-priority" in capsys.readouterr().err
