"""`home J` and `jog J SPEED_DEG_S` on the console (issue #32), on the emulated jpl-arm driven by a
live loop in lockstep: homing through the console's calibration job, status's homed=, a rig that
requires homing refusing moves with ERR NOT_HOMED; jogs with their deadman and bounds, checked
against the plant's truth."""

from __future__ import annotations

import math

import numpy as np
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


@pytest.fixture
def arm(tmp_path):
    """jpl-arm powered up with j1 at 150° (its soft limit max_deg = 163°, the hard stop 165°)."""
    system = build_emulated_rig(None, seed=0, initial_deg=[150.0, 0, 0, 0, 0, 0, 34.377])
    loop = build_loop(system, motion=Motion((WaitMove(0.0),), "hold", "<test>"), n_ticks=0)
    loop.start()
    runner = LockstepRunner(system, loop)
    console = start_console("loop://", loop, runner=runner, calibration=tmp_path / "cal.toml",
                            announce=lambda _: None)
    drv = Driver(loop, console, console.transport.write, tap_poll(console), step=runner.tick)
    runner.run(25)
    yield system, loop, runner, drv
    console.close()
    system.close()


def _true_deg(system, j: int = 0) -> float:
    return math.degrees(float(system.truth()["theta_joint"][j]))


def test_the_jog_deadman_stops_the_joint_unless_renewed(arm):
    system, loop, runner, drv = arm
    t = loop.period_s
    start = _true_deg(system)
    reply = drv.ask("jog j1 -10")
    assert reply[-1].startswith("OK jog joint=j1 speed_deg_s=-10 limited=0 deadman_s=0.5 started=1"), reply
    runner.run(round(1.5 / t))  # not renewed: 0.5 s at -10°/s (5°), then to rest
    moved = _true_deg(system) - start
    assert -6.0 < moved < -4.0, moved
    rest = _true_deg(system)
    runner.run(round(0.5 / t))
    assert abs(_true_deg(system) - rest) < 0.05  # the plant is at rest: the jog stopped
    assert loop.sequencer.finished and loop.fault is None
    # renewed every 0.25 s it goes on: 2 s at -10°/s
    start = _true_deg(system)
    for _ in range(8):
        assert drv.ask("jog j1 -10")[-1].startswith("OK jog")
        runner.run(round(0.25 / t))
    assert _true_deg(system) - start < -15.0


def test_a_jog_toward_a_soft_limit_stops_before_it(arm):
    system, loop, runner, drv = arm
    t = loop.period_s
    reply = drv.ask("jog j1 50")  # beyond the 20°/s limit: clamped
    assert "speed_deg_s=20 limited=1" in reply[-1], reply
    peak = -math.inf
    for _ in range(16):  # 4 s of renewed jogging into the limit (13° away)
        drv.ask("jog j1 50")
        for _ in range(round(0.25 / t)):
            runner.tick()
            peak = max(peak, _true_deg(system))
    # the soft limit is max_deg = 163.01° (jpl-arm.toml): the joint never reached it; its target
    # rests 1° inside (servo.jog.LIMIT_ALLOWANCE_DEG), the joint within the loop's hold band of that
    assert peak < 163.01, peak
    assert 161.0 < _true_deg(system) < 163.01
    assert loop.fault is None  # no soft_limit stop


def test_a_jog_toward_an_obstacle_stops_short_of_it_and_the_next_jog_says_why(arm):
    system, loop, runner, drv = arm
    t = loop.period_s
    # a box beside the arm, which stands at j1 = 150° (links radial at the shoulder's 0.30 m)
    assert drv.ask("obstacle add shelf -0.9 0.65 0.2 -0.5 0.9 0.4")[-1].startswith("OK obstacle")
    bounds = loop.plan_context.bounds
    replies = []
    for _ in range(12):  # 3 s at -10°/s, renewed: it would turn j1 through 30°
        replies.append(drv.ask("jog j1 -10")[-1])
        for _ in range(round(0.25 / t)):
            runner.tick()
            truth = np.asarray(system.truth()["theta_joint"], float)
            assert not bounds.collisions_at(truth), np.degrees(truth)
    # every ask lands on a known tick (Driver.ask waits for the console to take the line before it
    # ticks), so the first refusal is the next jog's, saying why the last one stopped
    refused = [r for r in replies if r.startswith("ERR")]
    assert refused and refused[0].startswith("ERR COLLISION jog stopped: link") and "obstacle shelf" in refused[0]
    assert 140.0 < _true_deg(system) < 150.0 and loop.fault is None


def test_home_of_a_joint_whose_pot_is_not_calibrated_says_why_once(rig):
    # the fixture calibrated j1's pot only: j2 cannot choose its index
    _system, _loop, _runner, drv, out = rig
    before = out.read_bytes()
    end = drv.ask("home j2", max_ticks=20)[-1]
    assert end.startswith("ERR STATE home: j2: its pot is not calibrated"), end
    assert "CalibrationAbort" not in end and "home home" not in end and "left unchanged" in end
    assert out.read_bytes() == before
