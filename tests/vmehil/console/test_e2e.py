"""End to end: the console beside a real lockstep `vmehil run` on the emulated JPL arm (crate,
drivers, plant), in process and as `vmehil run --console` / `vmehil console` subprocesses driven
through the pty by a terminal program."""

from __future__ import annotations

import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import serial

from servo.motion import default_demo_motion
from servo.runner import LockstepRunner
from tests.support.console import Driver, LineReader, wait_for_link
from vmehil.commands.run_options import RunOptions
from vmehil.console.extension import ConsoleOptions, attach
from vmehil.console.protocol import parse_reply_line
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

COMMANDS = ('command nudge(float a) = {\n    move_joint(1, a, 1.0);\n    move_joint(1, 0.0);\n'
            '    echo("nudged");\n}\n')


def _joints(reply: list[str]) -> dict[str, dict[str, str]]:
    out = {}
    for line in reply:
        if line.startswith("DATA joint"):
            d = parse_reply_line(line)[2]
            out[d["joint"]] = d
    return out


@pytest.mark.slow  # over 5 s: make test runs it, make test-fast leaves it out
def test_console_beside_a_lockstep_run_moves_a_joint(tmp_path):
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, motion=default_demo_motion(system.rig.n_joints), n_ticks=3000)
    loop.start()
    runner = LockstepRunner(system, loop)
    cmd_file = tmp_path / "ops.cmd"
    cmd_file.write_text(COMMANDS)
    link = tmp_path / "console"
    options = RunOptions(console=ConsoleOptions(port=f"pty:{link}", commands=str(cmd_file), baud=115200))
    console = attach(options, system, loop, runner)
    assert console is not None and console.on_tick in runner.after_tick
    assert console.session.delay == pytest.approx(system.rig.computation_delay_s / system.rig.period_s)
    client = serial.Serial(str(link), timeout=0.02)
    try:
        drv = Driver(loop, console, client.write, LineReader(client.read).lines, step=runner.tick)
        r = drv.ask("status")
        assert r[-1] == f"OK status joints={system.rig.n_joints} state=running"
        assert list(_joints(r)) == [j.name for j in system.rig.joints]
        assert drv.ask("move_joint 1 5")[0].startswith("ERR STATE a motion is running")  # the demo move
        assert drv.ask("stay")[-1].startswith("OK stay")
        j1 = loop.names[0]
        start = float(_joints(drv.ask("status"))[j1]["target_deg"])
        assert drv.ask(f"move_joint {j1} {start + 5:.6f} speed=1")[-1].startswith("OK move_joint")
        for _ in range(800):
            runner.tick()
            if loop.sequencer.finished:
                break
        runner.run(250)  # settle
        joint = _joints(drv.ask("status"))[j1]
        assert float(joint["target_deg"]) == pytest.approx(start + 5, abs=1e-4)
        assert abs(float(joint["pos_deg"]) - (start + 5)) < 1.0
        assert loop.fault is None
        assert drv.ask("gains 1 kp=120")[-1].startswith("OK gains")
        assert drv.ask("nudge 2")[-1] == "OK nudge id=1"
        drv.wait_event("EVT done 1 nudge", max_ticks=3000)
        assert any(msg == "compound nudge #1 done" for _, src, msg in loop.log)
    finally:
        client.close()
        console.close()
        system.close()


def _socat() -> str | None:
    return shutil.which("socat")


class _Terminal:
    """socat on the pty link (or pyserial when socat is missing), exchanging whole lines."""

    def __init__(self, link: Path) -> None:
        self.lines: queue.Queue[str] = queue.Queue()
        socat = _socat()
        if socat is not None:
            self.proc = subprocess.Popen([socat, "-", f"{link},raw,echo=0"], stdin=subprocess.PIPE,
                                         stdout=subprocess.PIPE)
            self.ser = None
            threading.Thread(target=self._pump, daemon=True).start()
        else:
            self.proc = None
            self.ser = serial.Serial(str(link), timeout=0.05)
            threading.Thread(target=self._pump_serial, daemon=True).start()

    def _pump(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        for raw in iter(self.proc.stdout.readline, b""):
            self.lines.put(raw.decode().strip("\r\n"))

    def _pump_serial(self) -> None:
        reader = LineReader(self.ser.read)
        while self.ser is not None and self.ser.is_open:
            try:
                for line in reader.lines():
                    self.lines.put(line)
            except Exception:
                return

    def ask(self, line: str, timeout_s: float = 60.0) -> list[str]:
        data = (line + "\n").encode()
        if self.proc is not None:
            self.proc.stdin.write(data)
            self.proc.stdin.flush()
        else:
            self.ser.write(data)
        out = []
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                x = self.lines.get(timeout=0.5)
            except queue.Empty:
                continue
            if not x or x.startswith("EVT"):
                continue
            out.append(x)
            if x.startswith(("OK", "ERR")):
                return out
        raise AssertionError(f"no reply to {line!r}")

    def close(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(timeout=10)
        if self.ser is not None:
            ser, self.ser = self.ser, None
            ser.close()


def _vmehil(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "vmehil", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})


@pytest.mark.slow
def test_vmehil_run_console_through_a_terminal_program(tmp_path):
    link = tmp_path / "console"
    cmd_file = tmp_path / "ops.cmd"
    cmd_file.write_text(COMMANDS)
    # a loaded test machine must not decide the outcome: the overrun policy warns instead of stopping
    # a script's client: no prompt, no echo (a person at a terminal gets both by default)
    proc = _vmehil("run", "--realtime", "--overrun", "warn", "--duration", "120", "--quiet", "--console", f"pty:{link}",
                   "--console-commands", str(cmd_file), "--console-prompt", "off", "--console-echo", "off")
    term = None
    try:
        wait_for_link(link, proc)
        term = _Terminal(link)
        r = term.ask("status")
        assert r[-1].startswith("OK status joints=") and len(_joints(r)) >= 1
        assert term.ask("stay")[-1].startswith("OK stay")
        assert term.ask("move_joint 1 3 speed=1")[-1].startswith("OK move_joint")
        for _ in range(200):  # watch status until the move has ended
            r = term.ask("status")
            if parse_reply_line(r[0])[2]["motion"] == "idle":
                break
            time.sleep(0.05)
        assert parse_reply_line(r[0])[2]["motion"] == "idle"
        assert abs(float(next(iter(_joints(r).values()))["target_deg"]) - 3.0) < 1e-6
        assert term.ask("help nudge")[0].startswith("DATA help command=nudge")
    finally:
        if term is not None:
            term.close()
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=60)
    assert "console: pty /dev/pts/" in err
    assert not link.is_symlink()  # closed and removed when the run ended


@pytest.mark.slow  # over 5 s: make test runs it, make test-fast leaves it out
def test_vmehil_console_serves_and_shuts_down(tmp_path):
    link = tmp_path / "console"
    # the shipped spelling --port (an alias of --console)
    proc = _vmehil("console", "--overrun", "warn", "--port", f"pty:{link}", "--console-prompt", "off",
                   "--console-echo", "off")
    term = None
    try:
        wait_for_link(link, proc)
        term = _Terminal(link)
        assert term.ask("status")[-1].startswith("OK status")
        assert term.ask("move_joint 1 1")[-1].startswith("OK move_joint")
        assert term.ask("shutdown")[-1].startswith("OK shutdown")
        out, _err = proc.communicate(timeout=60)
    finally:
        if term is not None:
            term.close()
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0
    assert "vmehil console:" in out and "stopped: operator_shutdown" in out
