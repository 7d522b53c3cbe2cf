"""The console's ``move_to X Y Z [ROLL PITCH YAW]`` (docs/console.md, docs/cartesian.md): the tool
to a point of the arm's base frame; out of reach answered ``ERR REACH`` before anything moves. A
7-joint simulated loop (jpl-arm's joint count, the default ArmModel) over loop://."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hal.kinematics import ArmModel, rotation_rpy
from servo.scene import Scene
from servo.trajectory import JointLimits, MotionBounds, PlanContext
from tests.support.console import Driver, tap_poll, until
from tests.support.fakes import make_loop
from vmehil.console.server import Console, open_transport

NAMES = ["j1", "j2", "j3", "j4", "j5", "j6", "hand"]
ARM = ArmModel()


@pytest.fixture
def drv():
    loop = make_loop(7, names=NAMES)
    bounds = MotionBounds(tuple(NAMES), np.full(7, math.radians(-150.0)), np.full(7, math.radians(150.0)),
                          ARM, Scene())
    loop.plan_context = PlanContext(JointLimits.make(7, math.radians(30.0)), bounds=bounds)
    console = Console(loop, open_transport("loop://")).start()
    yield Driver(loop, console, console.transport.write, tap_poll(console))
    console.close()


def test_move_to_puts_the_tool_at_the_point_with_the_default_hand(drv) -> None:
    reply = drv.ask("move_to 0.8 0.1 0.3")
    assert reply[-1].startswith("OK move_to duration_s="), reply
    until(lambda: drv.loop.sequencer.finished, drv.loop, drv.console, max_ticks=4000, pause_s=0.0)
    end = drv.loop.sequencer.current.end
    np.testing.assert_allclose(ARM.tool_position(end), [0.8, 0.1, 0.3], atol=1e-9)
    assert ARM.hand_rotation(end)[2, 0] == pytest.approx(0.0, abs=1e-9)  # level


def test_move_to_with_an_orientation_turns_the_hand(drv) -> None:
    reply = drv.ask("move_to 0.9 0 0 0 90 0 approach=0.05")
    assert reply[-1].startswith("OK move_to"), reply
    until(lambda: drv.loop.sequencer.finished, drv.loop, drv.console, max_ticks=6000, pause_s=0.0)
    end = drv.loop.sequencer.current.end
    np.testing.assert_allclose(ARM.tool_position(end), [0.9, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(ARM.hand_rotation(end), rotation_rpy(0.0, math.pi / 2, 0.0), atol=1e-9)


def test_move_to_beyond_reach_is_refused_with_err_reach(drv) -> None:
    reply = drv.ask("move_to 1.6 0 0.3")
    assert reply == ["ERR REACH move refused: move 1: target [1.600, 0.000, 0.300] m cannot be reached: beyond "
                     "reach: the wrist 1.350 m from the shoulder, the arm reaches 1.150 m"]
    assert drv.loop.sequencer.finished  # nothing started


def test_move_to_needs_all_three_angles_or_none(drv) -> None:
    assert drv.ask("move_to 0.8 0 0.3 10 20")[0].startswith("ERR ARGS move_to X Y Z [ROLL PITCH YAW]")
    assert drv.ask("move_to 0.8 0 1e9")[0].startswith("ERR VALUE move_to: X Y Z must be finite")


def test_move_to_settle_adds_the_fine_positioning_phase_and_refuses_a_bad_tolerance(drv) -> None:
    plain = drv.ask("move_to 0.8 0.1 0.3")[-1]
    until(lambda: drv.loop.sequencer.finished, drv.loop, drv.console, max_ticks=4000, pause_s=0.0)
    settled = drv.ask("move_to 0.8 0.1 0.3 settle=1")[-1]
    assert settled.startswith("OK move_to duration_s="), settled
    # the same point (already there: a zero-length move) plus the phase's 3 s (docs/cartesian.md)
    d_plain = float(plain.split("duration_s=")[1].split()[0])
    d_settled = float(settled.split("duration_s=")[1].split()[0])
    assert d_settled >= 3.0 and d_settled < d_plain + 3.0 + 1e-6
    assert "settle must be a tolerance" in drv.ask("move_to 0.8 0.1 0.3 settle=0.01")[-1]
