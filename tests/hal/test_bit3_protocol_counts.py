"""The vision-servo protocol's records and robot side (hal.bit3.protocol) at their edges: commands
returned, missed, clamped, torn reads, link errors, doorbells, the step limits at their edges,
the telemetry tick and padding (docs/bit3.md, "Records", "Robot side"). The vision side is the
emulated vision computer's own implementation (emulators.vision_protocol); expected values are
worked by hand."""

from __future__ import annotations

import struct

import pytest

from emulators.vision_protocol import (
    ROBOT_STATUS,
    TELEMETRY,
    VISION_STATUS,
    SeqlockRecord,
    VisionServer,
    VisionTimeouts,
)
from hal.bit3 import BufferMemory, LinkDownError, ProtocolError
from hal.bit3.protocol import (
    LAYOUT_SIZE,
    OFF_COMMAND,
    EndReason,
    Record,
    RobotState,
    Timeouts,
    VisionServoClient,
    _limit,
    check_layout,
    format_layout,
    seq_newer,
)

VISION_IDLE, VISION_TRACKING, VISION_ENDING = 0, 2, 3  # VISION_STATUS.state (docs/bit3.md)
T = Timeouts(peer_timeout_s=0.1, accept_timeout_s=0.2, ending_timeout_s=0.05)
VT = VisionTimeouts(peer_timeout_s=0.1, ending_timeout_s=0.05)


class Flaky(BufferMemory):
    """Shared memory whose accesses fail like a BIT3 link that went down, while ``down``."""

    down = False

    def read(self, offset: int, size: int) -> bytes:
        if self.down:
            raise LinkDownError("link down")
        return super().read(offset, size)

    def write(self, offset: int, data: bytes) -> None:
        if self.down:
            raise LinkDownError("link down")
        super().write(offset, data)


def _servoing(bells: list[int] | None = None) -> tuple[bytearray, Flaky, VisionServoClient, VisionServer]:
    buf = bytearray(LAYOUT_SIZE)
    mem = Flaky(buf)
    format_layout(mem)
    robot = VisionServoClient(mem, T, ring=None if bells is None else bells.append)
    vision = VisionServer(BufferMemory(buf), VT)
    robot.request(0.0)
    vision.step(0.001)
    robot.step(0.002)
    assert robot.state is RobotState.SERVOING
    return buf, mem, robot, vision


def test_step_limits_scale_the_whole_vector_only_beyond_the_limit() -> None:
    assert _limit((0.0, 0.0, 0.02), 0.01) == ((0.0, 0.0, 0.01), True)  # z alone, halved
    assert _limit((3.0, 4.0, 0.0), 5.0) == ((3.0, 4.0, 0.0), False)  # exactly at the limit
    assert _limit((1.0, 2.0, 2.0), 6.0) == ((1.0, 2.0, 2.0), False)
    assert _limit((1.0, 0.0, 0.0), 0.0) == ((1.0, 0.0, 0.0), False)  # limit 0: no limit


def test_commands_missed_and_clamped_are_counted() -> None:
    _, _, robot, vision = _servoing()
    robot.max_step_m, robot.max_rot_rad = 0.01, 0.05
    vision.send(0.003, (0.001, 0.0, 0.0), flags=3, frame_ms=1234)
    cmd = robot.step(0.004)
    assert cmd is not None and (cmd.cmd_no, cmd.flags, cmd.frame_ms, cmd.clamped) == (1, 3, 1234, False)
    assert (robot.commands, robot.missed, robot.clamped) == (1, 0, 0)
    vision.send(0.005, (0.02, 0.0, 0.0))  # overwritten before the robot reads it
    vision.send(0.006, (0.0, 0.0, 0.0), (0.0, 0.1, 0.0))  # overwritten too
    vision.send(0.007, (0.0, 0.03, 0.0))  # read: clamped by its translation
    cmd = robot.step(0.008)
    assert cmd is not None and cmd.cmd_no == 4 and cmd.clamped and cmd.dp == pytest.approx((0.0, 0.01, 0.0))
    assert (robot.commands, robot.missed, robot.clamped) == (2, 2, 1)
    vision.send(0.009, (0.0, 0.0, 0.0), (0.0, 0.0, -0.1))  # clamped by its rotation
    vision.send(0.010, (0.0, 0.0, 0.0), (0.0, 0.0, -0.1))
    cmd = robot.step(0.011)
    assert cmd is not None and cmd.clamped and cmd.drot == pytest.approx((0.0, 0.0, -0.05))
    assert (robot.commands, robot.missed, robot.clamped) == (3, 3, 2)
    vision.send(0.012, (0.001, 0.0, 0.0), (0.04, 0.0, 0.0))  # each within its own limit
    cmd = robot.step(0.013)
    assert cmd is not None and not cmd.clamped
    assert cmd.dp == pytest.approx((0.001, 0.0, 0.0)) and cmd.drot == pytest.approx((0.04, 0.0, 0.0))


def test_a_command_begun_when_servoing_starts_is_taken_once_complete() -> None:
    buf = bytearray(LAYOUT_SIZE)
    mem = BufferMemory(buf)
    format_layout(mem)
    robot = VisionServoClient(mem, T)
    vision = VisionServer(BufferMemory(buf), VT)
    robot.request(0.0)
    vision.step(0.001)
    vision.send(0.0015, (0.001, 0.0, 0.0))  # version 1 of COMMAND, slot 1, complete
    buf[OFF_COMMAND:OFF_COMMAND + 4] = struct.pack(">I", 2)  # version 2 begun in slot 0 (SEQ_BEGIN only)
    robot.step(0.002)  # SERVOING: commands up to version 1 are old
    assert robot.state is RobotState.SERVOING and robot.step(0.0025) is None
    vision.send(0.003, (0.002, 0.0, 0.0))  # version 2 written whole
    cmd = robot.step(0.004)
    assert cmd is not None and cmd.cmd_no == 2


def test_torn_command_reads_are_counted_and_return_nothing() -> None:
    buf, _, robot, _ = _servoing()
    for slot in (0, 1):  # both COMMAND slots begun but never ended
        buf[OFF_COMMAND + 52 * slot:OFF_COMMAND + 52 * slot + 4] = struct.pack(">I", 7 + slot)
    assert robot.step(0.003) is None
    assert robot.step(0.004) is None
    assert robot.torn_reads == 2 and robot.state is RobotState.SERVOING


def test_a_bad_command_and_a_link_failure_go_idle_at_that_step_s_time() -> None:
    _, mem, robot, vision = _servoing()
    vision.send(0.003, (float("inf"), 0.0, 0.0))
    assert robot.step(0.0042) is None
    assert (robot.state, robot.end_reason, robot.state_since) == (RobotState.IDLE, EndReason.BAD_COMMAND, 0.0042)
    robot.request(0.005)
    mem.down = True
    robot.publish_joints([0.1], 0.006)
    assert (robot.state, robot.end_reason, robot.state_since, robot.link_errors) == (
        RobotState.IDLE, EndReason.LINK_ERROR, 0.006, 1)
    assert robot.step(0.007) is None
    assert robot.link_errors == 2


def test_request_and_end_ring_the_state_doorbell() -> None:
    bells: list[int] = []
    _, _, robot, _ = _servoing(bells)
    assert bells == [1, 1]  # request(); SERVOING reached
    robot.end(0.003)
    assert bells == [1, 1, 1]


def test_notify_only_counts_doorbells() -> None:
    _, _, robot, _ = _servoing()
    robot.notify()
    robot.notify(2)
    assert robot.doorbells == 2 and robot.state is RobotState.SERVOING


def test_telemetry_tick_counts_from_1_and_unused_joints_read_0() -> None:
    buf, _, robot, _ = _servoing()
    reader = SeqlockRecord(BufferMemory(buf), TELEMETRY)
    robot.publish_joints([0.5, -0.25, 1.0], 0.003)
    got = reader.latest()
    assert got is not None and got[1] == (1, 3, 0.003, 0.5, -0.25, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    robot.publish_joints([0.5], 0.004)
    got = reader.latest()
    assert got is not None and got[1][:2] == (2, 1)
    with pytest.raises(ValueError, match=r"^9 joints; the telemetry record holds 8$"):
        robot.publish_joints([0.0] * 9, 0.005)


# --- records: sequence numbers of 31 bits and more, resume, torn slots ----------------------------
def test_record_versions_above_2_to_the_31_and_the_wrap_to_1() -> None:
    buf = bytearray(64)
    w, r = Record(BufferMemory(buf), 0, 4), Record(BufferMemory(buf), 0, 4)
    w.seq = 0xFFFFFFFD
    assert w.write(b"abcd") == 0xFFFFFFFE  # slot 0
    assert r.read() == (0xFFFFFFFE, b"abcd")
    assert buf[0:4] == bytes.fromhex("FFFFFFFE") and buf[12:16] == bytes.fromhex("FFFFFFFE")
    assert w.write(b"efgh") == 0xFFFFFFFF  # slot 1
    assert r.read() == (0xFFFFFFFF, b"efgh")
    r.resume()
    assert r.seq == 0xFFFFFFFF
    assert w.write(b"ijkl") == 1  # 0 is never a version: the count goes on at 1 (slot 1)
    assert r.read() == (1, b"ijkl")
    r.resume()
    assert r.seq == 1


def test_resume_continues_after_the_newest_begun_version_in_either_slot() -> None:
    buf = bytearray(64)
    w = Record(BufferMemory(buf), 0, 4)
    w.write(b"v1..")  # slot 1
    w.write(b"v2..")  # slot 0
    r = Record(BufferMemory(buf), 0, 4)
    r.resume()
    assert r.seq == 2
    w.write(b"v3..")  # slot 1
    r.resume()
    assert r.seq == 3


def test_a_slot_being_rewritten_is_not_read_even_with_a_matching_crc() -> None:
    buf = bytearray(64)
    w = Record(BufferMemory(buf), 0, 4)
    w.write(b"v1..")  # slot 1 (bytes 16..31), slot 0 never written
    buf[16:20] = struct.pack(">I", 3)  # a writer began version 3 there; the old body and SEQ_END stay
    assert Record(BufferMemory(buf), 0, 4).read() is None


def test_records_must_be_word_aligned_and_payloads_of_their_size() -> None:
    mem = BufferMemory(bytearray(64))
    for offset, size in ((2, 8), (4, 6)):
        with pytest.raises(ValueError, match=r"^records must be word aligned$"):
            Record(mem, offset, size)
    with pytest.raises(ValueError, match=r"^payload of 3 bytes, record holds 4$"):
        Record(mem, 0, 4).write(b"abc")


def test_sequence_order_is_half_the_32_bit_circle() -> None:
    assert seq_newer(0x7FFFFFFF, 0) and not seq_newer(0x80000000, 0) and not seq_newer(0, 0)
    assert seq_newer(1, 0xFFFFFFFF)


def test_layout_checks_name_what_they_found() -> None:
    buf = bytearray(LAYOUT_SIZE)
    mem = BufferMemory(buf)
    format_layout(mem)
    assert buf[0:12] == bytes.fromhex("56534D31 00000001 00000200")
    buf[0:4] = bytes.fromhex("FFFFFFFF")
    with pytest.raises(ProtocolError, match=r"^no vision-servo layout in the shared memory \(magic 0xFFFFFFFF, "
                                            r"expected 0x56534D31\); the robot side must format it first$"):
        check_layout(mem)
    format_layout(mem)
    buf[8:12] = struct.pack(">I", 0x100)  # the right version, another size
    with pytest.raises(ProtocolError, match=r"^vision-servo layout version 1 size 256; this side speaks "
                                            r"version 1 size 512$"):
        check_layout(mem)


# --- the robot's status record, its doorbells and timing edges --------------------------------------
def _bare(timeouts: Timeouts = T) -> tuple[bytearray, Flaky, VisionServoClient]:
    """A robot on a formatted memory and no vision side (its records written by hand, if at all)."""
    buf = bytearray(LAYOUT_SIZE)
    mem = Flaky(buf)
    format_layout(mem)
    return buf, mem, VisionServoClient(mem, timeouts)


def _vision_says(buf: bytearray, state: int, task_id: int, end_reason: int = 0, heartbeat: int = 1) -> None:
    rec = SeqlockRecord(BufferMemory(buf), VISION_STATUS)
    rec.continue_sequence()
    rec.publish((state, task_id, heartbeat, end_reason, 0, 0, 0, 0))


def test_the_robot_status_record_from_construction_on() -> None:
    buf, _, robot = _bare()
    assert (robot.state_since, robot.peer, robot.heartbeat, robot.max_step_m, robot.max_rot_rad) == (
        0.0, None, 1, 0.01, 0.05)
    assert (robot.doorbells, robot.link_errors, robot.torn_reads, robot.commands) == (0, 0, 0, 0)
    status = SeqlockRecord(BufferMemory(buf), ROBOT_STATUS)
    got = status.latest()
    assert got is not None and got[1] == pytest.approx((0, 0, 1, 0, 1, 0.01, 0.05, 0))
    assert robot.request(0.125) == 1
    got = status.latest()  # REQUESTED, task 1, heartbeat 2, no end reason, task kind 1 by default
    assert got is not None and got[1][:5] == (1, 1, 2, 0, 1)
    robot.step(0.2)  # still waiting for an answer: the heartbeat goes on
    got = status.latest()
    assert got is not None and got[1][:3] == (1, 1, 3) and got[1][7] == 0


def test_task_ids_wrap_past_0_to_1_and_request_twice_is_refused() -> None:
    _, _, robot = _bare()
    robot.task_id = 0xFFFFFFFF
    assert robot.request(0.0) == 1
    with pytest.raises(ProtocolError, match=r"^request\(\) in state REQUESTED: end the current task first$"):
        robot.request(0.1)


def test_a_state_change_rings_once_and_a_step_without_one_does_not_ring() -> None:
    bells: list[int] = []
    _buf, _, robot, vision = _servoing(bells)
    assert bells == [1, 1]
    robot.step(0.003)
    robot.step(0.004)
    assert bells == [1, 1]
    vision.end(0.005)
    robot.step(0.006)  # the vision side is ending: the robot goes idle and says so
    assert robot.state is RobotState.IDLE and bells == [1, 1, 1]
    assert robot.state_since == 0.006 and robot.end_reason is EndReason.PEER_ENDED


def test_peer_timeout_and_accept_timeout_are_strictly_exceeded() -> None:
    _, _, robot = _bare(Timeouts(peer_timeout_s=0.25, accept_timeout_s=0.5, ending_timeout_s=0.125))
    robot.request(0.25)  # no vision side at all: every read of its status is torn
    robot.step(0.5)  # exactly peer_timeout_s since the request: not yet
    assert robot.state is RobotState.REQUESTED and robot.torn_reads == 1
    robot.step(0.5000001)
    assert (robot.state, robot.end_reason, robot.state_since) == (RobotState.IDLE, EndReason.PEER_TIMEOUT, 0.5000001)
    _, _, robot = _bare(Timeouts(peer_timeout_s=1.0, accept_timeout_s=0.25, ending_timeout_s=0.125))
    robot.request(0.25)
    robot.step(0.5)  # exactly accept_timeout_s: not yet
    assert robot.state is RobotState.REQUESTED
    robot.step(0.5000001)
    assert (robot.state, robot.end_reason, robot.state_since) == (
        RobotState.IDLE, EndReason.ACCEPT_TIMEOUT, 0.5000001)


def test_ending_waits_for_the_ending_timeout_strictly() -> None:
    _, _, robot = _bare(Timeouts(peer_timeout_s=1.0, accept_timeout_s=1.0, ending_timeout_s=0.125))
    robot.request(0.25)
    robot.end(0.25)
    assert (robot.state, robot.state_since) == (RobotState.ENDING, 0.25)
    robot.step(0.375)  # exactly ending_timeout_s: not yet
    assert robot.state is RobotState.ENDING
    robot.step(0.3750001)
    assert (robot.state, robot.end_reason, robot.state_since) == (
        RobotState.IDLE, EndReason.ENDING_TIMEOUT, 0.3750001)


def test_ending_holds_while_the_vision_side_still_tracks_the_task() -> None:
    buf, _, robot = _bare()
    robot.request(0.0)
    _vision_says(buf, VISION_TRACKING, 1)
    robot.step(0.01)
    assert robot.state is RobotState.SERVOING and robot.state_since == 0.01
    assert robot.peer is not None and (robot.peer.state, robot.peer.task_id) == (VISION_TRACKING, 1)
    robot.end(0.02)
    _vision_says(buf, VISION_TRACKING, 1, heartbeat=2)
    robot.step(0.03)
    assert robot.state is RobotState.ENDING
    _vision_says(buf, VISION_IDLE, 1, end_reason=2, heartbeat=3)
    robot.step(0.04)
    assert (robot.state, robot.end_reason, robot.state_since) == (RobotState.IDLE, EndReason.REQUESTED_END, 0.04)


@pytest.mark.parametrize(("vision_state", "end_reason", "robot_reason"), [
    (VISION_IDLE, 5, EndReason.REFUSED),  # refused
    (VISION_IDLE, 9, EndReason.PEER_ENDED),  # accepted and already ended (target lost)
    (VISION_ENDING, 0, EndReason.PEER_ENDED),
])
def test_a_request_answered_by_anything_but_tracking_ends_it(vision_state, end_reason, robot_reason) -> None:
    buf, _, robot = _bare()
    robot.request(0.0)
    _vision_says(buf, vision_state, 1, end_reason=end_reason)
    robot.step(0.01)
    assert (robot.state, robot.end_reason, robot.state_since) == (RobotState.IDLE, robot_reason, 0.01)


def test_servoing_ends_when_the_peer_falls_silent() -> None:
    buf, _, robot = _bare()
    robot.request(0.0)
    _vision_says(buf, VISION_TRACKING, 1)
    robot.step(0.01)
    robot.step(0.1)  # the heartbeat has not moved since 0.01, but 0.09 s is within peer_timeout_s
    assert robot.state is RobotState.SERVOING
    robot.step(0.12)
    assert (robot.state, robot.end_reason, robot.state_since) == (RobotState.IDLE, EndReason.PEER_TIMEOUT, 0.12)


def test_torn_peer_reads_are_counted() -> None:
    _buf, _, robot = _bare()
    robot.step(0.01)
    robot.step(0.02)
    assert robot.torn_reads == 2 and robot.peer is None


def test_link_failures_while_writing_or_stepping_go_idle_at_that_time() -> None:
    _, mem, robot = _bare()
    mem.down = True
    robot.request(0.3)  # the status write fails: the request ends at once
    assert (robot.state, robot.end_reason, robot.state_since, robot.link_errors) == (
        RobotState.IDLE, EndReason.LINK_ERROR, 0.3, 1)
    mem.down = False
    robot.request(0.4)
    mem.down = True
    assert robot.step(0.5) is None
    assert (robot.state, robot.end_reason, robot.state_since, robot.link_errors) == (
        RobotState.IDLE, EndReason.LINK_ERROR, 0.5, 2)
