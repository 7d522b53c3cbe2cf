"""One emulated rig of B lanes from B scalar ones (batched lockstep, issue #34; hal.lanes).

:func:`stack_rigs` takes B :class:`~vmehil.rig_setup.system.EmulatedRig` built alike (the same rig
file; their own seeds, plant values and gains) and at the same point — built, before their first
tick — and stacks them part by part, bottom-up: the crate and its boards, the drivers, the plant
and its link, the harness, the drivers' joint I/O. Each part's ``from_lanes`` raises
:class:`NotImplementedError` in one line when it has no lane form (a plug-in board, a fault, a
remote plant); the batch then runs its instances one at a time.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from emulators.crate import Crate
from emulators.harness import Harness, InProcessLink
from emulators.plant import Plant
from hal.lanes import LaneSet
from servo.io import JointIO
from vmehil.rig_setup.system import EmulatedRig


def stack_rigs(systems: Sequence[EmulatedRig], lanes: LaneSet) -> EmulatedRig:
    """The lane-mode rig of ``systems`` (lane order; see the module docstring). The B scalar rigs
    are not used afterwards."""
    s0 = systems[0]
    for s in systems:
        if s.rig.name != s0.rig.name or s.rig.n_joints != s0.rig.n_joints:
            raise NotImplementedError("the instances are of different rigs")
        if s.grasp is not None:
            raise NotImplementedError("the hand's world (objects to grasp) has no lane form")
        if s.plant is None or not isinstance(s.link, InProcessLink):
            raise NotImplementedError("a plant out of process (--plant can) has no lane form")
    crate = Crate.from_lanes([s.crate for s in systems], lanes)
    plant = Plant.from_lanes([s.plant for s in systems if s.plant is not None], lanes)
    link = InProcessLink(plant, codec=s0.link.codec)  # type: ignore[attr-defined]
    harness = Harness.from_lanes([s.harness for s in systems], signals=crate.signals, link=link)

    def drivers(role: str) -> dict[str, Any]:
        out = {}
        for name, d0 in getattr(s0.io, role).items():
            out[name] = type(d0).from_lanes([getattr(s.io, role)[name] for s in systems], bus=crate)
        return out

    io = JointIO.from_lanes([s.io for s in systems], lanes, adc=drivers("adc"), dac=drivers("dac"),
                            pio=drivers("pio"), quad=drivers("quad"))
    rig = EmulatedRig(s0.rig, crate, plant, link, harness, io, s0.params, s0.seed)
    rig.late_exchanges = s0.late_exchanges
    return rig
