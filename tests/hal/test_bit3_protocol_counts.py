"""The robot side of the vision-servo protocol (hal.bit3.protocol) counted exactly: commands
returned, missed, clamped, torn reads, link errors, doorbells, the step limits at their edges,
the telemetry tick and padding (docs/bit3.md, "Records", "Robot side"). The vision side is the
emulated vision computer's own implementation (emulators.vision_protocol); expected values are
worked by hand."""

from __future__ import annotations

import struct

import pytest

from emulators.vision_protocol import TELEMETRY, SeqlockRecord, VisionServer, VisionTimeouts
from hal.bit3 import BufferMemory, LinkDownError
from hal.bit3.protocol import (
    LAYOUT_SIZE,
    OFF_COMMAND,
    EndReason,
    RobotState,
    Timeouts,
    VisionServoClient,
    _limit,
    format_layout,
)

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
