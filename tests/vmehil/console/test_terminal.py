"""The console for a person at a terminal (issue 20, "The operator console"): a prompt, echo,
arrow keys swallowed (up/down: history), replies in ASCII, and ``--motion none`` so that
``move_joint`` is accepted at once.

The end-to-end tests talk through real ptys with pyserial: ``vmehil run --console pty:LINK`` opened
with ``serial.Serial`` on the link, and a pty the test opens itself, given to ``vmehil console`` as
a serial device. They wait for what they expect (the prompt after a reply) with a generous bound,
never for a time.
"""

from __future__ import annotations

import errno
import json
import os
import re
import select
import signal
import subprocess
import sys
import time
import tty

import pytest

from tests.support.console import wait_for_link
from vmehil.console.protocol import LineAssembler
from vmehil.console.terminal import ERASE_LINE, TerminalView

serial = pytest.importorskip("serial")

PROMPT = b"> "
UP, DOWN, LEFT = b"\x1b[A", b"\x1b[B", b"\x1b[D"


# ---- the line editor, byte by byte ------------------------------------------------------------------------
def test_arrow_and_function_keys_are_taken_out_of_the_line():
    la = LineAssembler()
    events = la.feed(b"sta" + UP + b"tus" + b"\x1bOB" + b"\x1b[3~" + b"\x1b[1;5C" + b"\r")
    assert [(e.kind, e.text) for e in events] == [("line", "status")]  # no "binary": nothing reached the line
    keyed = LineAssembler(keys=True)
    assert [(e.kind, e.text) for e in keyed.feed(UP + b"\x1bOB" + b"\x1b[3~" + LEFT + b"x\n")] == [
        ("key", "up"), ("key", "down"), ("key", "delete"), ("key", "left"), ("line", "x")]


def test_a_lone_escape_swallows_one_key_and_the_rest_of_the_line_survives():
    la = LineAssembler()
    assert [(e.kind, e.text) for e in la.feed(b"\x1bxhelp\r")] == [("line", "help")]


class _Screen:
    def __init__(self) -> None:
        self.out = bytearray()

    def write(self, data: bytes) -> None:
        self.out += data

    def take(self) -> bytes:
        data, self.out = bytes(self.out), bytearray()
        return data


def test_echo_backspace_enter_and_history_on_the_screen():
    screen, la = _Screen(), LineAssembler(keys=True)
    view = TerminalView(screen.write, prompt="> ", echo=True)
    view.output(b"EVT hello\r\n")
    assert screen.take() == b"EVT hello\r\n> "
    view.feed(b"statx", la)
    assert screen.take() == b"statx"
    view.feed(b"\x7f", la)
    assert screen.take() == b"\b \b"
    assert [e.text for e in view.feed(b"us\r\n", la)] == ["status"]  # CR LF: one Enter
    assert screen.take() == b"us\r\n> "
    view.output(b"OK status\r\n")  # the reply erases the prompt line and draws it again
    assert screen.take() == ERASE_LINE + b"OK status\r\n> "
    view.feed(b"he", la)
    view.output(b"EVT fault cause=x\r\n")  # an event while typing: the typed line survives
    assert screen.take() == b"he" + ERASE_LINE + b"EVT fault cause=x\r\n> he"
    view.feed(b"\x15", la)  # Ctrl-U
    assert screen.take() == ERASE_LINE + b"> " and la.pending == ""
    view.feed(UP, la)
    assert screen.take() == ERASE_LINE + b"> status" and la.pending == "status"
    view.feed(DOWN, la)
    assert screen.take() == ERASE_LINE + b"> " and la.pending == ""
    view.feed(LEFT, la)
    assert screen.take() == b""  # swallowed


def test_without_echo_only_the_prompt_is_drawn():
    screen, la = _Screen(), LineAssembler(keys=True)
    view = TerminalView(screen.write, prompt="> ", echo=False)
    assert [e.text for e in view.feed(b"status\r", la)] == ["status"]
    assert screen.take() == b"> "
    view.feed(UP, la)
    assert screen.take() == b"" and la.pending == ""


# ---- through real ptys ---------------------------------------------------------------------------------
class _Reader:
    """Everything read from a pty, and waiting for a pattern in what has not been consumed yet."""

    def __init__(self, read) -> None:
        self.read = read
        self.seen = bytearray()
        self.pos = 0

    def until(self, pattern: bytes | re.Pattern[bytes], timeout_s: float = 120.0) -> bytes:
        deadline = time.monotonic() + timeout_s  # a bound against a hang only
        rx = pattern if isinstance(pattern, re.Pattern) else re.compile(re.escape(pattern))
        while (m := rx.search(self.seen, self.pos)) is None:
            if time.monotonic() > deadline:
                raise AssertionError(f"{rx.pattern!r} not seen; got {bytes(self.seen[self.pos:])!r}")
            self.seen += self.read()
        chunk, self.pos = bytes(self.seen[self.pos:m.end()]), m.end()
        return chunk

    def reply(self, end: bytes) -> bytes:
        """Up to the line starting with ``end`` (at a line start, or after the prompt line was
        erased) and the prompt drawn after it."""
        return self.until(re.compile(rb"(?:^|\n|\x1b\[K)" + re.escape(end) + rb"[^\r\n]*\r\n> "))


def _vmehil(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "vmehil", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})


@pytest.mark.slow
def test_run_console_on_a_pty_prompts_echoes_swallows_arrows_answers_in_ascii_and_moves_at_once(tmp_path):
    link, out = tmp_path / "console", tmp_path / "run.json"
    # what a new user types: a console, no demo motion (so move_joint is accepted at once)
    proc = _vmehil("run", "--console", f"pty:{link}", "--motion", "none", "--duration", "600", "--quiet",
                   "--overrun", "warn", "--json", str(out))
    try:
        wait_for_link(link, proc)
        ser = serial.Serial(str(link), timeout=0.1)
        term = _Reader(lambda: ser.read(4096))
        hello = term.until(b"\r\n" + PROMPT)  # the greeting and the prompt, without typing anything
        assert hello.count(b"EVT hello vmehil console") == 1
        ser.write(b"stat")
        term.until(b"stat")  # echoed as typed (an event may come first: it redraws the prompt line)
        ser.write(b"us" + LEFT + UP + b"\r")  # cursor keys: swallowed (history is empty)
        r = term.reply(b"OK status")
        assert b"ERR BINARY" not in r and b"DATA loop" in r and b"motion=idle" in r
        ser.write(b"move_joint 1 2 speed=1\r")
        r = term.reply(b"OK move_joint")
        assert b"ERR" not in r
        ser.write(UP)  # history: the last line again, ready to edit
        assert term.until(b"move_joint 1 2 speed=1").endswith(b"> move_joint 1 2 speed=1")
        ser.write(b"\x15" + 'echo "θ ≤ 1° — j1 ← j2"\r'.encode())  # Ctrl-U, then UTF-8 the reply must not carry
        r = term.reply(b"OK echo")
        assert b'INFO "theta <= 1 deg - j1 <- j2"' in r or b"INFO theta <= 1 deg - j1 <- j2" in r
        ser.write(b"stop\r")
        term.reply(b"OK stop")
        ser.close()
        assert all(b < 0x80 for b in term.seen), "every byte on the line is 7-bit ASCII"
    finally:
        proc.send_signal(signal.SIGTERM)
        _stdout, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    summary = json.loads(out.read_text())
    # the boards were read back after the stop: enables low, 0 V, PWM off
    assert summary["final_stop"]["verified"] is True and summary["safe_stop_incomplete"] == []
    assert summary["faults"][0]["cause"] == "operator_stop"
    assert "picocom -q " in err and "--echo" not in err  # the hint matches the console's own echo


@pytest.mark.slow
def test_console_on_a_pty_the_test_opened_serves_the_serial_device_and_writes_its_json(tmp_path):
    master, slave = os.openpty()
    tty.setraw(slave)
    slave_path = os.ttyname(slave)
    os.close(slave)
    out = tmp_path / "console.json"
    # the shipped spellings (--port, --lockstep) next to the new ones
    proc = _vmehil("console", "--port", slave_path, "--lockstep", "--console-echo", "on", "--json", str(out))

    def read() -> bytes:
        r, _, _ = select.select([master], [], [], 0.1)
        try:
            return os.read(master, 4096) if r else b""
        except OSError as e:  # EIO: the console has not opened the slave side yet
            if e.errno != errno.EIO or proc.poll() is not None:
                raise AssertionError(f"vmehil console ended: {proc.communicate()[1]}") from e
            time.sleep(0.05)  # not synchronisation: only not spinning until it opens
            return b""

    term = _Reader(read)
    try:
        assert b"EVT hello" in term.until(b"\r\n" + PROMPT)
        os.write(master, b"move_joint j1 1" + b"\x1b[C" + b"\r")  # right arrow: swallowed
        r = term.reply(b"OK move_joint")
        assert r.startswith(b"move_joint j1 1\r\n")  # the echo
        os.write(master, b"shutdown\r")
        term.reply(b"OK shutdown")
        _stdout, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        os.close(master)
    assert proc.returncode == 0, err
    assert all(b < 0x80 for b in term.seen)
    summary = json.loads(out.read_text())
    assert summary["commands"] == 2 and summary["mode"] == "lockstep"
    assert summary["stopped"]["cause"] == "operator_shutdown" and summary["stop_incomplete"] is False


class _FakePty:
    """A pty-like transport: ``on_connect`` as PtyTransport has it, writes collected."""

    description = "fake pty"

    def __init__(self) -> None:
        self.on_connect = None
        self.out = bytearray()

    def read(self, n: int) -> bytes:
        time.sleep(0.01)  # an idle line (the reader thread's poll), not synchronisation
        return b""

    def write(self, data: bytes) -> None:
        self.out += data

    def close(self) -> None:
        pass


def _wait_until(cond, what: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s  # a bound against a hang only
    while not cond():
        assert time.monotonic() < deadline, what
        time.sleep(0.005)


def test_each_terminal_that_opens_the_pty_is_greeted_once_and_starts_with_an_empty_line():
    from tests.support.fakes import make_loop
    from vmehil.console.server import Console

    pty = _FakePty()
    console = Console(make_loop(2), pty, prompt="> ", echo=True).start()
    try:
        assert pty.on_connect is not None and bytes(pty.out) == b""  # nobody there: no greeting yet
        pty.on_connect()
        _wait_until(lambda: bytes(pty.out).endswith(b"\r\n> "), "the greeting")
        assert bytes(pty.out).count(b"EVT hello") == 1
        console.feed(b"half")  # typed, then the terminal program hangs up
        pty.out.clear()
        pty.on_connect()  # the next one
        _wait_until(lambda: bytes(pty.out).endswith(b"\r\n> "), "the second greeting")
        assert b"half" not in bytes(pty.out) and bytes(pty.out).count(b"EVT hello") == 1
        console.feed(b"\r")  # an empty line: nothing of the first terminal's is sent
        assert console.stats.lines == 0
    finally:
        console.close()
