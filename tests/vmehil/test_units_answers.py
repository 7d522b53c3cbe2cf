"""A free-running unit's link (vmehil.unit_controllers.remote.UnitCanLink) reading the coordinator's answers
as they come: the plant step each answer carries, and no encoder count lost with an answer the
unit never got whole. Frames are sent by the test on a `virtual` unit bus: deterministic."""

from __future__ import annotations

import itertools

import numpy as np

from emulators.can.codec import EncoderTotals
from emulators.can.dbc import ID_SENS
from emulators.plant import PlantCommand, PlantSensors
from emulators.presets import resolve_rig
from emulators.signals import QuadratureEvents
from servo.joint_groups import rig_units
from servo.rig import load_rig
from vmehil.unit_controllers.remote import UnitCanLink, unit_bus

_channels = itertools.count()


def _answer(n: int, counts: list[int]) -> PlantSensors:
    return PlantSensors(pot_v=np.zeros(n), tach_v=np.zeros(n), imon_v=np.zeros(n), amp_fault=np.zeros(n, bool),
                        encoder=[QuadratureEvents(counts=c) for c in counts], switching=np.zeros(n, bool), truth={})


def test_a_free_running_unit_gets_every_count_and_the_plant_step_of_answers_it_got_in_part() -> None:
    """After the power-up exchange the coordinator (here: the test) answers steps 1..8 with 5
    counts per joint each; of steps 3 and 6 the unit gets an incomplete answer (a SENS frame
    lost), which it drops. Its exchanges still add up to every count of steps 1..8, and each
    says the plant step of the newest whole answer it took."""
    spec = load_rig(resolve_rig("melmalec-16"))
    unit = rig_units(spec)[0]
    channel = f"units-answers-{next(_channels)}"
    coordinator, bus = unit_bus("virtual", channel), unit_bus("virtual", channel)
    link = UnitCanLink(bus, unit, 0, boot_id=7, timeout_s=1.0)
    link.free_running, link.stale_ticks = True, 50
    codec, totals, n = coordinator.codec, EncoderTotals(), spec.n_joints
    mine = list(unit.indices)
    idle = PlantCommand.idle(len(mine))

    def publish(step: int, *, lose: int | None = None) -> None:
        s = _answer(n, [5] * n)
        frames = codec.sensor_frames(codec.sensors_raw(s), step, totals=totals.add(s.encoder))
        coordinator.send_all([f for f in frames if lose is None or f.arbitration_id != ID_SENS + lose])
        coordinator.send("UNIT_ANSWER", Exchange=step, PlantStep=100 + step)

    def exchange() -> list[int]:
        s = link.exchange(idle, spec.period_s, spec.computation_delay_s)
        return [e.counts for e in s.encoder]

    try:
        publish(0)
        exchange()  # the power-up exchange (lockstep): the reference of the totals
        assert link.answer_step == 100
        got, steps = np.zeros(len(mine), int), []
        publish(1)
        link.await_first_answer()
        for step in range(2, 9):
            publish(step, lose=mine[1] if step in (3, 6) else None)
            if step % 2 == 0:
                continue  # the unit reads every other period: two answers (or one and a broken one)
            got += exchange()
            steps.append(link.answer_step)
        got += exchange()
        steps.append(link.answer_step)
        assert link.incomplete == 2
        assert got.tolist() == [5 * 8] * len(mine)  # steps 1..8: every count, the broken answers' too
        assert link.totals.recovered == 2
        assert steps == [102, 105, 107, 108]  # at 3 and 6 the newest whole answer was 2 and 5
    finally:
        link.bus.close()
        coordinator.close()
