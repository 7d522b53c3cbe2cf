"""The vision computer's side of the vision-servo protocol, written from docs/bit3.md.

This is the emulated vision computer's own reading of the protocol spec — the memory layout,
the double-buffered seqlocked records, the state table of the vision side, heartbeats,
doorbell hints and timeouts — and deliberately not ``hal.bit3.protocol`` (the robot's side):
the two ends of the link are two implementations of one document, so a mistake in either
shows up as a disagreement on the link instead of being shared by both.

The endpoint is a pure state machine driven by ``step(now_s)`` on the vision computer's own
clock. It reads and writes its dual-port memory through any object with
``read(offset, size) -> bytes`` and ``write(offset, data)`` (``hal.shm.BufferMemory``, or a
test's port that tears writes).
"""

from __future__ import annotations

import enum
import struct
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from emulators.errors import EmulatorError


class Memory(Protocol):
    """What the endpoint needs of its dual-port memory: byte reads and writes."""

    def read(self, offset: int, size: int) -> bytes: ...

    def write(self, offset: int, data: bytes) -> None: ...


class LayoutError(EmulatorError, ValueError):
    """The memory holds no protocol layout, or one of another version."""


# --- the layout (docs/bit3.md, "Vision-servo protocol") -------------------------------------
LAYOUT_MAGIC = 0x56534D31  # "VSM1"
LAYOUT_VERSION = 1
LAYOUT_SIZE = 0x200


@dataclass(frozen=True)
class RecordLayout:
    """One record of the layout: where it is, its stated slot size, its payload fields in order
    (name, ``struct`` code: I = u32, f = f32, d = f64; all big-endian)."""

    name: str
    offset: int
    slot_size: int
    fields: tuple[tuple[str, str], ...]

    @property
    def codec(self) -> struct.Struct:
        return struct.Struct(">" + "".join(code for _, code in self.fields))

    def __post_init__(self) -> None:
        # the doc states both the slot size and the payload; they must agree (SEQ_BEGIN, CRC, SEQ_END)
        if self.codec.size + 12 != self.slot_size:
            raise ValueError(f"{self.name}: a {self.codec.size}-byte payload does not fill "
                             f"a {self.slot_size}-byte slot")


def _u32(*names: str) -> tuple[tuple[str, str], ...]:
    return tuple((n, "I") for n in names)


def _f32(*names: str) -> tuple[tuple[str, str], ...]:
    return tuple((n, "f") for n in names)


ROBOT_STATUS = RecordLayout("ROBOT_STATUS", 0x010, 44, (
    *_u32("state", "task_id", "heartbeat", "end_reason", "task_kind"),
    *_f32("max_step_m", "max_rot_rad"), *_u32("reserved")))
VISION_STATUS = RecordLayout("VISION_STATUS", 0x070, 44, _u32(
    "state", "task_id", "heartbeat", "end_reason", "frames", "commands", "reserved0", "reserved1"))
COMMAND = RecordLayout("COMMAND", 0x0D0, 52, (
    *_u32("task_id", "cmd_no", "flags", "frame_ms"), *_f32("dx", "dy", "dz", "drx", "dry", "drz")))
TELEMETRY_JOINTS = 8
TELEMETRY = RecordLayout("TELEMETRY", 0x140, 60, (
    *_u32("tick", "n_joints"), ("time_s", "d"), *_f32(*(f"theta{i}" for i in range(TELEMETRY_JOINTS)))))

FLAG_TARGET_VISIBLE = 1
FLAG_CONVERGED = 2
BELL_STATE = 1  #: doorbell code after a state change
BELL_COMMAND = 2  #: doorbell code after a new command


class RobotState(enum.IntEnum):
    IDLE = 0
    REQUESTED = 1
    SERVOING = 2
    ENDING = 3


class VisionState(enum.IntEnum):
    IDLE = 0
    TRACKING = 2
    ENDING = 3


class EndReason(enum.IntEnum):
    NONE = 0
    REQUESTED_END = 1
    PEER_ENDED = 2
    PEER_TIMEOUT = 3
    ACCEPT_TIMEOUT = 4
    REFUSED = 5
    LINK_ERROR = 6
    BAD_COMMAND = 7
    TARGET_REACHED = 8
    TARGET_LOST = 9
    ENDING_TIMEOUT = 10
    SHUTDOWN = 11


@dataclass(frozen=True)
class VisionTimeouts:
    """The vision side's timeouts (s, on its own clock; docs/bit3.md "Timeouts")."""

    peer_timeout_s: float = 0.25  #: robot heartbeat unchanged this long: the robot is dead
    ending_timeout_s: float = 0.1  #: wait this long in ENDING for the robot to acknowledge


@dataclass(frozen=True)
class SentCommand:
    """A command as written (the increments as the robot will read them: rounded to f32)."""

    task_id: int
    cmd_no: int
    dp: tuple[float, float, float]
    drot: tuple[float, float, float]
    flags: int
    frame_ms: int


@dataclass(frozen=True)
class RobotView:
    """The robot's status record as last read."""

    state: int
    task_id: int
    heartbeat: int
    end_reason: int
    task_kind: int
    max_step_m: float
    max_rot_rad: float


@dataclass(frozen=True)
class JointTelemetry:
    """The robot's TELEMETRY record: joint angles (rad) at robot time ``time_s``."""

    tick: int
    time_s: float
    theta: tuple[float, ...]


# --- layout and records ----------------------------------------------------------------------
def format_layout(memory: Memory) -> None:
    """Zero the protocol area, then write VERSION and SIZE, and MAGIC last (a reader that sees
    the magic sees a complete header)."""
    memory.write(0, bytes(LAYOUT_SIZE))
    memory.write(4, LAYOUT_VERSION.to_bytes(4, "big") + LAYOUT_SIZE.to_bytes(4, "big"))
    memory.write(0, LAYOUT_MAGIC.to_bytes(4, "big"))


def check_layout(memory: Memory) -> None:
    """Raise :class:`LayoutError` unless the memory holds this version's layout."""
    head = memory.read(0, 12)
    magic, version, size = (int.from_bytes(head[i : i + 4], "big") for i in (0, 4, 8))
    if magic != LAYOUT_MAGIC:
        raise LayoutError(f"no vision-servo layout in the shared memory (magic 0x{magic:08X}, "
                          f"expected 0x{LAYOUT_MAGIC:08X}); the robot side must format it first")
    if (version, size) != (LAYOUT_VERSION, LAYOUT_SIZE):
        raise LayoutError(f"vision-servo layout version {version} size {size}; this side speaks "
                          f"version {LAYOUT_VERSION} size {LAYOUT_SIZE}")


def _after(a: int, b: int) -> bool:
    """Sequence number ``a`` comes after ``b`` (32-bit wrap-around: less than half a lap ahead)."""
    d = (a - b) % (1 << 32)
    return d != 0 and d < (1 << 31)


def _check_word(seq: int, payload: bytes) -> int:
    return zlib.crc32(seq.to_bytes(4, "big") + payload)


class SeqlockRecord:
    """A double-buffered seqlocked record: two slots of ``SEQ_BEGIN | payload | CRC | SEQ_END``;
    version n in slot n mod 2."""

    def __init__(self, memory: Memory, layout: RecordLayout) -> None:
        self.memory = memory
        self.layout = layout
        self.codec = layout.codec
        self.start = layout.offset
        self.last_seq = 0

    def _slot(self, seq: int) -> int:
        return self.start + (seq % 2) * self.layout.slot_size

    def continue_sequence(self) -> None:
        """A writer starting on a memory with versions in it continues after the newest begun one."""
        begun = [int.from_bytes(self.memory.read(self._slot(i), 4), "big") for i in (0, 1)]
        self.last_seq = begun[0] if _after(begun[0], begun[1]) else begun[1]

    def publish(self, values: Sequence[float | int]) -> int:
        """Write the next version: SEQ_BEGIN, then payload + CRC, then SEQ_END last."""
        payload = self.codec.pack(*values)
        seq = (self.last_seq + 1) % (1 << 32) or 1
        at = self._slot(seq)
        tag = seq.to_bytes(4, "big")
        self.memory.write(at, tag)
        self.memory.write(at + 4, payload + _check_word(seq, payload).to_bytes(4, "big"))
        self.memory.write(at + 4 + len(payload) + 4, tag)
        self.last_seq = seq
        return seq

    def _complete(self, slot: int) -> tuple[int, bytes] | None:
        n = self.codec.size
        at = self.start + slot * self.layout.slot_size
        end = int.from_bytes(self.memory.read(at + 8 + n, 4), "big")
        body = self.memory.read(at + 4, n + 4)
        begin = int.from_bytes(self.memory.read(at, 4), "big")
        if begin != end or end == 0 or int.from_bytes(body[n:], "big") != _check_word(end, body[:n]):
            return None
        return end, body[:n]

    def latest(self) -> tuple[int, tuple] | None:
        """(seq, values) of the newest complete slot, or ``None``."""
        found = [c for c in (self._complete(0), self._complete(1)) if c is not None]
        if not found:
            return None
        seq, payload = found[0]
        if len(found) == 2 and _after(found[1][0], seq):
            seq, payload = found[1]
        return seq, self.codec.unpack(payload)


# --- the vision endpoint -------------------------------------------------------------------
class VisionServer:
    """The vision side's state machine (docs/bit3.md, "Vision side").

    Args:
        memory: the vision computer's dual-port memory (formatted: :func:`format_layout`).
        timeouts: peer and ending timeouts.
        accept: decides whether to serve a task of a kind (default: serve every task).
        ring: rings the robot's doorbell with a code (a hint; the protocol never needs it).
    """

    def __init__(
        self,
        memory: Memory,
        timeouts: VisionTimeouts | None = None,
        *,
        accept: Callable[[int], bool] | None = None,
        ring: Callable[[int], None] | None = None,
    ) -> None:
        check_layout(memory)
        self.timeouts = timeouts or VisionTimeouts()
        self.accept = accept
        self.ring = ring
        self._robot = SeqlockRecord(memory, ROBOT_STATUS)
        self._status = SeqlockRecord(memory, VISION_STATUS)
        self._command = SeqlockRecord(memory, COMMAND)
        self._telemetry = SeqlockRecord(memory, TELEMETRY)
        self._status.continue_sequence()
        self._command.continue_sequence()
        self.state = VisionState.IDLE
        self.state_since = 0.0
        self.task_id = 0
        self.end_reason = EndReason.NONE
        self.heartbeat = 0
        self.frames = 0
        self.commands = 0
        self.doorbells = 0  #: doorbells from the robot (counted only)
        self.torn_reads = 0  #: steps that found no complete robot status
        self.peer: RobotView | None = None
        self._cmd_no = 0
        self._answered: int | None = None  # the task last accepted or refused
        self._robot_beat: int | None = None
        self._robot_beat_at = 0.0
        self._write_status()

    @property
    def tracking(self) -> bool:
        return self.state is VisionState.TRACKING

    # --- inputs --------------------------------------------------------------------------
    def notify(self, code: int = 0) -> None:
        """A doorbell from the robot: a hint only, counted; the next step polls anyway."""
        self.doorbells += 1

    def frame(self) -> None:
        """Count a processed camera frame (VISION_STATUS.frames)."""
        self.frames = (self.frames + 1) % (1 << 32)

    def telemetry(self) -> JointTelemetry | None:
        """The robot's newest complete TELEMETRY record (``None`` while none is complete)."""
        got = self._telemetry.latest()
        if got is None:
            return None
        tick, n, time_s, *theta = got[1]
        return JointTelemetry(tick, time_s, tuple(theta[: min(n, TELEMETRY_JOINTS)]))

    # --- the state machine -----------------------------------------------------------------
    def step(self, now: float) -> VisionState:
        """Read the robot's status, take the transition the state table gives, write our
        status (heartbeat + 1) and ring after a state change. Returns the new state."""
        was = self.state
        robot = self._read_robot(now)
        on_task = (robot is not None and robot.task_id == self.task_id
                   and robot.state in (RobotState.REQUESTED, RobotState.SERVOING))
        silent = now - self._robot_beat_at > self.timeouts.peer_timeout_s
        if self.state is VisionState.IDLE and robot is not None:
            if robot.state == RobotState.IDLE:
                self._answered = None
            elif robot.state == RobotState.REQUESTED and robot.task_id != self._answered:
                self._answer(robot, now)
        elif self.state is VisionState.TRACKING:
            if silent:
                self._to_idle(now, EndReason.PEER_TIMEOUT)
            elif robot is not None and not on_task:
                self._to_idle(now, EndReason.PEER_ENDED)
        elif self.state is VisionState.ENDING:
            if (robot is not None and not on_task) or silent:
                self._to_idle(now, None)
            elif now - self.state_since > self.timeouts.ending_timeout_s:
                self._to_idle(now, EndReason.ENDING_TIMEOUT)
        self._write_status(BELL_STATE if self.state is not was else None)
        return self.state

    def send(self, now: float, dp: Sequence[float], drot: Sequence[float] = (0.0, 0.0, 0.0),
             flags: int = FLAG_TARGET_VISIBLE, frame_ms: int | None = None) -> SentCommand | None:
        """Write the next command (end-effector frame: m, rad); only while TRACKING."""
        if self.state is not VisionState.TRACKING:
            return None
        self._cmd_no = (self._cmd_no + 1) % (1 << 32)
        stamp = (int(now * 1000) if frame_ms is None else frame_ms) % (1 << 32)
        values = (self.task_id, self._cmd_no, flags, stamp, *(float(x) for x in dp), *(float(x) for x in drot))
        self._command.publish(values)
        self.commands += 1
        self._ring(BELL_COMMAND)
        as_read = self._command.codec.unpack(self._command.codec.pack(*values))[4:]
        return SentCommand(self.task_id, self._cmd_no, (as_read[0], as_read[1], as_read[2]),
                           (as_read[3], as_read[4], as_read[5]), flags, stamp)

    def end(self, now: float, reason: EndReason = EndReason.REQUESTED_END) -> None:
        """End the task: TRACKING → ENDING (no-op in other states)."""
        if self.state is VisionState.TRACKING:
            self.end_reason = reason
            self._enter(VisionState.ENDING, now)
            self._write_status(BELL_STATE)

    def shutdown(self, now: float) -> None:
        """Leave the protocol at process exit: IDLE, end reason SHUTDOWN, status written."""
        self.end_reason = EndReason.SHUTDOWN
        self._enter(VisionState.IDLE, now)
        self._write_status(BELL_STATE)

    # --- internals -----------------------------------------------------------------------
    def _read_robot(self, now: float) -> RobotView | None:
        got = self._robot.latest()
        if got is None:
            self.torn_reads += 1
            return None
        robot = RobotView(*got[1][:7])
        if robot.heartbeat != self._robot_beat:
            self._robot_beat, self._robot_beat_at = robot.heartbeat, now
        self.peer = robot
        return robot

    def _answer(self, robot: RobotView, now: float) -> None:
        self._answered = self.task_id = robot.task_id
        if self.accept is not None and not self.accept(robot.task_kind):
            self.end_reason = EndReason.REFUSED  # stays IDLE, echoing the task id
            return
        self.end_reason = EndReason.NONE
        self._cmd_no = 0
        self._enter(VisionState.TRACKING, now)
        self._robot_beat_at = now  # the robot gets a full peer timeout from the start of the task

    def _enter(self, state: VisionState, now: float) -> None:
        self.state, self.state_since = state, now

    def _to_idle(self, now: float, reason: EndReason | None) -> None:
        if reason is not None:
            self.end_reason = reason
        self._enter(VisionState.IDLE, now)

    def _write_status(self, bell: int | None = None) -> None:
        self.heartbeat = (self.heartbeat + 1) % (1 << 32)
        self._status.publish((int(self.state), self.task_id, self.heartbeat, int(self.end_reason),
                              self.frames, self.commands, 0, 0))
        if bell is not None:
            self._ring(bell)

    def _ring(self, code: int) -> None:
        if self.ring is not None:
            self.ring(code)

