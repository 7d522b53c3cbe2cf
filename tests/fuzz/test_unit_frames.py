"""Fuzzing the unit bus's frame handlers (docs/melmalec.md, "Sessions"; hypothesis).

Inputs: arbitrary frames and structurally valid frames of every ``vmehil.dbc`` message, whose
fields take any value their bits hold, with the boot ids of the session's nodes among the
interesting values — sent on a ``virtual`` unit bus before one proper round of exchange 0:

* the coordinator's side (``_Server.lockstep_round``): every unit's CMD and UNIT_SYNC follow
  the fuzzed frames; the plant is the in-process one of melmalec-16;
* a unit's side (``UnitCanLink.exchange``): the coordinator's answer (SENS, UNIT_ANSWER) follows.

SENS frames carry the low byte of their sender's boot id: only the session coordinator's count.

Properties: no exception escapes the coordinator; the unit raises only a ``PlantLinkError`` (its
reported safe stop), and only when a fuzzed frame carried the session's coordinator boot id. A
frame with no session boot id stops nothing and is counted (``other_session``) when it is a
frame the node reads; with none of the session's, the round ends as it would without them.
"""

from __future__ import annotations

import itertools
from typing import Any

import can
import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from emulators.can.codec import CanCodec
from emulators.can.dbc import ID_CMD, ID_UNIT_HEARTBEAT, ID_UNIT_SYNC, ID_UNIT_TIMING
from emulators.plant import PlantCommand, PlantSensors
from emulators.plant_link import PlantLinkError
from emulators.presets import resolve_rig
from emulators.signals import QuadratureEvents
from servo.joint_groups import rig_units
from servo.rig import load_rig
from tests.fuzz.test_can_frames import raw_frames
from vmehil.unit_controllers.coordinator import plant_link_for
from vmehil.unit_controllers.remote import CoordinatorOutcome, UnitCanLink, _Server, unit_bus

SPEC = load_rig(resolve_rig("melmalec-16"))
UNITS = rig_units(SPEC)
N = SPEC.n_joints
COORD = 0xC00D  # the session's coordinator boot id
UNIT_BOOTS = {u: 0x1100 + u for u in range(len(UNITS))}  # the session's units' boot ids
FORGED = 0xBEEF
PROBE = CanCodec()
MESSAGES = sorted(PROBE.db.messages, key=lambda m: m.frame_id)
_chan = itertools.count()
_PLANT = plant_link_for(SPEC, 0)  # one in-process plant for every example (its state moves on)

_INTERESTING = {
    "BootId": [COORD, FORGED, *UNIT_BOOTS.values()],
    "BootIdLow": [COORD & 0xFF, *(b & 0xFF for b in UNIT_BOOTS.values())],
    "UnitBootId": [*UNIT_BOOTS.values(), FORGED], "Unit": [0, 1, 2, 4, 255], "Exchange": [0, 1, 2**32 - 1],
    "Seq": [0], "Left": [0, 1], "Stopped": [0, 1], "Stop": [0, 1, 2, 3, 8], "Cause": [1, 2, 3, 9, 10],
    "State": [1, 2],
}


def _field(draw, sig, interesting: list[int]) -> Any:
    if sig.is_float:
        return draw(st.one_of(st.sampled_from([0.0, 1.0]), st.floats(width=64)))
    lo = -(2 ** (sig.length - 1)) if sig.is_signed else 0
    hi = 2 ** (sig.length - 1) - 1 if sig.is_signed else 2**sig.length - 1
    special = [v for v in [lo, hi, 0, 1, *interesting] if lo <= v <= hi]
    return draw(st.one_of(st.sampled_from(special), st.integers(lo, hi)))


@st.composite
def unit_bus_frames(draw) -> can.Message:
    """A frame of a DBC message (the unit bus's kinds twice as likely), any field value."""
    unit_kinds = [m for m in MESSAGES if m.name.startswith("UNIT_") or m.name.startswith(("CMD_J", "SENS_J"))]
    msg = draw(st.sampled_from(unit_kinds + MESSAGES))
    values = {s.name: _field(draw, s, _INTERESTING.get(s.name, [])) for s in msg.signals}
    data = msg.encode(values, scaling=False, padding=False, strict=False)
    return can.Message(arbitration_id=msg.frame_id, data=data, is_extended_id=False, is_fd=msg.is_fd)


frames = st.lists(st.one_of(raw_frames(), unit_bus_frames()), min_size=1, max_size=20)


def _decoded(ms: list[can.Message]) -> list:
    return [f for f in (PROBE.try_decode(m) for m in ms) if f is not None]


def _of_session(server: _Server, f) -> bool:
    """The test's own reading of "a unit frame of the session": its sender's boot id."""
    if f.kind == "CMD":
        return int(f.raw["BootIdLow"]) == UNIT_BOOTS[server.owner[f.joint]] & 0xFF
    return UNIT_BOOTS.get(int(f.raw["Unit"])) == int(f.raw["BootId"])


# --- the coordinator ---------------------------------------------------------------------------
@given(frames)
def test_the_coordinator_stops_on_no_frame_of_another_session(ms):
    chan = f"fuzz-units-{next(_chan)}"
    bus, sender = unit_bus("virtual", chan), unit_bus("virtual", chan)
    try:
        bus.accept = {ID_CMD + j for j in range(N)} | {ID_UNIT_SYNC, ID_UNIT_HEARTBEAT, ID_UNIT_TIMING}
        out = CoordinatorOutcome()
        server = _Server(SPEC, UNITS, bus, _PLANT, out, n_ticks=10, boot_id=COORD, timeout_s=2.0, stale_ticks=5,
                         stop_requested=lambda: False, started=dict(UNIT_BOOTS))
        for m in ms:
            sender.endpoint.send(m)
        codec = sender.codec
        for u, unit in enumerate(UNITS):  # the round every unit hands in
            raw = codec.command_raw(PlantCommand.idle(len(unit.indices)))
            sender.send_all(codec.command_frames(raw, 0, UNIT_BOOTS[u], joints=list(unit.indices)))
            sender.send("UNIT_SYNC", Exchange=0, Unit=u, BootId=UNIT_BOOTS[u])
        assert server.lockstep_round(0)  # no exception escapes
        read = [f for f in _decoded(ms) if f.kind in ("CMD", "UNIT_SYNC", "UNIT_TIMING")
                and (f.kind != "CMD" or (f.joint is not None and f.joint < N))]
        session = [f for f in read if _of_session(server, f)]
        if not session:
            assert server.stop is None and server.running == set(range(len(UNITS))), out.events
            assert out.other_session == len(read)
            assert out.exchanges == 1
    finally:
        bus.close()
        sender.close()


# --- a unit ------------------------------------------------------------------------------------
def _answer(n: int) -> PlantSensors:
    return PlantSensors(pot_v=np.full(n, 0.5), tach_v=np.zeros(n), imon_v=np.zeros(n), amp_fault=np.zeros(n, bool),
                        encoder=[QuadratureEvents(counts=3) for _ in range(n)], switching=np.zeros(n, bool), truth={})


@given(frames)
def test_a_unit_stops_on_no_frame_of_another_session(ms):
    chan = f"fuzz-unit-{next(_chan)}"
    bus, coordinator = unit_bus("virtual", chan), unit_bus("virtual", chan)
    unit = UNITS[1]
    link = UnitCanLink(bus, unit, 1, UNIT_BOOTS[1], timeout_s=2.0, session_boot=COORD, members=dict(UNIT_BOOTS))
    try:
        for m in ms:
            coordinator.endpoint.send(m)
        codec = coordinator.codec
        s = _answer(N)
        coordinator.send_all(codec.sensor_frames(codec.sensors_raw(s), 0, boot_id=COORD))
        coordinator.send("UNIT_ANSWER", Exchange=0, BootId=COORD)
        session = [f for f in _decoded(ms) if f.kind in ("UNIT_ANSWER", "UNIT_STOP") and int(f.raw["BootId"]) == COORD]
        # SENS frames of its joints with the coordinator's low byte may make the answer incomplete
        sens = [f for f in _decoded(ms) if f.kind == "SENS" and f.joint in unit.indices]
        sens_mine = [f for f in sens if int(f.raw["BootIdLow"]) == COORD & 0xFF]
        try:
            got = link.exchange(PlantCommand.idle(len(unit.indices)), SPEC.period_s, SPEC.computation_delay_s)
        except PlantLinkError as e:
            assert session or (sens_mine and e.cause == "answer_incomplete"), (type(e).__name__, e)
            return
        assert np.isfinite(got.pot_v).all()
        if not session and not sens_mine:
            assert np.allclose(got.pot_v, 0.5, atol=1e-5) and link.stop_event is None
            others = [f for f in _decoded(ms) if f.kind in ("UNIT_ANSWER", "UNIT_STOP")
                      or (f.kind == "UNIT_POS" and int(f.raw["Unit"]) in UNIT_BOOTS
                          and UNIT_BOOTS[int(f.raw["Unit"])] != int(f.raw["BootId"]))]
            others += [f for f in sens if f not in sens_mine]
            assert link.other_session == len(others)
    finally:
        bus.close()
        coordinator.close()
