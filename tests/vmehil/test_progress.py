"""Progress bars (tqdm on stderr): drawn only on a terminal and without --quiet; every line printed
meanwhile — procedure remarks, prompts, log records, warnings — lands on a line of its own, above
the bar, never on the bar's line."""

from __future__ import annotations

import io
import logging
import re
import sys
import warnings

import pytest

from vmehil.cli import main
from vmehil.writers.progress import PhaseProgress, TickProgress, progress_bar, say


class FakeTerminal(io.StringIO):
    """What a terminal receives (``isatty`` true), and the screen it would show."""

    def isatty(self) -> bool:
        return True

    def screen(self) -> list[str]:
        """The lines on screen: ``\\r`` returns to column 0 and overwrites, ``\\n`` moves down."""
        rows: list[list[str]] = [[]]
        row = col = 0
        for token in re.findall(r"\x1b\[[0-9;]*[A-Za-z]|[\s\S]", self.getvalue()):
            if token == "\r":
                col = 0
            elif token == "\n":
                row, col = row + 1, 0
                if row == len(rows):
                    rows.append([])
            elif token == "\x1b[A":
                row = max(0, row - 1)
            elif token.startswith("\x1b"):
                raise AssertionError(f"unexpected escape sequence {token!r}")
            else:
                line = rows[row]
                line.extend(" " * (col + 1 - len(line)))
                line[col] = token
                col += 1
        return ["".join(r).rstrip() for r in rows]


BAR = re.compile(r"\d+%\|")  # tqdm's "50%|#####     |"


def on_terminal(monkeypatch) -> FakeTerminal:
    """stdout and stderr both go to one fake terminal, as on a real one. (Called in the test
    body: pytest's output capture re-installs its own streams between set-up and call.)"""
    t = FakeTerminal()
    monkeypatch.setattr(sys, "stdout", t)
    monkeypatch.setattr(sys, "stderr", t)
    return t


def test_a_bar_is_drawn_only_on_a_terminal_and_never_with_quiet() -> None:
    pipe, tty, quiet = io.StringIO(), FakeTerminal(), FakeTerminal()
    for stream, q in ((pipe, False), (tty, False), (quiet, True)):
        with progress_bar("work", 3, stream=stream, quiet=q) as bar:
            bar.update(3)
    assert pipe.getvalue() == "" and quiet.getvalue() == ""
    assert BAR.search(tty.getvalue()) and "3/3" in tty.getvalue()
    assert not TickProgress("run", stream=pipe).enabled and not TickProgress("run", stream=tty, quiet=True).enabled
    assert not PhaseProgress(stream=pipe).enabled and PhaseProgress(stream=tty).enabled


def test_tick_progress_follows_the_runner_and_closes_at_the_last_tick() -> None:
    tty = FakeTerminal()
    with TickProgress("run", stream=tty) as progress:
        for i in range(1, 101):
            progress(i, 100)
        assert progress._bar is None  # closed by the last tick
    assert "100/100" in tty.getvalue() and tty.screen()[-1] == ""  # the finished bar stays, then a new line


def test_phase_progress_prints_remarks_and_prompts_above_the_bar(monkeypatch) -> None:
    terminal = on_terminal(monkeypatch)
    def answer(question: str) -> str:
        sys.stdout.write(question)  # as input() does
        sys.stdout.write("12.5\n")  # the operator's typing, echoed
        return "12.5"

    with PhaseProgress(answer=answer) as progress:
        progress("pot stops", 0, 4)
        progress.say("  j1: 9 points")
        progress("pot stops", 1, 4)
        assert progress.ask("  j1: type the angle: ") == "12.5"
        progress("pot stops", 4, 4)
    screen = terminal.screen()
    assert "  j1: 9 points" in screen and "  j1: type the angle: 12.5" in screen
    assert BAR.search(terminal.getvalue())
    assert not any(BAR.search(line) for line in screen)  # cleared when the phase completed


def test_log_records_and_warnings_during_a_bar_land_above_it(monkeypatch) -> None:
    terminal = on_terminal(monkeypatch)
    last_resort, show_warning = logging.lastResort, warnings.showwarning
    with progress_bar("work", 2) as bar:
        bar.update(1)
        logging.getLogger("vmehil.test.progress").warning("a log record")  # no handler: the last resort
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.warn("a warning", UserWarning, stacklevel=1)
        say("a remark")
        bar.update(1)
    screen = terminal.screen()
    assert "a log record" in screen and "a remark" in screen
    assert any(line.endswith("UserWarning: a warning") for line in screen)
    assert logging.lastResort is last_resort and warnings.showwarning is show_warning  # put back


def test_calibrate_prints_its_lines_above_the_progress_bar_not_on_it(tmp_path, monkeypatch) -> None:
    terminal = on_terminal(monkeypatch)
    from tests.vmehil.commands.test_calibrate import default_rig_with_references

    rig_path = default_rig_with_references(tmp_path)
    assert main(["calibrate", "adc", "--rig", str(rig_path), "--out", str(tmp_path / "cal.toml")]) == 0
    raw, screen = terminal.getvalue(), terminal.screen()
    assert BAR.search(raw), "the bar was drawn"
    remarks = [line for line in screen if line.startswith("  adc")]
    assert any("reading 2 reference inputs" in line for line in remarks)
    for line in screen:  # a line with a bar on it holds the bar and nothing after it
        assert not BAR.search(line) or re.fullmatch(r".*\d+%\|.*\| \d+/\d+ \[[^\]]*\]", line), line
    # every remark is a whole line of its own, exactly as said
    said = re.findall(r"(?:^|\r)(  adc[^\r\n]*)\n", raw)
    assert said and all(s in screen for s in said)
    assert not any(BAR.search(line) for line in screen)  # no bar left behind


def test_calibrate_quiet_draws_no_bar(tmp_path, monkeypatch) -> None:
    terminal = on_terminal(monkeypatch)
    from tests.vmehil.commands.test_calibrate import default_rig_with_references

    rig_path = default_rig_with_references(tmp_path)
    assert main(["calibrate", "adc", "--quiet", "--rig", str(rig_path), "--out", str(tmp_path / "cal.toml")]) == 0
    assert not BAR.search(terminal.getvalue()) and "\r" not in terminal.getvalue()


def test_run_shows_a_tick_bar_on_a_terminal_only(tmp_path, monkeypatch, capsys) -> None:
    tty = FakeTerminal()
    monkeypatch.setattr(sys, "stderr", tty)
    assert main(["run", "--duration", "0.4", "--seed", "1"]) in (0, 1)
    assert re.search(r"run: 100%\|.*\| 50/50", tty.getvalue())
    monkeypatch.setattr(sys, "stderr", io.StringIO())  # a pipe: nothing but the plain messages
    assert main(["run", "--duration", "0.4", "--seed", "1"]) in (0, 1)
    assert "\r" not in sys.stderr.getvalue() and not BAR.search(sys.stderr.getvalue())


def test_sweep_bar_counts_points_and_names_the_last(tmp_path, monkeypatch, capsys) -> None:
    tty = FakeTerminal()
    monkeypatch.setattr(sys, "stderr", tty)
    assert main(["tune", "sweep", "--margins-only", "--grid", "kp=80:120:2", "--jobs", "1",
                 "--out", str(tmp_path)]) == 0
    out = tty.getvalue()
    assert re.search(r"sweep: 100%\|.*\| 2/2", out) and "last: kp=" in out
    assert (tmp_path / "sweep.csv").exists()


@pytest.mark.slow
def test_calibrate_pot_log_records_and_remarks_each_land_on_a_line_of_their_own(tmp_path, monkeypatch) -> None:
    """`calibrate pot --auto` on a terminal, with a library logging through the root logger's
    console handler (as a user's `logging.basicConfig` sets up) at every fixture reading while the
    bar is drawn: the captured output holds every record and remark whole, on its own line."""
    from vmehil.rig_setup.emulated_calibration import EmulatedFixture

    terminal = on_terminal(monkeypatch)
    root = logging.getLogger()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("LOG %(message)s"))
    root.addHandler(handler)
    reading = EmulatedFixture.joint_angle
    count = {"n": 0}

    def logged_reading(self, joint: int) -> float:
        count["n"] += 1
        logging.getLogger("vmehil.test.fixture").warning("fixture reading %d", count["n"])
        return reading(self, joint)

    monkeypatch.setattr(EmulatedFixture, "joint_angle", logged_reading)
    try:
        argv = ["calibrate", "pot", "--auto", "--joint", "1", "--points", "3", "--out", str(tmp_path / "c.toml")]
        assert main(argv) == 0
    finally:
        root.removeHandler(handler)
    raw, screen = terminal.getvalue(), terminal.screen()
    assert BAR.search(raw), "the bar was drawn"
    assert count["n"] >= 5
    for k in range(1, count["n"] + 1):  # every record whole, alone on its line
        assert f"LOG fixture reading {k}" in screen
    assert any(line.startswith("  j1: residual ") for line in screen)
    for line in screen:  # a line with a bar holds the bar and nothing after it, nothing before it
        assert not BAR.search(line) or re.fullmatch(r"[^|]*\d+%\|.*\| \d+/\d+ \[[^\]]*\]", line), line
    assert not any(BAR.search(line) for line in screen)  # and none is left behind
