"""The console's ``controller`` and ``filter`` commands over loop:// against a running ServoLoop
(a small simulated JointIO): listing, switching at the next tick, refusals with the guard's
reason and nothing changed."""

from __future__ import annotations

import math

import pytest

from servo.control.gains import Gains
from servo.named_controllers import ControllerChoices, NamedController
from tests.support.console import Driver, tap_poll
from tests.support.fakes import make_loop, tick
from tests.vmehil.console.test_commands import data, err, ok
from vmehil.console.server import Console, open_transport

PAPER = Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0)
STIFF = Gains(kp=200.0, kpi=10000.0, kv=60.0, kvi=2000.0)
HOT = Gains(kp=5e4, kpi=5000.0, kv=50.0, kvi=1000.0)  # unstable at 125 Hz: the guard refuses it


@pytest.fixture
def drv3():
    """Three joints, each with default and stiff; j3 also hot."""
    loop = make_loop(3)
    named = (NamedController("default", PAPER), NamedController("stiff", STIFF), NamedController("hot", HOT))
    loop.controllers = ControllerChoices((named[:2], named[:2], named), (0, 0, 0))
    loop.active_controller = [0, 0, 0]
    console = Console(loop, open_transport("loop://")).start()
    yield Driver(loop, console, console.transport.write, tap_poll(console))
    console.close()


@pytest.fixture
def drv():
    loop = make_loop(2)
    named = (NamedController("default", PAPER), NamedController("stiff", STIFF), NamedController("hot", HOT))
    loop.controllers = ControllerChoices((named[:1], named), (0, 0))
    loop.active_controller = [0, 0]
    console = Console(loop, open_transport("loop://")).start()
    yield Driver(loop, console, console.transport.write, tap_poll(console))
    console.close()


def test_controller_lists_each_joints_controllers_and_the_active_one(drv):
    r = drv.ask("controller")
    ok(r, "controller")
    rows = data(r, "controller")
    assert [(x["joint"], x["active"], x["controllers"]) for x in rows] == [
        ("j1", "default", "default"), ("j2", "default", "default,stiff,hot")]


def test_controller_use_switches_one_joint_at_the_next_tick(drv):
    r = drv.ask('controller use stiff j2')
    ok(r, "controller")
    assert data(r, "controller")[0]["active"] == "stiff"
    tick(drv.loop, drv.console, 2)
    assert drv.loop.law.gains.joint(1) == STIFF and drv.loop.law.gains.joint(0) == PAPER
    assert drv.loop.active_controller == [0, 1]


def test_controller_use_refused_by_the_guard_or_unknown_changes_nothing(drv):
    assert "unstable" in err(drv.ask("controller use hot j2"), "GAIN")
    assert "no controller 'stiff'" in err(drv.ask("controller use stiff all"), "VALUE")  # j1 has none: all or none
    err(drv.ask("controller use"), "ARGS")
    tick(drv.loop, drv.console, 2)
    assert drv.loop.law.gains.joint(1) == PAPER and drv.loop.active_controller == [0, 0]


def test_filter_sets_and_clears_the_velocity_filter_of_a_joint(drv):
    ok(drv.ask("filter j1 6"), "filter")
    tick(drv.loop, drv.console, 2)
    assert drv.loop.law.filter_hz[0] == 6.0 and math.isnan(drv.loop.law.filter_hz[1])
    assert data(drv.ask("filter j1"), "controller")[0]["velocity_filter_hz"] == "6"
    err(drv.ask("filter j1 80"), "VALUE")  # beyond the Nyquist frequency (62.5 Hz)
    ok(drv.ask("filter j1 0"), "filter")
    tick(drv.loop, drv.console, 2)
    assert not drv.loop.law.filtered.any()


def test_controller_use_takes_a_list_of_joints_and_switches_those_only(drv3):
    r = drv3.ask("controller use stiff 1,3")
    ok(r, "controller")
    assert [(x["joint"], x["active"]) for x in data(r, "controller")] == [("j1", "stiff"), ("j3", "stiff")]
    tick(drv3.loop, drv3.console, 2)
    assert drv3.loop.active_controller == [1, 0, 1]
    assert drv3.loop.law.gains.joint(0) == STIFF and drv3.loop.law.gains.joint(1) == PAPER
    assert drv3.loop.law.gains.joint(2) == STIFF
    # all or none: hot exists on j3 only, so 2,3 changes nothing
    assert "no controller 'hot'" in err(drv3.ask("controller use hot 2,3"), "VALUE")
    assert "joints are numbers" in err(drv3.ask("controller use default 1.5,2"), "VALUE")
    tick(drv3.loop, drv3.console, 2)
    assert drv3.loop.active_controller == [1, 0, 1]
