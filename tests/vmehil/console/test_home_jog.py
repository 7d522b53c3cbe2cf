"""`home J` and `jog J SPEED_DEG_S` on the console (issue #32), on the emulated jpl-arm driven by a
live loop in lockstep: homing through the console's calibration job, status's homed=, a rig that
requires homing refusing moves with ERR NOT_HOMED; jogs with their deadman and bounds, checked
against the plant's truth."""

from __future__ import annotations

import math

import pytest

from servo.motion import Motion, WaitMove
from servo.runner import LockstepRunner
from tests.support.console import Driver, tap_poll
from tests.support.homing import plant_pot_store
from vmehil.console.extension import start_console
from vmehil.console.protocol import parse_reply_line
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig


@pytest.fixture
def rig(tmp_path):
    system = build_emulated_rig(None, seed=0, initial_deg=[10.7, 0, 0, 0, 0, 0, 34.377])
    out = tmp_path / "cal.toml"
    store = plant_pot_store(system, [0])
    store.save(out)
    system.io.apply_calibration(store)
    loop = build_loop(system, motion=Motion((WaitMove(0.0),), "hold", "<test>"), n_ticks=0)
    loop.start()
    runner = LockstepRunner(system, loop)
    console = start_console("loop://", loop, runner=runner, calibration=out, announce=lambda _: None)
    drv = Driver(loop, console, console.transport.write, tap_poll(console), step=runner.tick)
    runner.run(25)
    yield system, loop, runner, drv, out
    console.close()
    system.close()


def _joint_line(reply: list[str], name: str) -> dict[str, str]:
    return next(parse_reply_line(x)[2] for x in reply if x.startswith("DATA joint") and f"joint={name} " in x)


def test_home_on_the_console_homes_the_live_encoder_and_a_rig_that_requires_it_refuses_moves_before(rig):
    system, loop, _runner, drv, out = rig
    loop.require_homing = True  # [servo] require_homing = true (parsed in servo.settings)
    status = drv.ask("status")
    assert "homed=no" in status[0] and "homing=required" in status[0]
    assert _joint_line(status, "j1")["homed"] == "no"
    reply = drv.ask("move_joint j1 12")
    assert reply[-1].startswith("ERR NOT_HOMED") and "j1" in reply[-1], reply
    reply = drv.ask("home j1", max_ticks=20)
    prefix, _, end = parse_reply_line(reply[-1])
    assert prefix == "OK" and reply[-1].startswith("OK home") and end["written"] == str(out), reply
    data = next(parse_reply_line(x)[2] for x in reply if x.startswith("DATA home"))
    # powered up at 10.7° (x4 5944.4); the pot chooses the index at 10.8° (x4 6000)
    assert data["joint"] == "j1" and float(data["index_deg"]) == pytest.approx(10.8)
    assert int(data["index_counts"]) == 56 and data["homed"] == "yes"
    status = drv.ask("status")
    j1 = _joint_line(status, "j1")
    assert j1["homed"] == "yes"
    truth = math.degrees(float(system.truth()["theta_joint"][0]))
    assert float(j1["enc_deg"]) == pytest.approx(truth, abs=0.01)
    # j2..hand are not homed: the rig still waits for them
    assert "homed=no" in status[0]
    assert drv.ask("move_joint j1 12")[-1].startswith("ERR NOT_HOMED")
    loop.require_homing = False
    assert drv.ask("move_joint j1 12")[-1].startswith("OK move_joint")
