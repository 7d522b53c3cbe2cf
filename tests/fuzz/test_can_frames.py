"""Fuzzing the CAN plant node's and the controller link's frame handlers (hypothesis).

Inputs: arbitrary frames (any 11- or 29-bit identifier, 0–64 payload bytes, remote and error
frames) and structurally valid frames of every message in ``vmehil.dbc`` whose fields take any
value their bits can hold (out of the declared range, NaN and infinite floats, the right or a
wrong boot id and session). Each frame goes through the same entry point a received frame does:
``PlantNode.handle`` for the node; for the link, a second bus on its ``virtual`` channel sends it
and ``CanPlantLink._pump`` reads it (the receive path of every exchange). No thread, no wall
clock: the node's clock is a fake one.

Properties:

* no exception escapes the node; the link raises only :class:`PlantLinkError` (its reported safe
  stop), and only for a frame that decodes as a plant frame reporting that condition;
* a frame the codec refuses is counted (``CodecCounters``) and changes nothing else;
* a decodable frame that is not the session owner's CONTROL/SYNC/CMD is counted (refused or
  dropped) and obeyed in nothing: the node's commands, plant, session and step count stay;
* the plant stays finite, and the link's answers are finite and of its session only.

The example count comes from the hypothesis profile (``python -m tests.fuzz --n N``), not from
these tests.
"""

from __future__ import annotations

import itertools
from typing import Any

import can
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from emulators.can.bus import Endpoint, open_bus
from emulators.can.can_plant_link import CONTROLLER_IDS, CanPlantLink
from emulators.can.codec import CanCodec, CodecCounters
from emulators.can.dbc import CONTROL_RESET
from emulators.can.node import PLANT_IDS, PlantNode, node_spec
from emulators.plant import Plant
from emulators.plant_link import PlantLinkError

SPEC = node_spec("jpl-arm")
N = SPEC.n_joints
PERIOD, DELAY = SPEC.period_s, SPEC.delay_s
CODEC = CanCodec()  # parsed once; each example gets fresh counters
PROBE = CanCodec()  # the test's own decoder: what the handlers' codec should make of a frame
OWNER, STRANGER = 0x5A17, 0x33C4  # controller boot ids: the node's session owner, another controller
NODE_BOOT, SESSION = 0x0BEE, 1  # the node's boot id and the session it gave the link
_chan = itertools.count()
MESSAGES = sorted(CODEC.db.messages, key=lambda m: m.frame_id)
KNOWN_IDS = [m.frame_id for m in MESSAGES]
_PLANT_KINDS = ("SENS", "TRUTH", "PLANT_STATUS", "HEARTBEAT_PLANT", "PLANT_SESSION")

FUZZ = settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large], deadline=None)


# --- strategies --------------------------------------------------------------------------------
def _kind(fid: int) -> str:
    kind, _ = CODEC._kind_of(fid)
    return kind or "?"


@st.composite
def raw_frames(draw) -> can.Message:
    """Any frame a bus can deliver: identifier, length and payload arbitrary."""
    extended = draw(st.booleans())
    fid = draw(st.integers(0, 0x1FFFFFFF) if extended else st.one_of(st.integers(0, 0x7FF), st.sampled_from(KNOWN_IDS)))
    data = draw(st.binary(max_size=64))
    return can.Message(arbitration_id=fid, data=data, is_extended_id=extended, is_fd=len(data) > 8,
                       is_remote_frame=draw(st.booleans()) if not data else False,
                       is_error_frame=draw(st.integers(0, 15)) == 0)


def _field(draw, sig, interesting: list[int]) -> Any:
    if sig.is_float:
        return draw(st.one_of(st.sampled_from([PERIOD, DELAY, 0.0, -0.0]), st.floats(width=64)))
    lo = -(2 ** (sig.length - 1)) if sig.is_signed else 0
    hi = 2 ** (sig.length - 1) - 1 if sig.is_signed else 2**sig.length - 1
    special = [v for v in [lo, hi, 0, 1, *interesting] if lo <= v <= hi]
    return draw(st.one_of(st.sampled_from(special), st.integers(lo, hi)))


_INTERESTING = {
    "BootId": [OWNER, STRANGER, NODE_BOOT], "BootIdLow": [OWNER & 0xFF, STRANGER & 0xFF, NODE_BOOT & 0xFF],
    "Owner": [OWNER, STRANGER], "RefusedBoot": [OWNER, STRANGER], "Tick": [OWNER, STRANGER, 0, 1],
    "Session": [SESSION, SESSION + 1], "NJoints": [N], "Command": [0, 1, 2, 3], "Seed": [0, 5],
    "Seq": [0, 1], "ResetAck": [0, 1], "FreeRunning": [0], "StepError": [0],
}


@st.composite
def valid_frames(draw) -> can.Message:
    """A frame of a DBC message with the right length; each field any value its bits hold."""
    msg = draw(st.sampled_from(MESSAGES))
    values = {s.name: _field(draw, s, _INTERESTING.get(s.name, [])) for s in msg.signals}
    data = msg.encode(values, scaling=False, padding=False, strict=False)
    return can.Message(arbitration_id=msg.frame_id, data=data, is_extended_id=False, is_fd=msg.is_fd)


frames = st.lists(st.one_of(raw_frames(), valid_frames()), min_size=1, max_size=25)


# --- the node ----------------------------------------------------------------------------------
class Clock:
    def __init__(self) -> None:
        self.t = 10.0

    def __call__(self) -> float:
        return self.t


def _node(*, free_running: bool) -> tuple[PlantNode, Clock]:
    """A node whose session belongs to OWNER (its RESET acknowledged), with the real jpl-arm plant."""
    CODEC.counters = CodecCounters()
    clock = Clock()
    node = PlantNode(Endpoint(open_bus("virtual", f"fuzz-node-{next(_chan)}"), PLANT_IDS),
                     lambda s: Plant.from_config(SPEC.table, seed=s), N, free_running=free_running,
                     period_s=PERIOD, delay_s=DELAY, command_timeout_s=0.2, codec=CODEC, names=SPEC.names,
                     clock=clock, boot_id=NODE_BOOT)
    node.handle(CODEC.frame("CONTROL", Command=CONTROL_RESET, Seed=5, NJoints=N, BootId=OWNER))
    assert node.session_owner == OWNER
    return node, clock


def _from_owner(kind: str, raw: dict[str, Any]) -> bool:
    if kind == "CMD":
        return int(raw["BootIdLow"]) == OWNER & 0xFF
    return kind in ("SYNC", "CONTROL") and int(raw["BootId"]) == OWNER


def _snapshot(node: PlantNode) -> tuple:
    return ({k: v.copy() for k, v in node.cmd_raw.items()}, node.plant, node.counters.steps, node.session_owner,
            node.session_no, node.seed)


def _same(a: tuple, b: tuple) -> bool:
    return (all(np.array_equal(a[0][k], b[0][k]) for k in a[0]) and a[1] is b[1] and a[2:] == b[2:])


def _plant_finite(node: PlantNode) -> bool:
    p = node.plant
    return bool(np.isfinite(p.joint_angle()).all() and np.isfinite(p.joint_speed()).all()
                and np.isfinite(p.i).all() and np.isfinite(p.time_s))


def _check_node(ms: list[can.Message], *, free_running: bool) -> None:
    node, clock = _node(free_running=free_running)
    try:
        for m in ms:
            clock.t += PERIOD / 2
            before = _snapshot(node)
            dropped, refused = node.dropped_total(), node.counters.refused
            f = PROBE.try_decode(m)
            node.handle(m)  # must not raise
            if f is None:  # refused by the codec: counted, nothing else
                assert node.dropped_total() == dropped + 1
                assert _same(before, _snapshot(node))
            elif f.kind in _PLANT_KINDS:  # another plant's frame: counted, ignored
                assert node.dropped_total() == dropped + 1 and _same(before, _snapshot(node))
            elif f.kind in ("CMD", "SYNC", "CONTROL") and not _from_owner(f.kind, f.raw):
                # the owner is never silent here (the fake clock moves 4 ms a frame and every
                # example starts with its RESET), so no stranger's RESET may be accepted either
                assert node.counters.refused == refused + 1
                assert _same(before, _snapshot(node)), f"a stranger's {f.kind} was obeyed: {f.raw}"
            elif f.kind == "HEARTBEAT_CONTROLLER":
                assert _same(before, _snapshot(node))
            if free_running:
                node.step(node.counters.steps, PERIOD, DELAY)
            assert node.counters.steps >= before[2]
            assert _plant_finite(node)
            node.check_command_timeout()  # the timeout path on whatever state the frames left
    finally:
        node.close()


@FUZZ
@given(frames)
def test_the_lockstep_node_survives_any_frames_and_obeys_only_its_session_owner(ms):
    _check_node(ms, free_running=False)


@FUZZ
@given(frames)
def test_the_free_running_node_survives_any_frames_and_obeys_only_its_session_owner(ms):
    _check_node(ms, free_running=True)


# --- the link ----------------------------------------------------------------------------------
def _link() -> tuple[CanPlantLink, can.BusABC]:
    """A lockstep link whose RESET a node (boot NODE_BOOT) acknowledged with session SESSION."""
    chan = f"fuzz-link-{next(_chan)}"
    CODEC.counters = CodecCounters()
    link = CanPlantLink(Endpoint(open_bus("virtual", chan), CONTROLLER_IDS), SPEC.names, seed=5, codec=CODEC,
                        boot_id=OWNER, answer_timeout_s=0.0, heartbeat_timeout_s=3600.0)
    bus = open_bus("virtual", chan)
    bus.send(CODEC.frame("PLANT_STATUS", Tick=OWNER, BootId=NODE_BOOT, NJoints=N, ResetAck=1, Session=SESSION))
    assert link._pump(0.0) and link.session == SESSION and link.peer_boot == NODE_BOOT
    link.connected = True
    return link, bus


def _sensors():
    from emulators.plant import PlantCommand

    return Plant.from_config(SPEC.table, seed=1).step_period(PlantCommand.idle(N), PERIOD, DELAY)


_SENSORS = _sensors()


def _answer_frames(tick: int) -> list[can.Message]:
    """A proper answer of our session (so the fuzzed frames meet a link with answers flowing)."""
    s = _SENSORS
    out = CODEC.sensor_frames(CODEC.sensors_raw(s), tick, s.truth, boot_id=NODE_BOOT)
    return [*out, CODEC.frame("PLANT_STATUS", Tick=tick, BootId=NODE_BOOT, NJoints=N, Session=SESSION)]


@st.composite
def answers(draw) -> list[can.Message]:
    """A whole answer (SENS, TRUTH, then PLANT_STATUS) whose status is ours or nearly: another
    session, another node, a reset acknowledgement, a step error, the wrong tick; joints missing."""
    tick = draw(st.integers(0, 2))
    frames = _answer_frames(tick)[:-1]
    if draw(st.booleans()):
        frames = draw(st.lists(st.sampled_from(frames), max_size=len(frames)))
    status = CODEC.frame("PLANT_STATUS", Tick=draw(st.sampled_from([tick, tick + 1, OWNER])),
                         BootId=draw(st.sampled_from([NODE_BOOT, NODE_BOOT ^ 1])),
                         NJoints=draw(st.sampled_from([N, 1])),
                         Session=draw(st.sampled_from([SESSION, 0, SESSION + 1, 15])),
                         ResetAck=draw(st.sampled_from([0, 0, 1])), StepError=draw(st.sampled_from([0, 0, 0, 1])))
    return [*frames, status]


link_frames = st.lists(st.one_of(raw_frames().map(lambda m: [m]), valid_frames().map(lambda m: [m]), answers()),
                       min_size=1, max_size=12).map(lambda groups: [m for g in groups for m in g])


def _finite(s: Any) -> bool:
    return bool(np.isfinite(s.pot_v).all() and np.isfinite(s.tach_v).all() and np.isfinite(s.imon_v).all())


@FUZZ
@given(link_frames, st.booleans())
def test_the_link_survives_any_frames_and_takes_only_its_sessions_answers(ms, with_answer):
    link, bus = _link()
    try:
        if with_answer:
            for m in _answer_frames(0):
                bus.send(m)
            while link._pump(0.0):
                pass
            assert len(link._fresh) == 1
        link._fresh.clear()
        for m in ms:
            f = PROBE.try_decode(m)
            refused, sorted_before = _codec_refused(link), _statuses_sorted(link)
            fresh_before = len(link._fresh)
            bus.send(m)
            try:
                got = link._pump(0.0)
            except PlantLinkError as e:  # a reported safe stop: only for a plant frame saying so
                assert f is not None, f"{type(e).__name__} for a frame the codec refuses: {e}"
                assert f.kind in ("PLANT_STATUS", "HEARTBEAT_PLANT", "PLANT_SESSION"), (f.kind, e)
                return
            if not got:  # our own identifiers: the endpoint filters them out (a looped-back frame)
                assert not m.is_extended_id and m.arbitration_id in CONTROLLER_IDS and not m.is_error_frame
                continue
            if f is None:
                assert _codec_refused(link) == refused + 1
            elif f.kind == "PLANT_STATUS" and not f.raw["ResetAck"]:
                # every answer is sorted once: ours (complete), incomplete, or not our session's
                assert _statuses_sorted(link) == sorted_before + 1
                if len(link._fresh) > fresh_before:
                    assert (int(f.raw["Session"]), int(f.raw["BootId"])) == (SESSION, NODE_BOOT)
            else:
                assert len(link._fresh) == fresh_before  # nothing else makes an answer
            assert link.session == SESSION and link.peer_boot == NODE_BOOT  # no frame moves our session
            assert all(_finite(s) for _, s in link._fresh)
    finally:
        link.close()
        bus.shutdown()


def _codec_refused(link: CanPlantLink) -> int:
    c = link.codec.counters
    return c.unknown_id + c.wrong_length + c.undecodable + c.out_of_range


def _statuses_sorted(link: CanPlantLink) -> int:
    # other_boot: a status of another boot id, dropped before it is sorted (one frame proves no restart)
    c = link.counters
    return c.other_session + c.other_boot + c.incomplete + len(link._fresh)
