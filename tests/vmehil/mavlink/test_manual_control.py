"""MANUAL_CONTROL jogs the joints (issue #32): axis x, y, z, r, s, t, aux1-6 → joints 1-12, ±1000 =
± the joint's velocity limit, INT16_MAX = unused; each message renews the jog's 0.5 s deadman.
Over loopback UDP against the emulated jpl-arm in lockstep; the plant's truth says what moved."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from servo.motion import Motion, WaitMove
from servo.runner import LockstepRunner
from vmehil.mavlink.client import Client
from vmehil.mavlink.endpoint import MavlinkEndpoint, free_udp_port
from vmehil.mavlink.manual_control import AXIS_UNUSED, axis_speeds
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

U = AXIS_UNUSED


def _msg(**kw):
    base = {"x": U, "y": U, "z": U, "r": U, "s": U, "t": U, "enabled_extensions": 0,
            **{f"aux{i}": U for i in range(1, 7)}}
    return SimpleNamespace(**{**base, **kw})


def test_axes_map_to_joints_in_order_as_fractions_of_their_velocity_limits():
    vmax = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0])
    assert axis_speeds(_msg(x=500, r=-1000), vmax) == {0: 0.5, 3: -4.0}
    assert axis_speeds(_msg(y=15, z=2000), vmax) == {1: 0.0, 2: 3.0}  # dead zone; clamped to full stick
    # the extension axes count only when enabled: s (bit 0), aux1 (bit 2) → joints 5 and 7
    assert axis_speeds(_msg(s=1000, aux1=-500), vmax) == {}
    assert axis_speeds(_msg(s=1000, aux1=-500, enabled_extensions=0b101), vmax) == {4: 5.0, 6: -3.5}


@pytest.fixture
def arm():
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, motion=Motion((WaitMove(0.0),), "hold", "<test>"), n_ticks=0)
    loop.start()
    runner = LockstepRunner(system, loop)
    port = free_udp_port()
    ep = MavlinkEndpoint(loop, f"udpin:127.0.0.1:{port}")
    runner.after_tick.append(ep.after_tick)
    client = Client(port)
    client.hello()
    runner.run(25)
    yield system, loop, runner, ep, client
    client.close()
    ep.close()
    system.close()


def _true_deg(system, j: int) -> float:
    return math.degrees(float(system.truth()["theta_joint"][j]))


def _send(client, **axes) -> None:
    a = {"x": U, "y": U, "z": U, "r": U, **axes}
    client.conn.mav.manual_control_send(1, a["x"], a["y"], a["z"], a["r"], 0)


def test_manual_control_jogs_a_joint_and_the_deadman_stops_it_when_the_messages_stop(arm):
    system, loop, runner, ep, client = arm
    t = loop.period_s
    start = _true_deg(system, 0)
    _send(client, x=500)  # j1 at half its 20°/s limit
    client.wait(lambda: loop.tick_count > 0 and not loop.sequencer.finished, runner.tick)
    runner.run(round(1.5 / t))  # no more messages: 0.5 s at 10°/s (5°), then to rest
    moved = _true_deg(system, 0) - start
    assert 4.0 < moved < 6.5, moved
    rest = _true_deg(system, 0)
    runner.run(round(0.5 / t))
    assert abs(_true_deg(system, 0) - rest) < 0.05 and loop.sequencer.finished
    # y → j2, sent every 0.2 s for 1.6 s: it keeps moving (−1000: −20°/s, 32° in 1.6 s) until its
    # soft limit (min_deg = −18.05°) stops it, the target 1° inside
    for _ in range(8):
        _send(client, y=-1000)
        runner.run(round(0.2 / t))
    assert -18.05 < _true_deg(system, 1) < -16.0
    assert loop.fault is None and ep.stats.errors == []
    assert any(src == "mavlink" and msg.startswith("jog from MANUAL_CONTROL") for _, src, msg in loop.log)
