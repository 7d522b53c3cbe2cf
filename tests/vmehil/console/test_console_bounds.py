"""The console and motion bounds (issue #32): a move past a soft limit is refused with ``ERR
LIMIT``, one through an obstacle with ``ERR COLLISION``, and ``obstacle add|remove|list`` edit
the scene later moves are checked against. A 7-joint simulated loop (the jpl-arm's joint count;
the arm's default geometry, links along x at 0.30 m at zero) over loop://."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hal.kinematics import ArmModel
from servo.scene import Scene
from servo.trajectory import JointLimits, MotionBounds, PlanContext
from tests.support.console import Driver, tap_poll, until
from tests.support.fakes import make_loop
from vmehil.console.protocol import parse_reply_line
from vmehil.console.server import Console, open_transport

NAMES = ["j1", "j2", "j3", "j4", "j5", "j6", "hand"]


@pytest.fixture
def drv():
    loop = make_loop(7, names=NAMES)
    bounds = MotionBounds(tuple(NAMES), np.full(7, math.radians(-90.0)), np.full(7, math.radians(90.0)),
                          ArmModel(), Scene())
    loop.plan_context = PlanContext(JointLimits.make(7, math.radians(30.0)), bounds=bounds)
    console = Console(loop, open_transport("loop://")).start()
    yield Driver(loop, console, console.transport.write, tap_poll(console))
    console.close()


def _ok(reply: list[str], name: str) -> dict[str, str]:
    assert reply[-1].startswith(f"OK {name}"), reply
    return parse_reply_line(reply[-1])[2]


def test_a_move_past_a_soft_limit_is_refused_with_err_limit(drv) -> None:
    reply = drv.ask("move [100, 0, 0, 0, 0, 0, 0]")
    # the console's lines are 7-bit: ° is written " deg"
    assert reply == ["ERR LIMIT move refused: move 1: joint j1 target 100.00 deg is past its soft limit "
                     "max_deg = 90.00 deg"]
    assert drv.loop.sequencer.finished  # nothing started
    reply = drv.ask("move_joint j3 -95")
    assert reply[0].startswith("ERR LIMIT") and "joint j3 target -95.00 deg" in reply[0]


def test_obstacles_added_on_the_console_refuse_a_move_through_them_until_removed(drv) -> None:
    # a box at x, y 0.5..0.7, z 0.2..0.4: the forearm (0.6..1.15 m out, level) passes through it
    # when the waist is at 45° (its point at 0.8 m: (0.566, 0.566, 0.30))
    assert _ok(drv.ask("obstacle add crate 0.5 0.5 0.2 0.7 0.7 0.4"), "obstacle")["obstacles"] == "1"
    listed = drv.ask("obstacle list")
    assert listed[0] == 'DATA obstacle name=crate min_m=[0.5,0.5,0.2] max_m=[0.7,0.7,0.4]'
    reply = drv.ask("move_joint 1 60")
    assert len(reply) == 1 and reply[0].startswith("ERR COLLISION move refused: move 1: link ")
    assert "hits obstacle crate at point" in reply[0]
    assert drv.ask("obstacle add crate 0 0 0 1 1 1")[0].startswith("ERR VALUE")  # the name is taken
    assert _ok(drv.ask("obstacle remove crate"), "obstacle")["obstacles"] == "0"
    assert drv.ask("obstacle remove crate")[0].startswith("ERR VALUE")
    _ok(drv.ask("move_joint 1 60"), "move_joint")
    until(lambda: drv.loop.sequencer.finished, drv.loop, drv.console, max_ticks=2000, pause_s=0.0)
    assert math.degrees(drv.loop.sequencer.current.end[0]) == pytest.approx(60.0)


def test_an_obstacle_around_the_arm_is_said_at_once(drv) -> None:
    reply = drv.ask("obstacle add post 0.2 -0.1 0 0.3 0.1 1")  # the upper arm passes through x 0.2..0.3
    assert reply[0].startswith("INFO the arm's present target puts link upper_arm in post")
    _ok(reply, "obstacle")
