"""MANUAL_CONTROL → jog (docs/mavlink.md, "Jog with MANUAL_CONTROL").

The usual convention of the message: each axis is normalized to [−1000, 1000] (1000 = full stick),
``INT16_MAX`` (32767) marks an axis the sender does not use, and a ground station sends it
continuously (QGroundControl: 10-25 Hz) while the sticks are live — the receiver treats silence as
"sticks released". Here each axis is one joint's jog speed as a fraction of that joint's velocity
limit (``[servo] max_velocity_deg_s``):

======  =====================================  ========
axis    field (MAVLink 2)                      joint
======  =====================================  ========
x       ``x`` (pitch stick)                    1
y       ``y`` (roll stick)                     2
z       ``z`` (thrust)                         3
r       ``r`` (yaw stick)                      4
s       ``s`` (extension, enabled bit 0)       5
t       ``t`` (extension, enabled bit 1)       6
aux1-6  ``aux1``..``aux6`` (bits 2-7)          7-12
======  =====================================  ========

A value within ±:data:`DEAD_ZONE` of 0 is 0 (a stick's rest noise). Each message renews the jog's
0.5 s deadman (:mod:`servo.jog`): when the messages stop, the joints come to rest. ``buttons`` are
not used. A message whose axes are all at rest ends a running jog and starts none.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from servo.jog import jog, running_jog
from vmehil.console.commands import hold_position
from vmehil.errors import VmehilError

#: a MANUAL_CONTROL axis the sender does not use
AXIS_UNUSED = 32767
#: full stick
AXIS_FULL = 1000
#: |value| up to this is 0 (2 % of full stick)
DEAD_ZONE = 20
#: the axes in joint order, with the ``enabled_extensions`` bit that makes an extension axis valid
AXES: tuple[tuple[str, int | None], ...] = (
    ("x", None), ("y", None), ("z", None), ("r", None), ("s", 0), ("t", 1),
    ("aux1", 2), ("aux2", 3), ("aux3", 4), ("aux4", 5), ("aux5", 6), ("aux6", 7))


class JogRefused(VmehilError, RuntimeError):
    """The loop cannot jog now (stopped, a planned motion runs): the reason for the ground station."""


def axis_speeds(msg: Any, v_max_rad_s: np.ndarray) -> dict[int, float]:
    """Joint index → jog speed (rad/s) from one MANUAL_CONTROL message (see the module table)."""
    ext = int(getattr(msg, "enabled_extensions", 0) or 0)
    out: dict[int, float] = {}
    for j, (name, bit) in enumerate(AXES[: len(v_max_rad_s)]):
        if bit is not None and not ext >> bit & 1:
            continue
        raw = getattr(msg, name, AXIS_UNUSED)
        if raw is None or int(raw) == AXIS_UNUSED:
            continue
        value = int(raw)
        frac = 0.0 if abs(value) <= DEAD_ZONE else max(-1.0, min(1.0, value / AXIS_FULL))
        out[j] = frac * float(v_max_rad_s[j])
    return out


def jog_command(speeds: dict[int, float]):
    """The live command (run at a tick boundary) that jogs the loop at ``speeds``: renews or starts
    the jog; returns the speeds in force, or ``None`` when nothing was to be done (sticks at rest,
    no jog running). Raises :class:`JogRefused` when the loop cannot jog now."""
    def command(loop: Any) -> dict[int, float] | None:
        moving = any(v != 0.0 for v in speeds.values())
        if running_jog(loop) is None:
            if not moving:
                return None
            if loop.fault is not None or not loop.enabled or getattr(loop, "stopping", None) is not None:
                raise JogRefused("jog refused: the loop is not servoing (enable first)")
            if not loop.sequencer.finished:
                raise JogRefused("jog refused: a motion is running")
        got, started = jog(loop, speeds, hold_position(loop))
        if started:
            loop.note("mavlink", "jog from MANUAL_CONTROL: " + ", ".join(
                f"{loop.names[j]} {np.degrees(v):+.3g} deg/s" for j, v in got.items() if v))
        return got
    return command
