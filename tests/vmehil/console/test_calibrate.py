"""`calibrate` on the console over loop://: the procedures run on the rig the live loop drives,
with the live loop moving the joints; progress streams as INFO lines, checks as DATA lines; the
file is written atomically and put in force; stop aborts and leaves everything as it was."""

from __future__ import annotations

import threading

import pytest

from servo.motion import Motion, WaitMove
from servo.runner import LockstepRunner
from tests.support.console import Driver, tap_poll
from vmehil.calibration.store import load_store
from vmehil.console.extension import start_console
from vmehil.console.protocol import parse_reply_line
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig


@pytest.fixture
def rig(tmp_path):
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, motion=Motion((WaitMove(0.0),), "hold", "<test>"), n_ticks=0)
    loop.start()
    runner = LockstepRunner(system, loop)
    out = tmp_path / "cal.toml"
    console = start_console("loop://", loop, runner=runner, calibration=out, announce=lambda _: None)
    drv = Driver(loop, console, console.transport.write, tap_poll(console), step=runner.tick)
    runner.run(25)
    yield system, loop, runner, console, drv, out
    console.close()
    system.close()


def _checks(reply: list[str]) -> list[dict[str, str]]:
    return [parse_reply_line(x)[2] for x in reply if x.startswith("DATA calibration")]


@pytest.mark.slow
def test_calibrate_encoder_runs_on_the_live_loop_and_puts_the_result_in_force(rig):
    system, loop, runner, _console, drv, out = rig
    j1 = loop.names[0]
    k0 = loop.tick_count
    reply = drv.ask("calibrate encoder --joint 1 --auto", max_ticks=20)
    assert reply[0].startswith("INFO calibrating encoder on rig"), reply
    assert all(x.split(" ", 1)[0] in ("INFO", "DATA") for x in reply[:-1]), reply
    assert any(f"{j1}: moving" in x for x in reply), reply  # the procedure's remarks, streamed
    checks = _checks(reply)
    assert [c["procedure"] for c in checks] == ["encoder"] * 3 and all(c["result"] == "pass" for c in checks)
    prefix, _, end = parse_reply_line(reply[-1])
    assert prefix == "OK" and end["written"] == str(out) and end["state"] == "running", reply[-1]
    # the live loop did the moving: its own ticks, no fault, holding afterwards
    assert loop.tick_count - k0 > 500 and float(end["loop_s"]) > 4.0
    assert loop.fault is None and loop.enabled and loop.sequencer.finished
    # written, and in force in the live drivers
    entry = load_store(out, system.rig).joint_entry(j1, "encoder")
    assert entry is not None
    assert system.io.calibration is not None and system.io.calibration.joint_entry(j1, "encoder") is not None
    assert system.io.scaling[0].encoder_counts_per_rev == pytest.approx(entry.values["counts_per_joint_rev"])
    assert any(src == "console" and msg.startswith("calibrate encoder: written") for _, src, msg in loop.log)
    # the loop goes on servoing the rig afterwards
    runner.run(250)
    assert loop.fault is None
    assert drv.ask("status")[-1].endswith("state=running")


def test_calibrate_adc_writes_board_coefficients_the_drivers_then_use(rig):
    system, loop, runner, _console, drv, out = rig
    nominal = {n: d.calibration for n, d in system.io.adc.items()}
    reply = drv.ask("calibrate adc", max_ticks=20)
    assert reply[-1].startswith("OK calibrate procedures=adc"), reply[-3:]
    checks = [c for c in _checks(reply) if c["result"] != "skipped"]
    assert len(checks) >= 3 and all(c["result"] == "pass" for c in checks)
    written = load_store(out, system.rig)
    boards = [n for n in system.io.adc if written.board_calibration(n) is not None]
    assert boards  # the injected offset/gain errors were measured on the live rig's boards ...
    for n in boards:  # ... and the live drivers now use them
        assert system.io.adc[n].calibration == written.board_calibration(n) != nominal[n]
    runner.run(100)
    assert loop.fault is None


def test_calibrate_is_refused_while_a_motion_runs_and_on_bad_arguments(rig):
    _system, loop, _runner, _console, drv, out = rig
    assert drv.ask("move_joint 1 3")[-1].startswith("OK move_joint")
    assert drv.ask("calibrate encoder --auto")[0].startswith("ERR STATE a motion is running")
    assert drv.ask("stay")[-1].startswith("OK stay")
    for line, code, text in [
        ("calibrate", "ARGS", "which procedure"),
        ("calibrate nosuch", "VALUE", "no procedure 'nosuch'"),
        ("calibrate pot", "ARGS", "add --auto"),
        ("calibrate all", "ARGS", "add --auto"),
        ("calibrate encoder --joint 9", "VALUE", "joint 9 does not exist"),
        ("calibrate encoder --joint", "ARGS", "--joint needs"),
        ("calibrate encoder --fast", "ARGS", "unknown option '--fast'"),
        ("calibrate encoder adc", "ARGS", "one procedure at a time"),
    ]:
        reply = drv.ask(line)
        assert len(reply) == 1 and reply[0].startswith(f"ERR {code} ") and text in reply[0], (line, reply)
    assert not out.exists() and loop.fault is None
    drv.ask("stop")  # category 1 (#29): refused while it decelerates, and once it has stopped
    assert drv.ask("calibrate adc")[0].startswith("ERR STATE the loop is stopping (operator_stop, category 1")
    _runner.finish_stop()
    assert drv.ask("calibrate adc")[0].startswith("ERR STATE the loop is stopped by a fault")


def test_stop_aborts_a_calibration_and_leaves_file_and_drivers_as_they_were(rig):
    system, loop, runner, console, drv, out = rig
    assert drv.ask("calibrate adc", max_ticks=20)[-1].startswith("OK calibrate")
    before = out.read_bytes()
    in_force = system.io.calibration
    cpr = [s.encoder_counts_per_rev for s in system.io.scaling]
    lines: list[str] = []
    sent = threading.Event()

    def watch(line: str) -> None:  # runs in the job's thread while the procedure moves the joint
        lines.append(line)
        if "moving" in line and not sent.is_set():
            sent.set()
            console.transport.write(b"stop\r\n")

    console.taps.append(watch)
    console.transport.write(b"calibrate encoder --joint 1 --auto\r\n")
    for _ in range(400):
        runner.tick()
        if any(x.startswith(("ERR STATE calibrate", "OK calibrate")) for x in lines):
            break
    end = next(x for x in lines if x.startswith(("ERR STATE calibrate", "OK calibrate")))
    assert sent.is_set() and "operator_stop" in end and "left unchanged" in end, end
    assert any(x.startswith("OK stop") for x in lines)  # the stop's own reply
    assert out.read_bytes() == before and not out.with_name(out.name + ".tmp").exists()
    assert system.io.calibration is in_force and [s.encoder_counts_per_rev for s in system.io.scaling] == cpr
    assert loop.fault is not None and loop.fault.cause == "operator_stop" and not loop.enabled
    drv.poll()  # drop the lines seen above from the driver's queue
    assert drv.ask("enable")[-1].startswith("OK enable state=running")
    runner.run(250)
    assert loop.fault is None


def test_a_calibration_that_changes_no_entry_answers_ok_unchanged_not_a_failed_check(rig, monkeypatch):
    # friction passes its checks and writes no entry: the runner leaves the file alone, and the
    # console must say so as success, not as "0 check(s) failed"
    from vmehil.calibration import procedure_runner
    from vmehil.calibration.base import Check, ProcedureResult

    def passes_and_changes_nothing(ctx, names, out_path=None, **_kw):
        result = ProcedureResult("friction", 1, checks=[Check("j1 running torque", 23.8, "oz-in", 29.0)])
        return procedure_runner.ProcedureRunOutcome(results=[result], unchanged=True)

    monkeypatch.setattr(procedure_runner, "run_procedures", passes_and_changes_nothing)
    _system, loop, _runner, _console, drv, out = rig
    reply = drv.ask("calibrate friction --joint 1", max_ticks=20)
    prefix, _, end = parse_reply_line(reply[-1])
    assert prefix == "OK" and end["written"] == "unchanged" and end["checks"] == "1", reply
    assert not out.exists() and loop.fault is None
