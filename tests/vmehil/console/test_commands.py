"""Every console command over loop:// and over a pty vmehil creates, against a running ServoLoop
(a small simulated JointIO; ticks driven by the test, commands handed over at tick boundaries)."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
import serial

from tests.support.console import Driver, LineReader, tap_poll, until
from tests.support.fakes import make_loop, tick
from vmehil.console.commands import Outcome
from vmehil.console.protocol import parse_reply_line
from vmehil.console.server import Console, PtyTransport, open_transport


@pytest.fixture(params=["loop", "pty"])
def console_driver(request, tmp_path):
    loop = make_loop(2)
    if request.param == "loop":
        console = Console(loop, open_transport("loop://")).start()
        drv = Driver(loop, console, console.transport.write, tap_poll(console))  # the port lock: no interleaving
        client = None
    else:
        link = tmp_path / "console"
        console = Console(loop, open_transport(f"pty:{link}")).start()
        assert isinstance(console.transport, PtyTransport)
        assert os.path.islink(link) and os.readlink(link).startswith("/dev/pts/")
        client = serial.Serial(str(link), timeout=0.02)
        drv = Driver(loop, console, client.write, LineReader(client.read).lines)
    yield drv
    if client is not None:
        client.close()
    console.close()


def ok(reply: list[str], name: str) -> dict[str, str]:
    assert reply[-1].startswith(f"OK {name}"), reply
    for line in reply[:-1]:
        assert line.split(" ", 1)[0] in ("DATA", "INFO"), line
    return parse_reply_line(reply[-1])[2]


def err(reply: list[str], code: str) -> str:
    assert len(reply) == 1 and reply[0].startswith(f"ERR {code} "), reply
    return reply[0]


def data(reply: list[str], kind: str) -> list[dict[str, str]]:
    return [parse_reply_line(x)[2] for x in reply if x.startswith(f"DATA {kind}")]


def wait_idle(drv: Driver) -> None:
    until(lambda: drv.loop.sequencer.finished, drv.loop, drv.console, max_ticks=2000, pause_s=0.0)


def test_help_lists_every_line_command(console_driver):
    r = console_driver.ask("help")
    names = [d["command"] for d in data(r, "help")]
    for c in ("help", "status", "move", "move_rel", "move_joint", "stay", "gains", "mode", "stop", "enable", "run",
              "calibrate", "log", "commands", "load", "cancel", "echo", "shutdown"):
        assert c in names
    ok(r, "help")
    one = console_driver.ask("help move")
    assert data(one, "help")[0]["usage"] == "move target:vector [speed:float=1.0]"


def test_status_reports_every_joint(console_driver):
    r = console_driver.ask("status")
    assert ok(r, "status") == {"joints": "2", "state": "running"}
    loop_line = data(r, "loop")[0]
    assert loop_line["state"] == "running" and loop_line["motion"] == "idle"
    joints = data(r, "joint")
    assert [j["joint"] for j in joints] == ["j1", "j2"]
    for j in joints:
        assert set(j) >= {"pos_deg", "target_deg", "err_deg", "current_a", "integrators", "kp_eff", "fault"}


def test_move_moves_the_joints_and_refuses_a_second_motion(console_driver):
    drv = console_driver
    r = drv.ask("move 10,-5 speed=0.5")
    assert float(ok(r, "move")["duration_s"]) > 0
    err(drv.ask("move 0,0"), "STATE")
    wait_idle(drv)
    tick(drv.loop, drv.console, 60)
    joints = data(drv.ask("status"), "joint")
    assert float(joints[0]["target_deg"]) == pytest.approx(10.0)
    assert float(joints[0]["pos_deg"]) == pytest.approx(10.0, abs=0.05)
    assert float(joints[1]["pos_deg"]) == pytest.approx(-5.0, abs=0.05)


def test_move_rel_move_joint_and_stay(console_driver):
    drv = console_driver
    ok(drv.ask("move_rel [2, 3]"), "move_rel")
    wait_idle(drv)
    ok(drv.ask("move_joint j2 -4 speed=1"), "move_joint")
    wait_idle(drv)
    assert np.degrees(drv.loop.sequencer.current.end) == pytest.approx([2.0, -4.0])
    ok(drv.ask("move_joint 1 30 speed=0.1"), "move_joint")
    tick(drv.loop, drv.console, 20)
    r = drv.ask("stay")
    held = [float(x) for x in ok(r, "stay")["target_deg"].strip("[]").split(",")]
    assert 2.0 < held[0] < 30.0 and held[1] == pytest.approx(-4.0)
    assert drv.loop.sequencer.finished
    err(drv.ask("move_joint 3 1"), "VALUE")
    err(drv.ask("move 1,2,3"), "VALUE")
    err(drv.ask("move 1,2 speed=2"), "VALUE")


def test_gains_show_set_and_reject(console_driver):
    drv = console_driver
    shown = data(drv.ask("gains"), "gains")
    assert [g["kp"] for g in shown] == ["100", "100"]
    r = drv.ask("gains j2 kp=120 kv=55")
    ok(r, "gains")
    tick(drv.loop, drv.console, 2)
    assert list(drv.loop.law.gains.kp) == [100.0, 120.0] and drv.loop.law.gains.kv[1] == 55.0
    before = drv.loop.law.gains.as_dict()
    assert "unstable" in err(drv.ask("gains all kp=5e4"), "GAIN")
    assert "limited" in err(drv.ask("gains all kp=1e6"), "GAIN")
    err(drv.ask("gains 1 kv=-3"), "GAIN")
    err(drv.ask("gains 1 kpi=0"), "GAIN")
    err(drv.ask("gains 1 kq=3"), "ARGS")
    tick(drv.loop, drv.console, 2)
    assert drv.loop.law.gains.as_dict() == before


def test_mode_show_and_set(console_driver):
    drv = console_driver
    r = drv.ask("mode")
    assert data(r, "mode")[0]["state"] == "running"
    ok(drv.ask("mode integrate j1"), "mode")
    tick(drv.loop, drv.console, 2)
    assert list(drv.loop.law.switch_off.enabled) == [False, True]
    ok(drv.ask("mode auto"), "mode")
    tick(drv.loop, drv.console, 2)
    assert list(drv.loop.law.switch_off.enabled) == [True, True]
    err(drv.ask("mode fast"), "VALUE")


def test_stop_and_enable(console_driver):
    drv = console_driver
    ok(drv.ask("move 20,20 speed=0.2"), "move")
    tick(drv.loop, drv.console, 30)
    assert ok(drv.ask("stop"), "stop")["state"] == "fault"
    assert drv.loop.fault.cause == "operator_stop" and not drv.loop.enabled
    drv.wait_event("EVT fault cause=operator_stop")
    r = drv.ask("status")
    assert data(r, "fault")[0]["cause"] == "operator_stop"
    err(drv.ask("move 0,0"), "STATE")
    assert ok(drv.ask("enable"), "enable") == {"state": "running", "cleared": "operator_stop"}
    tick(drv.loop, drv.console, 100)
    assert drv.loop.fault is None and drv.loop.enabled
    assert ok(drv.ask("enable"), "enable")["state"] == "running"


def test_run_a_motion_file(console_driver, tmp_path):
    drv = console_driver
    f = tmp_path / "m.toml"
    f.write_text('[[move]]\ntargets_deg = [3, 4]\nspeed = 1.0\n[[move]]\ntype = "wait"\nduration_s = 0.1\n')
    assert float(ok(drv.ask(f'run "{f}"'), "run")["duration_s"]) > 0.1
    wait_idle(drv)
    assert np.degrees(drv.loop.sequencer.current.end) == pytest.approx([3.0, 4.0])
    err(drv.ask(f"run {tmp_path}/missing.toml"), "FILE")
    (tmp_path / "bad.toml").write_text("[[move]]\ntargets_deg = [1]\n")
    err(drv.ask(f"run {tmp_path}/bad.toml"), "FILE")


def test_calibrate_without_a_rig_is_unavailable(console_driver):
    assert "has no rig for it" in err(console_driver.ask("calibrate pot j1"), "UNAVAILABLE")


def test_a_deferred_reply_streams_from_a_job_between_ticks(console_driver):
    """The mechanism calibrate uses: the command answers later, from a job run between ticks."""
    drv = console_driver
    ran: list[int] = []

    def hook(s, args):
        def job(send):
            ran.append(s.loop.tick_count)
            send(["INFO working", "INFO still working"])
            send([f"OK calibrate args={len(args)}"])
        s.defer(job)
        return Outcome(["INFO started"], deferred=True)

    drv.console.session.calibrate = hook
    assert drv.ask("calibrate x --auto") == ["INFO started", "INFO working", "INFO still working",
                                             "OK calibrate args=2"]
    assert len(ran) == 1
    # a host that runs jobs itself (vmehil console): on_tick leaves the job waiting, and schedules nothing
    drv.console.jobs_on_tick = False
    drv.send(b"calibrate y\r\n")
    until(drv.console.job_waiting, drv.loop, drv.console)
    tick(drv.loop, drv.console, n=5)
    assert len(ran) == 1 and drv.console.job_waiting()
    assert drv.console.run_job() and not drv.console.job_waiting() and len(ran) == 2
    assert drv.console.run_job() is False
    assert drv.reply() == ["INFO started", "INFO working", "INFO still working", "OK calibrate args=1"]


def test_log_lists_changes(console_driver):
    drv = console_driver
    ok(drv.ask("gains kp=110"), "gains")
    ok(drv.ask("mode integrate"), "mode")
    r = drv.ask("log 2")
    msgs = [d["message"] for d in data(r, "log")]
    assert msgs == ["gains all joints: kp=110", "mode integrate on all joints"]
    assert all(d["source"] == "console" for d in data(r, "log"))
    err(drv.ask("log 0"), "VALUE")


def test_log_lists_every_fault_of_the_run_and_counts_the_lines_it_shows(console_driver):
    # three stops, each cleared by `enable`: the log showed only the last, and said entries=5
    # beside 6 DATA lines
    drv = console_driver
    for n in range(3):
        drv.loop.safe_stop("following_error", f"stop {n}", joint=n % 2)
        ok(drv.ask("enable"), "enable")
    ok(drv.ask("gains kp=110"), "gains")
    r = drv.ask("log 20")
    rows = data(r, "log")
    assert [d["message"] for d in rows if d["source"] == "watchdog"] == [
        "fault following_error (j1): stop 0", "fault following_error (j2): stop 1",
        "fault following_error (j1): stop 2"]
    assert rows[-1]["message"] == "gains all joints: kp=110"
    assert ok(r, "log")["entries"] == str(len(rows))
    assert len(data(drv.ask("log 2"), "log")) == 2


@pytest.mark.slow
def test_compound_commands_load_run_and_cancel(console_driver, tmp_path):
    drv = console_driver
    f = tmp_path / "c.cmd"
    f.write_text('command hop(float a) = { move_joint(1, a); move_joint(1, 0); echo("hopped"); }\n'
                 'command wait_long() = { pause(100.0); }\n')
    r = drv.ask(f"load {f}")
    assert ok(r, "load") == {"count": "2"}
    assert [d["name"] for d in data(drv.ask("commands"), "command")] == ["hop", "wait_long"]
    assert ok(drv.ask("hop 5"), "hop") == {"id": "1"}
    assert drv.wait_event("EVT out 1 INFO hopped")
    assert drv.wait_event("EVT done 1 hop")
    err(drv.ask("hop"), "ARGS")
    err(drv.ask('hop "x"'), "ARGS")
    assert ok(drv.ask("wait_long"), "wait_long") == {"id": "2"}
    assert ok(drv.ask("cancel 2"), "cancel") == {"cancelled": "1"}
    drv.wait_event("EVT cancelled 2 wait_long")
    err(drv.ask("cancel 2"), "VALUE")
    (tmp_path / "bad.cmd").write_text("command x() = {\n  nope();\n}\n")
    assert "bad.cmd:2:3:" in err(drv.ask(f"load {tmp_path}/bad.cmd"), "FILE")


def test_echo_shutdown_unknown_and_syntax(console_driver):
    drv = console_driver
    r = drv.ask('echo "hello there"')
    assert r == ["INFO hello there", "OK echo"]
    err(drv.ask("shutdown"), "UNAVAILABLE")
    err(drv.ask("frobnicate"), "UNKNOWN")
    err(drv.ask("pause 1"), "UNKNOWN")
    assert "column 6" in err(drv.ask('echo "open'), "SYNTAX")
    assert math.isfinite(drv.loop.tick_count)


def test_a_motion_file_is_planned_off_the_loop_thread(console_driver, tmp_path, monkeypatch):
    """An LSPB path of thousands of vias takes tenths of a second to plan: `run` plans it in the
    preparer thread (from where the loop holds), never in the thread that ticks the loop (#30
    item 9: 7 000 vias stalled the console's loop 28.9 s)."""
    import threading

    from servo.motion import LspbMove

    drv = console_driver
    built_in: list[str] = []
    original = LspbMove.build

    def build(self, start, ctx):
        built_in.append(threading.current_thread().name)
        return original(self, start, ctx)

    monkeypatch.setattr(LspbMove, "build", build)
    f = tmp_path / "path.toml"
    f.write_text('[[move]]\ntype = "lspb"\nvia_deg = [[1, 2], [2, 1], [3, 3]]\n')
    assert float(ok(drv.ask(f'run "{f}"'), "run")["duration_s"]) > 0.0
    wait_idle(drv)
    assert np.degrees(drv.loop.sequencer.current.end) == pytest.approx([3.0, 3.0])
    ticking = threading.current_thread().name  # the test ticks the loop (tick())
    assert built_in and ticking not in built_in, built_in


def test_an_angle_beyond_a_turn_is_refused(console_driver):
    # `move_joint j1 1e300` was accepted and planned
    drv = console_driver
    assert "within +/-360" in err(drv.ask("move_joint j1 1e300"), "VALUE")  # the console speaks ASCII
    assert "within +/-360" in err(drv.ask("move 400,0"), "VALUE")
