"""`vmehil run` as a process under more than one signal: a burst of SIGINT or SIGTERM (every 2 ms
for 0.4 s) and two Ctrl-C 30 ms apart. The stop completes, every signal after the first is held
and recorded, the JSON and the report are written, and the exit status is 130/143."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest

from tests.vmehil.commands.test_run_exit_paths import _wait_started

pytestmark = pytest.mark.slow


def _run(tmp_path, *extra: str) -> tuple[subprocess.Popen, object]:
    out = tmp_path / "run.json"
    proc = subprocess.Popen([sys.executable, "-m", "vmehil", "run", "--realtime", "--overrun", "warn",
                             "--duration", "8", "--json", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=str(tmp_path))
    _wait_started(proc)
    return proc, out


def _signals(proc: subprocess.Popen, signum: int, every_s: float, count: int) -> int:
    """Send ``count`` signals ``every_s`` apart while the process lives; returns how many went."""
    sent = 0
    for _ in range(count):
        if proc.poll() is not None:
            break
        proc.send_signal(signum)
        sent += 1
        time.sleep(every_s)  # the pace of the sender, not a wait for the process
    return sent


@pytest.mark.parametrize(("signum", "status", "name"),
                         [(signal.SIGINT, 130, "SIGINT"), (signal.SIGTERM, 143, "SIGTERM")])
def test_a_burst_of_signals_ends_the_run_safe_with_its_json(tmp_path, signum, status, name) -> None:
    proc, out = _run(tmp_path)
    sent = _signals(proc, signum, 0.002, 200)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status, err
    summary = json.loads(out.read_text())
    stop = summary["final_stop"]
    assert stop["reason"] == "interrupted" and stop["verified"] is True and summary["safe_stop_incomplete"] == []
    assert summary["faults"][0]["cause"] == "interrupted"
    got = stop["interruptions"]
    assert got[0]["signal"] == name and got[0]["during"] == "run"
    assert 1 <= len(got) <= sent and all(i["signal"] == name for i in got)


def test_two_ctrl_c_30_ms_apart_still_write_the_report(tmp_path) -> None:
    report = tmp_path / "report"
    proc, out = _run(tmp_path, "--report", str(report))
    _signals(proc, signal.SIGINT, 0.030, 2)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert (report / "summary.md").is_file(), err
    assert json.loads(out.read_text())["final_stop"]["verified"] is True
