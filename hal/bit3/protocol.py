"""The vision-servo protocol over the BIT3 shared (dual-port) memory.

The robot's endpoint, :class:`VisionServoClient`: a pure state machine driven by explicit
``step(now_s)`` calls (no threads, no clocks inside; the ``vservo`` trajectory object drives it
every servo tick), reading and writing through a :class:`hal.shm.Memory`. The vision
computer's endpoint is not here: it runs on the other crate, and the emulated one
(``emulators.vision_protocol``) is its own implementation of docs/bit3.md.

Memory layout (byte offsets from the protocol base, big-endian; ``u32`` unsigned, ``f32`` /
``f64`` IEEE 754)::

    0x000 MAGIC    u32  0x56534D31 ("VSM1")      written by format_layout()
    0x004 VERSION  u32  1
    0x008 SIZE     u32  0x200 (bytes of the layout)
    0x010 ROBOT_STATUS   record, robot → vision  (2 slots × 44 bytes; 32-byte payload)
    0x070 VISION_STATUS  record, vision → robot  (2 slots × 44 bytes; 32-byte payload)
    0x0D0 COMMAND        record, vision → robot  (2 slots × 52 bytes; 40-byte payload)
    0x140 TELEMETRY      record, robot → vision  (2 slots × 60 bytes; 48-byte payload)

A *record* is double-buffered: two slots, each a seqlock ``SEQ_BEGIN u32 | payload | CRC32
u32 | SEQ_END u32``. Version n goes to slot n % 2: the writer writes SEQ_BEGIN = n, then
payload and CRC (zlib CRC-32 of the big-endian n and the payload), then SEQ_END = n last.
The reader reads SEQ_END, payload and CRC, then SEQ_BEGIN of each slot and takes the newest
slot with SEQ_BEGIN == SEQ_END and a matching CRC; a slot being written is skipped, and the
other slot still holds the previous complete version. A command is acted on only when its
sequence number has advanced (32-bit wrap-around compare), so a half-written or repeated
command is never executed.

Payloads::

    ROBOT_STATUS   state u32, task_id u32, heartbeat u32, end_reason u32,
                   task_kind u32, max_step_m f32, max_rot_rad f32, reserved u32
    VISION_STATUS  state u32, task_id u32, heartbeat u32, end_reason u32,
                   frames u32, commands u32, reserved u32 ×2
    COMMAND        task_id u32, cmd_no u32, flags u32, frame_ms u32,
                   dx dy dz f32 (m), drx dry drz f32 (rad) — end-effector (camera) frame
    TELEMETRY      tick u32, n_joints u32, time_s f64, theta[8] f32 (rad)

Heartbeats are each side's status-record counter, incremented every step; a side that sees
the peer's heartbeat unchanged for ``peer_timeout_s`` (its own time) declares the peer dead.
Doorbells are only hints (``ring`` is called after a new command or a state change); the
protocol polls and never depends on them.
"""

from __future__ import annotations

import enum
import math
import struct
import zlib
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass

from hal.bit3.errors import Bit3Error, ProtocolError
from hal.shm import Memory

MAGIC = 0x56534D31
VERSION = 1
LAYOUT_SIZE = 0x200
OFF_MAGIC, OFF_VERSION, OFF_SIZE = 0x000, 0x004, 0x008
OFF_ROBOT_STATUS = 0x010
OFF_VISION_STATUS = 0x070
OFF_COMMAND = 0x0D0
OFF_TELEMETRY = 0x140
MAX_JOINTS = 8

_ROBOT_STATUS = struct.Struct(">IIIIIffI")
_VISION_STATUS = struct.Struct(">IIIIIIII")
_COMMAND = struct.Struct(">IIII6f")
_TELEMETRY = struct.Struct(">IId8f")

DOORBELL_STATE = 0x0001  #: doorbell code: a side changed state
DOORBELL_COMMAND = 0x0002  #: doorbell code: a new command is in the mailbox

FLAG_TARGET_VISIBLE = 0x1  #: COMMAND.flags: the target is in the image
FLAG_CONVERGED = 0x2  #: COMMAND.flags: the vision system considers the target reached


class RobotState(enum.IntEnum):
    IDLE = 0  #: not servoing; hold position
    REQUESTED = 1  #: asked the vision system for a task; hold position
    SERVOING = 2  #: following vision commands
    ENDING = 3  #: ending the task, waiting for the vision side to stop; hold position


class VisionState(enum.IntEnum):
    IDLE = 0  #: not serving a task
    TRACKING = 2  #: accepted the task, sending commands
    ENDING = 3  #: ending the task, waiting for the robot to acknowledge


class EndReason(enum.IntEnum):
    """Why the last task ended (written in each side's status record)."""

    NONE = 0
    REQUESTED_END = 1  #: this side's user called end()
    PEER_ENDED = 2  #: the peer ended the task
    PEER_TIMEOUT = 3  #: the peer's heartbeat stopped for peer_timeout_s
    ACCEPT_TIMEOUT = 4  #: the vision side did not accept within accept_timeout_s
    REFUSED = 5  #: the vision side refused the task
    LINK_ERROR = 6  #: an access to the shared memory failed (BIT3 link down / BERR)
    BAD_COMMAND = 7  #: a command with non-finite values or from another task
    TARGET_REACHED = 8  #: vision: the target is reached
    TARGET_LOST = 9  #: vision: the target left the image
    ENDING_TIMEOUT = 10  #: the peer did not acknowledge the end within ending_timeout_s
    SHUTDOWN = 11  #: the process is exiting


@dataclass(frozen=True)
class Timeouts:
    """Protocol timeouts in seconds (each side measures them on its own clock).

    A side whose peer dies is back in IDLE (safe) at most ``peer_timeout_s`` after its first
    step that follows the peer's last heartbeat (or ``ending_timeout_s`` after it began ending).
    """

    peer_timeout_s: float = 0.25
    accept_timeout_s: float = 0.5
    ending_timeout_s: float = 0.1


@dataclass(frozen=True)
class EeCommand:
    """One end-effector-relative motion increment from the vision system.

    Attributes:
        task_id: the task it belongs to.
        cmd_no: the vision side's command number (consecutive within a task).
        dp: translation increment (dx, dy, dz) in metres, in the end-effector (camera) frame.
        drot: rotation increment (rx, ry, rz) in radians about the end-effector axes.
        flags: FLAG_TARGET_VISIBLE | FLAG_CONVERGED.
        frame_ms: the vision side's frame timestamp in ms (mod 2^32), for latency reports.
        clamped: True if the robot side scaled it down to its step limits.
    """

    task_id: int
    cmd_no: int
    dp: tuple[float, float, float]
    drot: tuple[float, float, float] = (0.0, 0.0, 0.0)
    flags: int = FLAG_TARGET_VISIBLE
    frame_ms: int = 0
    clamped: bool = False


@dataclass(frozen=True)
class VisionStatus:
    state: int
    task_id: int
    heartbeat: int
    end_reason: int
    frames: int
    commands: int


# --- records -----------------------------------------------------------------------------
def _crc(seq: int, payload: bytes) -> int:
    return zlib.crc32(payload, zlib.crc32(struct.pack(">I", seq)))


def seq_newer(a: int, b: int) -> bool:
    """True if sequence number ``a`` is after ``b`` (32-bit wrap-around)."""
    return 0 < ((a - b) & 0xFFFFFFFF) < 0x80000000


class Record:
    """A double-buffered, seqlocked record at ``offset``.

    Two slots, each ``SEQ_BEGIN u32 | payload | CRC32 u32 | SEQ_END u32``. Version ``n`` goes
    to slot ``n % 2``, so while the writer fills one slot the other holds the previous
    complete version and a reader never starves. The reader takes the newest slot that is
    complete (SEQ_BEGIN == SEQ_END != 0 and the CRC matches).
    """

    def __init__(self, memory: Memory, offset: int, payload_size: int) -> None:
        if offset % 4 or payload_size % 4:
            raise ValueError("records must be word aligned")
        self.memory = memory
        self.offset = offset
        self.payload_size = payload_size
        self.seq = 0  #: the last sequence number written by this side

    @property
    def slot_size(self) -> int:
        return 12 + self.payload_size

    @property
    def size(self) -> int:
        return 2 * self.slot_size

    def write(self, payload: bytes) -> int:
        """Write a new version; returns its sequence number. Three memory writes, in order."""
        if len(payload) != self.payload_size:
            raise ValueError(f"payload of {len(payload)} bytes, record holds {self.payload_size}")
        seq = (self.seq + 1) & 0xFFFFFFFF or 1
        m, o = self.memory, self.offset + (seq & 1) * self.slot_size
        m.write(o, struct.pack(">I", seq))
        m.write(o + 4, payload + struct.pack(">I", _crc(seq, payload)))
        m.write(o + 8 + self.payload_size, struct.pack(">I", seq))
        self.seq = seq
        return seq

    def _read_slot(self, o: int) -> tuple[int, bytes] | None:
        m, n = self.memory, self.payload_size
        seq_end = struct.unpack(">I", m.read(o + 8 + n, 4))[0]
        body = m.read(o + 4, n + 4)
        seq_begin = struct.unpack(">I", m.read(o, 4))[0]
        if seq_begin != seq_end or seq_end == 0:
            return None
        payload, crc = body[:n], struct.unpack(">I", body[n:])[0]
        if crc != _crc(seq_end, payload):
            return None
        return seq_end, payload

    def read(self) -> tuple[int, bytes] | None:
        """(seq, payload) of the newest complete version, or ``None`` if there is none."""
        a = self._read_slot(self.offset)
        b = self._read_slot(self.offset + self.slot_size)
        if a is None or b is None:
            return a or b
        return a if seq_newer(a[0], b[0]) else b

    def resume(self) -> None:
        """Continue the sequence already in memory (after a restart of the writer)."""
        seqs = [struct.unpack(">I", self.memory.read(self.offset + i * self.slot_size, 4))[0] for i in (0, 1)]
        self.seq = seqs[0] if seq_newer(seqs[0], seqs[1]) else seqs[1]


def format_layout(memory: Memory) -> None:
    """Zero the protocol area and write MAGIC/VERSION/SIZE. Done once by the side that
    creates the shared memory (the robot side in this project), before either endpoint runs."""
    memory.write(0, bytes(LAYOUT_SIZE))
    memory.write(OFF_VERSION, struct.pack(">II", VERSION, LAYOUT_SIZE))
    memory.write(OFF_MAGIC, struct.pack(">I", MAGIC))


def check_layout(memory: Memory) -> None:
    """Raise :class:`ProtocolError` unless the memory holds a formatted layout of this version."""
    magic, version, size = struct.unpack(">III", memory.read(0, 12))
    if magic != MAGIC:
        raise ProtocolError(f"no vision-servo layout in the shared memory (magic 0x{magic:08X}, "
                            f"expected 0x{MAGIC:08X}); the robot side must format it first")
    if version != VERSION or size != LAYOUT_SIZE:
        raise ProtocolError(f"vision-servo layout version {version} size {size}; this side speaks "
                            f"version {VERSION} size {LAYOUT_SIZE}")


def _records(memory: Memory) -> dict[str, Record]:
    return {
        "robot": Record(memory, OFF_ROBOT_STATUS, _ROBOT_STATUS.size),
        "vision": Record(memory, OFF_VISION_STATUS, _VISION_STATUS.size),
        "command": Record(memory, OFF_COMMAND, _COMMAND.size),
        "telemetry": Record(memory, OFF_TELEMETRY, _TELEMETRY.size),
    }


class _Endpoint:
    """Records, heartbeat bookkeeping and doorbell hints of an endpoint."""

    def __init__(self, memory: Memory, timeouts: Timeouts, ring: Callable[[int], None] | None) -> None:
        self.memory = memory
        self.timeouts = timeouts
        self.ring = ring
        check_layout(self.memory)
        self.rec = _records(self.memory)
        for r in self.rec.values():
            r.resume()
        self.heartbeat = 0
        self.task_id = 0
        self.end_reason = EndReason.NONE
        self.state_since = 0.0
        self._peer_hb: int | None = None
        self._peer_seen_at = 0.0
        self.doorbells = 0  #: doorbells received (hints only)
        self.link_errors = 0
        self.torn_reads = 0

    def notify(self, code: int = 0) -> None:
        """Doorbell from the peer (call from the interrupt handler). Only counted: the next
        ``step`` polls the memory anyway, so a lost doorbell changes nothing."""
        self.doorbells += 1

    def _note_peer(self, hb: int, now: float) -> None:
        if hb != self._peer_hb:
            self._peer_hb = hb
            self._peer_seen_at = now

    def _stale(self, now: float) -> bool:
        return now - self._peer_seen_at > self.timeouts.peer_timeout_s

    def _ring(self, code: int) -> None:
        if self.ring is not None:
            self.ring(code)


class VisionServoClient(_Endpoint):
    """Robot side of the protocol.

    State machine (see docs/bit3.md for the full table)::

        IDLE --request()--> REQUESTED --vision TRACKING--> SERVOING
        REQUESTED --vision refused / ended / accept or peer timeout--> IDLE
        SERVOING --end()--> ENDING --vision not tracking / ending timeout--> IDLE
        SERVOING --vision ENDING/IDLE or peer timeout or bad command--> IDLE
        any --memory access fails (Bit3Error)--> IDLE (LINK_ERROR)

    Every state but SERVOING means "hold position". ``step(now)`` returns a new
    :class:`EeCommand` only in SERVOING, only once per complete command of the current task.

    Args:
        memory: the shared memory (``Bit3Driver.memory()`` on the robot's bus).
        timeouts: protocol timeouts.
        max_step_m, max_rot_rad: per-command limits; larger commands are scaled down.
        ring: called with a doorbell code after a state change (e.g. ``driver.ring_doorbell``).
    """

    def __init__(
        self,
        memory: Memory,
        timeouts: Timeouts | None = None,
        *,
        max_step_m: float = 0.01,
        max_rot_rad: float = 0.05,
        ring: Callable[[int], None] | None = None,
    ) -> None:
        super().__init__(memory, timeouts or Timeouts(), ring)
        self.state = RobotState.IDLE
        self.max_step_m = float(max_step_m)
        self.max_rot_rad = float(max_rot_rad)
        self.task_kind = 1
        self.peer: VisionStatus | None = None
        self._last_cmd_seq = 0
        self._tick = 0
        self.commands = 0  #: commands returned by step()
        self.missed = 0  #: commands overwritten before this side read them
        self.clamped = 0
        prev = self.rec["robot"].read()
        if prev is not None:  # continue task numbering after a restart
            self.task_id = _ROBOT_STATUS.unpack(prev[1])[1]
        self._safe_write_status()

    # --- user API ------------------------------------------------------------------------
    @property
    def active(self) -> bool:
        """True while the robot follows vision commands (SERVOING)."""
        return self.state is RobotState.SERVOING

    @property
    def holding(self) -> bool:
        """True in every state where the robot must hold position."""
        return self.state is not RobotState.SERVOING

    def request(self, now: float, task_kind: int = 1) -> int:
        """Ask the vision system to start a servoing task; returns the new task id.
        Only from IDLE (raises :class:`ProtocolError` otherwise)."""
        if self.state is not RobotState.IDLE:
            raise ProtocolError(f"request() in state {self.state.name}: end the current task first")
        self.task_id = (self.task_id + 1) & 0xFFFFFFFF or 1
        self.task_kind = task_kind
        self.end_reason = EndReason.NONE
        self._enter(RobotState.REQUESTED, now)
        self._peer_seen_at = now  # the vision side gets peer_timeout_s to show life
        self._safe_write_status(DOORBELL_STATE)
        return self.task_id

    def end(self, now: float, reason: EndReason = EndReason.REQUESTED_END) -> None:
        """End the task (REQUESTED/SERVOING → ENDING); no-op in IDLE or ENDING."""
        if self.state in (RobotState.REQUESTED, RobotState.SERVOING):
            self.end_reason = reason
            self._enter(RobotState.ENDING, now)
            self._safe_write_status(DOORBELL_STATE)

    def publish_joints(self, theta: Collection[float], now: float) -> None:
        """Write the TELEMETRY record (joint angles in rad, at most 8) for the vision side."""
        if len(theta) > MAX_JOINTS:
            raise ValueError(f"{len(theta)} joints; the telemetry record holds {MAX_JOINTS}")
        self._tick = (self._tick + 1) & 0xFFFFFFFF
        padded = [float(x) for x in theta] + [0.0] * (MAX_JOINTS - len(theta))
        try:
            self.rec["telemetry"].write(_TELEMETRY.pack(self._tick, len(theta), float(now), *padded))
        except Bit3Error:
            self._link_failed(now)

    def step(self, now: float) -> EeCommand | None:
        """Run the state machine once; returns a new command in SERVOING, else ``None``."""
        try:
            return self._step(now)
        except Bit3Error:
            self._link_failed(now)
            return None

    # --- internals -----------------------------------------------------------------------
    def _enter(self, state: RobotState, now: float) -> None:
        self.state = state
        self.state_since = now

    def _finish(self, now: float, reason: EndReason) -> None:
        if self.state is not RobotState.ENDING:
            self.end_reason = reason
        self._enter(RobotState.IDLE, now)

    def _link_failed(self, now: float) -> None:
        self.link_errors += 1
        if self.state is not RobotState.IDLE:
            self.end_reason = EndReason.LINK_ERROR
        self._enter(RobotState.IDLE, now)

    def _read_peer(self, now: float) -> VisionStatus | None:
        got = self.rec["vision"].read()
        if got is None:
            self.torn_reads += 1
            return None
        peer = VisionStatus(*_VISION_STATUS.unpack(got[1])[:6])
        self._note_peer(peer.heartbeat, now)
        self.peer = peer
        return peer

    def _step(self, now: float) -> EeCommand | None:
        before = self.state
        peer = self._read_peer(now)
        cmd = None
        # ``mine`` is the peer status when it is for our task (so the type checker sees it is not None)
        mine = peer if peer is not None and peer.task_id == self.task_id else None
        ours = mine is not None
        if self.state is RobotState.REQUESTED:
            if mine is not None and mine.state == VisionState.TRACKING:
                self._enter(RobotState.SERVOING, now)
                self._last_cmd_seq = self._current_cmd_seq()
            elif mine is not None and mine.state == VisionState.IDLE and mine.end_reason != EndReason.NONE:
                refused = mine.end_reason == EndReason.REFUSED
                self._finish(now, EndReason.REFUSED if refused else EndReason.PEER_ENDED)
            elif mine is not None and mine.state == VisionState.ENDING:
                self._finish(now, EndReason.PEER_ENDED)
            elif self._stale(now):
                self._finish(now, EndReason.PEER_TIMEOUT)
            elif now - self.state_since > self.timeouts.accept_timeout_s:
                self._finish(now, EndReason.ACCEPT_TIMEOUT)
        elif self.state is RobotState.SERVOING:
            if self._stale(now):
                self._finish(now, EndReason.PEER_TIMEOUT)
            elif peer is not None and (not ours or peer.state != VisionState.TRACKING):
                self._finish(now, EndReason.PEER_ENDED)
            else:
                cmd = self._read_command(now)
        elif self.state is RobotState.ENDING:
            tracking = peer is not None and ours and peer.state == VisionState.TRACKING
            if (peer is not None and not tracking) or self._stale(now):
                self._enter(RobotState.IDLE, now)
            elif now - self.state_since > self.timeouts.ending_timeout_s:
                self.end_reason = EndReason.ENDING_TIMEOUT
                self._enter(RobotState.IDLE, now)
        self._write_status(DOORBELL_STATE if self.state is not before else None)
        return cmd

    def _current_cmd_seq(self) -> int:
        rec = self.rec["command"]
        got = rec.read()
        if got is not None:
            return got[0]
        rec.resume()  # both slots being written (cannot last): take the newest begun version
        return rec.seq

    def _read_command(self, now: float) -> EeCommand | None:
        got = self.rec["command"].read()
        if got is None:
            self.torn_reads += 1
            return None
        seq, payload = got
        if not seq_newer(seq, self._last_cmd_seq):
            return None
        gap = (seq - self._last_cmd_seq - 1) & 0xFFFFFFFF
        self._last_cmd_seq = seq
        task_id, cmd_no, flags, frame_ms, *v = _COMMAND.unpack(payload)
        if task_id != self.task_id:
            return None  # left over from an earlier task
        self.missed += gap if gap < 0x80000000 else 0
        if not all(math.isfinite(x) for x in v):
            self._finish(now, EndReason.BAD_COMMAND)
            return None
        dp, c1 = _limit(v[:3], self.max_step_m)
        drot, c2 = _limit(v[3:], self.max_rot_rad)
        self.commands += 1
        self.clamped += int(c1 or c2)
        return EeCommand(task_id, cmd_no, dp, drot, flags, frame_ms, c1 or c2)

    def _write_status(self, doorbell: int | None = None) -> None:
        self.heartbeat = (self.heartbeat + 1) & 0xFFFFFFFF
        self.rec["robot"].write(_ROBOT_STATUS.pack(
            int(self.state), self.task_id, self.heartbeat, int(self.end_reason), self.task_kind,
            self.max_step_m, self.max_rot_rad, 0))
        if doorbell is not None:
            self._ring(doorbell)

    def _safe_write_status(self, doorbell: int | None = None) -> None:
        try:
            self._write_status(doorbell)
        except Bit3Error:
            self._link_failed(self.state_since)


def _limit(v: Sequence[float], limit: float) -> tuple[tuple[float, float, float], bool]:
    n = math.sqrt(sum(x * x for x in v))
    if n > limit > 0:
        s = limit / n
        return (v[0] * s, v[1] * s, v[2] * s), True
    return (float(v[0]), float(v[1]), float(v[2])), False
