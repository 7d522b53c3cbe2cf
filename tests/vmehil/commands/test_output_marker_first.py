"""An output directory is made and marked as vmehil's before the command writes anything, so a
command killed half-way (SIGKILL: no `finally` runs) leaves a directory the next run and `tune
sweep --resume` accept. Before, the marker came only at the end: `--resume DIR` after a killed
sweep and a second `run --report DIR` after a killed one were refused ("not made by vmehil")."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from tests.vmehil.commands.test_run_exit_paths import _wait_started
from vmehil import cli
from vmehil.writers.output_paths import MARKER, check_output_dir


@pytest.mark.parametrize("argv", [["run", "--quiet", "--report", "{d}"],
                                  ["tune", "sweep", "--margins-only", "--out", "{d}"]],
                         ids=["run --report", "tune sweep --out"])
def test_the_output_directory_is_marked_before_the_command_runs(tmp_path, monkeypatch, argv) -> None:
    d = tmp_path / "out"
    seen: dict[str, bool] = {}

    def command(args) -> int:  # stands for the command: what exists when it starts
        seen["marked"] = (d / MARKER).is_file()
        return 0

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    sub = parser._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    target = sub[argv[0]] if argv[0] == "run" else sub["tune"]._subparsers._group_actions[0].choices[argv[1]]
    target.set_defaults(func=command)
    assert cli.main([a.format(d=d) for a in argv]) == 0
    assert seen == {"marked": True}


@pytest.mark.slow  # a run started as a process (2-3 s), then killed
def test_a_report_directory_of_a_killed_run_is_taken_by_the_next(tmp_path) -> None:
    d = tmp_path / "report"
    proc = subprocess.Popen([sys.executable, "-m", "vmehil", "run", "--duration", "60", "--report", str(d)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=str(tmp_path))
    try:
        _wait_started(proc)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=60)
    (d / "theta.png").write_bytes(b"half a figure")  # what a kill inside write_report leaves
    # the next run's check at start (vmehil.writers.output_paths, as `vmehil run --report DIR` makes it): accepted
    assert check_output_dir(d, "--report") == d
