"""The vision-servo protocol: transitions, torn writes, lost doorbells, peer death.

The robot side is ``hal.bit3.protocol``; its peer is the emulated vision computer's own
implementation of docs/bit3.md (``emulators.vision_protocol``), so every exchange here is two
independent readings of the spec talking to each other.

The stateful test gives each side its own port onto one shared buffer. A side's writes may
be held back and applied word by word while the other side reads (a torn, half-written
record), doorbells may be lost, and either side may die at any point, leaving its last write
half done forever. Invariants: the robot never acts on a command that the vision side did
not send complete (and never twice); no side stays in REQUESTED/ENDING beyond its timeout;
a side whose peer died is back in IDLE (holding) within peer_timeout_s.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from collections.abc import Callable

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, precondition, rule

from emulators.bit3 import Bit3Board, Bit3Link, Bit3RemotePort
from emulators.crate import Crate
from emulators.vision_protocol import EndReason as VisionEndReason
from emulators.vision_protocol import VisionServer, VisionState, VisionTimeouts
from hal.bit3 import Bit3Driver, BufferMemory, ProtocolError
from hal.bit3.protocol import (
    LAYOUT_SIZE,
    OFF_COMMAND,
    EndReason,
    Record,
    RobotState,
    Timeouts,
    VisionServoClient,
    _limit,
    format_layout,
)

T = Timeouts(peer_timeout_s=0.1, accept_timeout_s=0.2, ending_timeout_s=0.05)
VT = VisionTimeouts(peer_timeout_s=0.1, ending_timeout_s=0.05)  # the vision side's, the same values


def _pair(accept=None):
    buf = bytearray(LAYOUT_SIZE)
    mem = BufferMemory(buf)
    format_layout(mem)
    robot = VisionServoClient(mem, T)
    vision = VisionServer(mem, VT, accept=accept)
    return buf, robot, vision


def _run(robot, vision, t0: float, t1: float, dt: float = 0.008):
    t = t0
    while t < t1 - 1e-12:
        t += dt
        robot.step(t)
        vision.step(t)
    return t


# --- records -------------------------------------------------------------------------------
def test_record_accepts_only_complete_versions() -> None:
    buf = bytearray(64)
    w = Record(BufferMemory(buf), 0, 8)
    r = Record(BufferMemory(buf), 0, 8)
    assert r.read() is None  # never written
    w.write(b"ABCDEFGH")  # version 1, slot 1 (bytes 20..39)
    assert r.read() == (1, b"ABCDEFGH")
    w.write(b"abcdefgh")  # version 2, slot 0
    assert r.read() == (2, b"abcdefgh")
    buf[20:24] = struct.pack(">I", 3)  # the writer has begun version 3 in slot 1 ...
    assert r.read() == (2, b"abcdefgh")  # ... the reader keeps the complete version 2
    buf[24:28] = b"XYZW"
    buf[36:40] = struct.pack(">I", 3)  # SEQ_END matches but the payload/CRC are half written
    assert r.read() == (2, b"abcdefgh")
    buf[4:8] = b"!!!!"  # corrupt slot 0 too: nothing complete left
    assert r.read() is None


@given(start=st.integers(0, 0xFFFFFFFF), n=st.integers(1, 6))
def test_record_sequence_survives_wrap_around(start: int, n: int) -> None:
    buf = bytearray(64)
    w = Record(BufferMemory(buf), 0, 4)
    w.seq = start
    for i in range(n):
        seq = w.write(struct.pack(">I", i))
    assert Record(BufferMemory(buf), 0, 4).read() == (seq, struct.pack(">I", n - 1))


def test_layout_must_be_formatted_before_the_endpoints_start() -> None:
    with pytest.raises(ProtocolError, match="format"):
        VisionServoClient(BufferMemory(bytearray(LAYOUT_SIZE)))


# --- transitions ---------------------------------------------------------------------------
def test_request_accept_command_and_robot_end() -> None:
    _, robot, vision = _pair()
    task = robot.request(0.0)
    assert robot.state is RobotState.REQUESTED
    vision.step(0.001)
    assert vision.state is VisionState.TRACKING and vision.task_id == task
    assert robot.step(0.002) is None and robot.state is RobotState.SERVOING
    sent = vision.send(0.003, (0.001, -0.002, 0.0005), (0.0, 0.01, 0.0))
    cmd = robot.step(0.004)
    assert cmd is not None and (cmd.task_id, cmd.cmd_no, cmd.dp, cmd.drot) == (task, 1, sent.dp, sent.drot)
    assert robot.step(0.005) is None  # the same command is never returned twice
    robot.end(0.006)
    assert robot.state is RobotState.ENDING and robot.holding
    vision.step(0.007)
    assert vision.state is VisionState.IDLE and vision.end_reason is VisionEndReason.PEER_ENDED
    robot.step(0.008)
    assert robot.state is RobotState.IDLE and robot.end_reason is EndReason.REQUESTED_END


def test_vision_ends_the_task() -> None:
    _, robot, vision = _pair()
    robot.request(0.0)
    _run(robot, vision, 0.0, 0.02)
    assert robot.active
    vision.end(0.021, VisionEndReason.TARGET_REACHED)
    assert vision.send(0.021, (1e-3, 0, 0)) is None  # no commands once ending
    robot.step(0.022)
    assert robot.state is RobotState.IDLE and robot.end_reason is EndReason.PEER_ENDED
    vision.step(0.023)
    assert vision.state is VisionState.IDLE and vision.end_reason is VisionEndReason.TARGET_REACHED
    assert vision.peer is not None


def test_refused_task_returns_robot_to_idle() -> None:
    _, robot, vision = _pair(accept=lambda kind: kind == 1)
    robot.request(0.0, task_kind=7)
    _run(robot, vision, 0.0, 0.02)
    assert robot.state is RobotState.IDLE and robot.end_reason is EndReason.REFUSED
    robot.request(0.03, task_kind=1)
    _run(robot, vision, 0.03, 0.05)
    assert robot.active and vision.tracking


def test_silent_vision_gives_accept_or_peer_timeout() -> None:
    _, robot, _ = _pair()
    robot.request(0.0)
    t = 0.0
    while robot.state is RobotState.REQUESTED:
        t += 0.008
        robot.step(t)
    assert robot.end_reason is EndReason.PEER_TIMEOUT
    # the first step sees the (old) heartbeat; stale peer_timeout_s after that
    assert T.peer_timeout_s < t <= 0.008 + T.peer_timeout_s + 0.008 + 1e-9


def test_live_but_unresponsive_vision_gives_accept_timeout() -> None:
    _, robot, vision = _pair()
    robot.request(0.0)
    t = 0.0
    while robot.state is RobotState.REQUESTED and t < 1:
        t += 0.008
        vision._write_status()  # heartbeat advances, but the vision side never looks
        robot.step(t)
    assert robot.end_reason is EndReason.ACCEPT_TIMEOUT
    assert t <= T.accept_timeout_s + 0.008 + 1e-9


def test_vision_dies_while_servoing_robot_holds_within_peer_timeout() -> None:
    _, robot, vision = _pair()
    robot.request(0.0)
    t = _run(robot, vision, 0.0, 0.05)
    assert robot.active
    died = t
    while robot.state is not RobotState.IDLE:
        t += 0.008
        assert robot.step(t) is None
    assert robot.end_reason is EndReason.PEER_TIMEOUT and robot.holding
    assert t - died <= T.peer_timeout_s + 2 * 0.008


def test_robot_dies_vision_returns_to_idle() -> None:
    _, robot, vision = _pair()
    robot.request(0.0)
    t = _run(robot, vision, 0.0, 0.05)
    died = t
    while vision.state is not VisionState.IDLE:
        t += 0.01
        vision.step(t)
    assert vision.end_reason is VisionEndReason.PEER_TIMEOUT
    assert t - died <= T.peer_timeout_s + 0.02


def test_non_finite_command_ends_the_task() -> None:
    _, robot, vision = _pair()
    robot.request(0.0)
    _run(robot, vision, 0.0, 0.02)
    vision.send(0.021, (math.nan, 0.0, 0.0))
    assert robot.step(0.022) is None
    assert robot.state is RobotState.IDLE and robot.end_reason is EndReason.BAD_COMMAND


def test_oversized_command_is_scaled_to_the_step_limit() -> None:
    _, robot, vision = _pair()
    robot.max_step_m = 0.005
    robot.request(0.0)
    _run(robot, vision, 0.0, 0.02)
    vision.send(0.021, (0.03, 0.04, 0.0))
    cmd = robot.step(0.022)
    assert cmd.clamped and math.isclose(math.hypot(*cmd.dp), 0.005, rel_tol=1e-6)
    assert math.isclose(cmd.dp[0] / cmd.dp[1], 0.75, rel_tol=1e-6)


def test_stale_command_from_a_previous_task_is_ignored() -> None:
    _, robot, vision = _pair()
    robot.request(0.0)
    _run(robot, vision, 0.0, 0.02)
    vision.send(0.021, (0.001, 0, 0))
    robot.end(0.022)
    _run(robot, vision, 0.022, 0.05)
    robot.request(0.06)
    _run(robot, vision, 0.06, 0.08)
    assert robot.active and robot.commands == 0


def test_robot_restart_continues_task_numbering() -> None:
    buf, robot, vision = _pair()
    robot.request(0.0)
    _run(robot, vision, 0.0, 0.02)
    robot2 = VisionServoClient(BufferMemory(buf), T)  # robot computer rebooted
    assert robot2.state is RobotState.IDLE
    _run(robot2, vision, 0.02, 0.04)
    assert vision.state is VisionState.IDLE
    task = robot2.request(0.05)
    assert task == robot.task_id + 1
    _run(robot2, vision, 0.05, 0.07)
    assert robot2.active


def test_request_while_busy_is_a_protocol_error() -> None:
    _, robot, _ = _pair()
    robot.request(0.0)
    with pytest.raises(ProtocolError):
        robot.request(0.001)


def test_link_down_through_the_driver_ends_the_task_with_link_error() -> None:
    link = Bit3Link(0x1000)
    remote = Bit3RemotePort(link)
    remote.power_on()
    crate = Crate()
    card = Bit3Board("bit3", link, window_base=0x400000)
    crate.install(card, base=0xC000, space="A16")
    drv = Bit3Driver(crate, 0xC000, 0x400000, window_size=0x1000)
    format_layout(drv.memory())
    robot = VisionServoClient(drv.memory(), T, ring=drv.ring_doorbell)
    vision = VisionServer(remote.memory, VT, ring=remote.ring)
    bells: list[int] = []
    remote.on_doorbell(bells.append)
    robot.request(crate.now())
    _run(robot, vision, 0.0, 0.03)
    assert robot.active and bells  # the request rang the vision side
    card.inject("link_down")
    assert robot.step(0.04) is None
    assert robot.state is RobotState.IDLE and robot.end_reason is EndReason.LINK_ERROR
    t = 0.04
    while vision.state is not VisionState.IDLE:  # the vision side sees the robot go silent
        t += 0.01
        vision.step(t)
    assert vision.end_reason is VisionEndReason.PEER_TIMEOUT
    card.clear_fault("link_down")
    drv.reset_link()
    robot.request(t)
    _run(robot, vision, t, t + 0.03)
    assert robot.active


# --- stateful: random interleavings, torn writes, lost doorbells, peer death -----------------
class Port:
    """One side's view of the shared buffer; its writes may be queued and land word by word."""

    def __init__(self, buf: bytearray) -> None:
        self.buf = buf
        self.pending: deque[tuple[int, bytes]] = deque()
        self.defer = False
        self.peer: Port | None = None  #: the other side, whose writes may land during our reads
        self.interleave: deque[int] = deque()  #: words of the peer's writes landing before each read
        self.lap: Callable[[], None] | None = None  #: the peer writes a whole new version (k < 0)

    def read(self, offset: int, size: int) -> bytes:
        if self.peer is not None and self.interleave:
            k = self.interleave.popleft()
            if k < 0 and self.lap is not None:
                self.lap()  # the writer finishes and starts a whole new version mid-read
            else:
                self.peer.flush(k)  # the writer progresses mid-read
        return bytes(self.buf[offset : offset + size])

    def write(self, offset: int, data: bytes) -> None:
        for i in range(0, len(data), 4):
            self.pending.append((offset + i, data[i : i + 4]))
        if not self.defer:
            self.flush()

    def flush(self, k: int | None = None) -> None:
        n = len(self.pending) if k is None else min(k, len(self.pending))
        for _ in range(n):
            off, word = self.pending.popleft()
            self.buf[off : off + 4] = word


class ProtocolMachine(RuleBasedStateMachine):
    @initialize(defer=st.booleans(), start_servoing=st.booleans())
    def setup(self, defer: bool, start_servoing: bool = False) -> None:
        self.buf = bytearray(LAYOUT_SIZE)
        format_layout(BufferMemory(self.buf))
        self.rport, self.vport = Port(self.buf), Port(self.buf)
        self.rport.peer, self.vport.peer = self.vport, self.rport
        self.rport.lap = self._vision_sends_mid_read
        self.bells: list[tuple[str, int]] = []
        self.robot = VisionServoClient(self.rport, T, ring=lambda c: self.bells.append(("vision", c)))
        self.accepting = True
        self.vision = VisionServer(self.vport, VT, ring=lambda c: self.bells.append(("robot", c)),
                                        accept=lambda kind: self.accepting)
        self.rport.defer = self.vport.defer = defer
        self.t = 0.0
        self.alive = {"robot": True, "vision": True}
        self.first_step_after_death: dict[str, float | None] = {"robot": None, "vision": None}
        self.active_since = {"robot": 0.0, "vision": 0.0}
        self.sent: dict[tuple[int, int], tuple] = {}
        self.received: set[tuple[int, int]] = set()
        if start_servoing:  # many runs should start mid-task
            self.robot_request()
            for _ in range(3):
                self.tick(0.004, 30, 30, (0.001, 0.0, 0.0))
            assert self.robot.active

    @rule(dt=st.floats(0.0005, 0.03))
    def advance(self, dt: float) -> None:
        self.t += dt

    # --- robot side --------------------------------------------------------------------
    @rule(dt=st.floats(0.001, 0.02), land_v=st.integers(0, 30), land_r=st.integers(0, 30),
          dp=st.tuples(*[st.floats(-0.05, 0.05)] * 3), during=st.lists(st.integers(-1, 4), max_size=16))
    def tick(self, dt: float, land_v: int, land_r: int, dp, during: list[int] = ()) -> None:
        """Both sides run once (the common case); the other side's writes land partly, also
        between the individual reads of a record."""
        self.t += dt
        if self.alive["vision"]:
            self.vision_step(land_r, True, dp)
        if self.alive["robot"]:
            self.robot_step(land_v, during)

    @precondition(lambda self: self.alive["robot"])
    @rule(land=st.integers(0, 14), during=st.lists(st.integers(-1, 4), max_size=16))
    def robot_step(self, land: int, during: list[int] = ()) -> None:
        if self.alive["vision"]:
            self.vport.flush(land)  # the vision side is mid-write while the robot reads
            self.rport.interleave = deque(during)
        self.rport.flush()  # the previous write finished before new work starts
        before = self.robot.state
        cmd = self.robot.step(self.t)
        self.rport.interleave.clear()
        if before is RobotState.IDLE and self.robot.state is not RobotState.IDLE:
            self.active_since["robot"] = self.t
        if cmd is not None:
            key = (cmd.task_id, cmd.cmd_no)
            assert self.robot.state is RobotState.SERVOING and cmd.task_id == self.robot.task_id
            assert key in self.sent, f"robot acted on a command that was never sent complete: {cmd}"
            assert key not in self.received, f"robot acted twice on {key}"
            dp, drot = self.sent[key]
            assert cmd.dp == _limit(dp, self.robot.max_step_m)[0]
            assert cmd.drot == _limit(drot, self.robot.max_rot_rad)[0]
            self.received.add(key)
        self._after_step("robot", "vision")

    @precondition(lambda self: self.alive["robot"] and self.robot.state is RobotState.IDLE)
    @rule()
    def robot_request(self) -> None:
        self.rport.flush()
        self.robot.request(self.t)
        self.active_since["robot"] = self.t

    @precondition(lambda self: self.alive["robot"])
    @rule()
    def robot_end(self) -> None:
        self.rport.flush()
        self.robot.end(self.t)

    @precondition(lambda self: self.alive["robot"])
    @rule(theta=st.lists(st.floats(-3, 3), min_size=1, max_size=8))
    def robot_publish(self, theta: list[float]) -> None:
        self.rport.flush()
        self.robot.publish_joints(theta, self.t)

    # --- vision side -------------------------------------------------------------------
    @precondition(lambda self: self.alive["vision"])
    @rule(land=st.integers(0, 14), send=st.booleans(), dp=st.tuples(*[st.floats(-0.05, 0.05)] * 3))
    def vision_step(self, land: int, send: bool, dp) -> None:
        if self.alive["robot"]:
            self.rport.flush(land)
        self.vport.flush()
        before = self.vision.state
        self.vision.step(self.t)
        if send:
            sent = self.vision.send(self.t, dp)
            if sent is not None:
                self.sent[(sent.task_id, sent.cmd_no)] = (sent.dp, sent.drot)
        if before is VisionState.IDLE and self.vision.state is not VisionState.IDLE:
            self.active_since["vision"] = self.t
        tel = self.vision.telemetry()
        if tel is not None:
            assert all(math.isfinite(x) for x in tel.theta)
        self._after_step("vision", "robot")

    @precondition(lambda self: self.alive["vision"])
    @rule(dp=st.tuples(*[st.floats(-0.05, 0.05)] * 3), drot=st.tuples(*[st.floats(-0.2, 0.2)] * 3))
    def vision_send(self, dp, drot) -> None:
        self.vport.flush()
        sent = self.vision.send(self.t, dp, drot)
        if sent is not None:
            self.sent[(sent.task_id, sent.cmd_no)] = (sent.dp, sent.drot)

    def _vision_sends_mid_read(self) -> None:
        if self.alive["vision"]:
            self.vport.flush()
            sent = self.vision.send(self.t, (0.002, -0.001, 0.003))
            if sent is not None:
                self.sent[(sent.task_id, sent.cmd_no)] = (sent.dp, sent.drot)

    @precondition(lambda self: self.alive["vision"])
    @rule()
    def vision_end(self) -> None:
        self.vport.flush()
        self.vision.end(self.t, VisionEndReason.TARGET_REACHED)

    @rule(accepting=st.booleans())
    def vision_policy(self, accepting: bool) -> None:
        self.accepting = accepting

    # --- the medium --------------------------------------------------------------------
    @rule(side=st.sampled_from(["robot", "vision"]), k=st.integers(1, 6))
    def partial_write_lands(self, side: str, k: int) -> None:
        if self.alive[side]:
            (self.rport if side == "robot" else self.vport).flush(k)

    @precondition(lambda self: self.bells)
    @rule(deliver=st.booleans())
    def doorbell(self, deliver: bool) -> None:
        to, code = self.bells.pop(0)
        if deliver and self.alive[to]:
            (self.robot if to == "robot" else self.vision).notify(code)

    @precondition(lambda self: all(self.alive.values()))
    @rule(side=st.sampled_from(["robot", "vision"]), land=st.integers(0, 6))
    def die(self, side: str, land: int) -> None:
        port = self.rport if side == "robot" else self.vport
        port.flush(land)  # part of the last write lands; the rest never will
        port.pending.clear()
        port.peer = None
        self.alive[side] = False

    # --- invariants --------------------------------------------------------------------
    def _after_step(self, me: str, peer: str) -> None:
        ep = self.robot if me == "robot" else self.vision
        if ep.state in (RobotState.ENDING, VisionState.ENDING) and ep.state.name == "ENDING":
            assert self.t - ep.state_since <= T.ending_timeout_s + 1e-9
        if me == "robot" and ep.state is RobotState.REQUESTED:
            assert self.t - ep.state_since <= T.accept_timeout_s + 1e-9
        if not self.alive[peer]:
            if self.first_step_after_death[me] is None:
                self.first_step_after_death[me] = self.t
            start = max(self.first_step_after_death[me], self.active_since[me])
            if self.t - start > T.peer_timeout_s + 1e-9:
                assert ep.state.name == "IDLE", f"{me} stuck in {ep.state.name} after its peer died"

    @invariant()
    def safe_states(self) -> None:
        if not hasattr(self, "robot"):
            return
        # the robot moves only while SERVOING; a robot that is not servoing holds
        assert self.robot.holding == (self.robot.state is not RobotState.SERVOING)
        assert self.vision.state in tuple(VisionState)


ProtocolMachine.TestCase.settings = settings(
    max_examples=150, stateful_step_count=60, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
TestProtocolStateMachine = ProtocolMachine.TestCase
TestProtocolStateMachine.pytestmark = [pytest.mark.slow]  # ≈ 25 s on the 2-core machine: make test runs it


class QuickProtocolMachine(ProtocolMachine):
    """The same model, fewer examples: the fast subset (make test-fast) keeps a stateful run."""


QuickProtocolMachine.TestCase.settings = settings(
    max_examples=40, stateful_step_count=60, deadline=None, suppress_health_check=[HealthCheck.too_slow]
)
TestQuickProtocolStateMachine = QuickProtocolMachine.TestCase


def test_the_stateful_model_can_reach_servoing_and_deliver_commands() -> None:
    """Guard against a vacuous model: a plain run through the same ports delivers commands."""
    buf = bytearray(LAYOUT_SIZE)
    format_layout(BufferMemory(buf))
    rp, vp = Port(buf), Port(buf)
    robot, vision = VisionServoClient(rp, T), VisionServer(vp, VT)
    robot.request(0.0)
    got = []
    for i in range(1, 20):
        vision.step(i * 0.005)
        vision.send(i * 0.005, (0.001 * i, 0, 0))
        c = robot.step(i * 0.005 + 0.001)
        if c:
            got.append(c.cmd_no)
    assert len(got) >= 15
    assert OFF_COMMAND % 4 == 0
