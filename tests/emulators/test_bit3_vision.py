"""Arm model, emulated vision system and closed-loop visual servoing over the BIT3 link.

The closed loops integrate the commanded joint increments directly (a kinematic arm; the
servo loop is not needed here): in one process in lockstep through the full driver stack,
and with the vision system as its own process (``python -m vmehil vision``) over
``multiprocessing.shared_memory``.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
import zlib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from emulators import vision_protocol as vp
from emulators.bit3 import Bit3Board, Bit3Link, Bit3RemotePort
from emulators.crate import Crate
from emulators.vision import VisionParams, VisionSystem
from emulators.vision_protocol import EndReason as VisionEndReason
from emulators.vision_protocol import VisionServer, VisionState
from hal.bit3 import Bit3Driver
from hal.bit3.protocol import (
    EndReason,
    RobotState,
    Timeouts,
    VisionServoClient,
    format_layout,
)
from hal.kinematics import ArmModel
from hal.shm import BufferMemory

ARM = ArmModel()
angles = st.floats(-2.5, 2.5)


# --- arm model ---------------------------------------------------------------------------
def test_default_arm_reaches_1_15_m_at_full_extension() -> None:
    assert ARM.reach == pytest.approx(1.15)
    p = ARM.position([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    assert p == pytest.approx([1.15, 0.0, ARM.d1])


@given(q=st.tuples(angles, angles, angles))
def test_jacobian_matches_finite_differences(q) -> None:
    J = ARM.jacobian(q)
    h = 1e-6
    for i in range(3):
        dq = np.zeros(3)
        dq[i] = h
        num = (ARM.position(np.add(q, dq)) - ARM.position(np.subtract(q, dq))) / (2 * h)
        assert np.allclose(J[:, i], num, atol=1e-6)


@given(q=st.tuples(angles, angles, angles))
def test_camera_frame_is_a_rotation_with_x_along_the_forearm(q) -> None:
    R = ARM.rotation(q)
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1.0)
    # moving the elbow joint's tip along x_e: the forearm direction
    fore = ARM.position(q) - ARM.position((q[0], q[1], q[2])) + R[:, 0] * ARM.a3
    assert np.allclose(fore / ARM.a3, R[:, 0])


@given(q=st.tuples(st.floats(-2, 2), st.floats(0.2, 1.2), st.floats(-2.2, -0.4)),
       d=st.tuples(*[st.floats(-1e-5, 1e-5)] * 3))
def test_ee_increment_maps_to_joint_increment_that_realizes_it(q, d) -> None:
    theta = [*q, 0.3, -0.1, 0.0]  # wrist joints do not move the camera in this model
    dq = ARM.ee_delta_to_joint_delta(theta, d, frame="ee", damping=1e-4)
    assert dq[3:] == pytest.approx([0.0, 0.0, 0.0])
    moved = ARM.position(np.add(theta, dq)) - ARM.position(theta)
    # first order: exact up to curvature (|dq|² L) and damping (λ²/σ²) terms
    assert np.allclose(moved, ARM.rotation(theta) @ np.asarray(d), rtol=0, atol=1e-3 * np.linalg.norm(d) + 1e-14)


def test_inverse_kinematics_round_trip_and_out_of_reach() -> None:
    theta = ARM.inverse([0.7, 0.3, 0.6], [0.0, 0.5, -1.0])
    assert ARM.position(theta) == pytest.approx([0.7, 0.3, 0.6], abs=1e-8)
    with pytest.raises(ValueError, match="not reached"):
        ARM.inverse([3.0, 0.0, 0.3], [0.0, 0.5, -1.0])


def test_arm_from_parameter_table() -> None:
    arm = ArmModel.from_table({"d1": 0.2, "a2": 0.5, "a3": 0.4, "joints": [1, 2, 3]})
    assert arm.reach == pytest.approx(0.9) and arm.joints == (1, 2, 3)
    with pytest.raises(ValueError, match="unknown"):
        ArmModel.from_table({"length": 1.0})


# --- the vision side's own protocol, read with the bytes docs/bit3.md gives --------------------
def _u32(*words: int) -> bytes:
    return b"".join(w.to_bytes(4, "big") for w in words)


def _slot(seq: int, payload: bytes) -> bytes:
    """SEQ_BEGIN | payload | CRC32 | SEQ_END, the CRC (zlib CRC-32) over big-endian seq + payload."""
    return _u32(seq) + payload + _u32(zlib.crc32(_u32(seq) + payload)) + _u32(seq)


def test_vision_side_formats_the_layout_header_of_the_doc() -> None:
    buf = bytearray(b"\xff" * 0x200)
    vp.format_layout(BufferMemory(buf))
    assert bytes(buf[:12]) == bytes.fromhex("56534D31 00000001 00000200")
    assert bytes(buf[12:0x200]) == bytes(0x200 - 12)


def test_vision_side_refuses_an_unformatted_memory_or_another_version() -> None:
    with pytest.raises(vp.LayoutError, match="format it first"):
        VisionServer(BufferMemory(bytearray(0x200)))
    buf = bytearray(0x200)
    buf[:12] = bytes.fromhex("56534D31 00000002 00000200")
    with pytest.raises(vp.LayoutError, match="version 2"):
        VisionServer(BufferMemory(buf))


def _formatted() -> bytearray:
    buf = bytearray(0x200)
    buf[:12] = bytes.fromhex("56534D31 00000001 00000200")
    return buf


def test_vision_status_version_1_lands_in_slot_1_at_0x09c() -> None:
    buf = _formatted()
    VisionServer(BufferMemory(buf))  # writes its first status: IDLE, heartbeat 1
    payload = _u32(0, 0, 1, 0, 0, 0, 0, 0)  # state, task_id, heartbeat, end_reason, frames, commands, 2 reserved
    assert bytes(buf[0x070 + 44 : 0x070 + 88]) == _slot(1, payload)
    assert bytes(buf[0x070 : 0x070 + 44]) == bytes(44)  # slot 0 untouched


def test_vision_side_accepts_a_request_and_writes_the_command_record() -> None:
    buf = _formatted()
    # ROBOT_STATUS version 1 (slot 1, 0x010 + 44): REQUESTED, task 5, heartbeat 1, kind 1, 10 mm, 0.05 rad
    robot = _u32(1, 5, 1, 0, 1) + bytes.fromhex("3C23D70A 3D4CCCCD") + _u32(0)
    buf[0x010 + 44 : 0x010 + 88] = _slot(1, robot)
    bells: list[int] = []
    server = VisionServer(BufferMemory(buf), ring=bells.append)
    assert server.step(0.01) is VisionState.TRACKING and server.task_id == 5
    assert server.peer is not None and server.peer.max_step_m == pytest.approx(0.01)
    assert bells == [1]  # state changed: doorbell code 1
    sent = server.send(0.25, (0.001, -0.002, 0.0005))
    assert sent is not None and bells == [1, 2]  # a new command: doorbell code 2
    # COMMAND version 1 in slot 1 at 0x0D0 + 52: task 5, cmd 1, flags 1, frame_ms 250, dx dy dz, drx dry drz
    payload = _u32(5, 1, 1, 250) + bytes.fromhex("3A83126F BB03126F 3A03126F") + bytes(12)
    assert bytes(buf[0x0D0 + 52 : 0x0D0 + 104]) == _slot(1, payload)


def test_vision_side_ignores_a_torn_robot_record_and_keeps_the_complete_one() -> None:
    buf = _formatted()
    buf[0x010 + 44 : 0x010 + 88] = _slot(1, _u32(1, 5, 1, 0, 1, 0, 0, 0))
    torn = bytearray(_slot(2, _u32(0, 5, 2, 0, 1, 0, 0, 0)))
    torn[-4:] = _u32(1)  # SEQ_END still the old number: version 2 is being written
    buf[0x010 : 0x010 + 44] = torn
    server = VisionServer(BufferMemory(buf))
    server.step(0.0)
    assert server.peer is not None and (server.peer.state, server.peer.heartbeat) == (1, 1)


def test_restarted_vision_side_continues_its_record_sequence() -> None:
    buf = _formatted()
    buf[0x070 : 0x070 + 4] = _u32(6)  # slot 0 holds version 6, slot 1 version 5
    buf[0x070 + 44 : 0x070 + 48] = _u32(5)
    VisionServer(BufferMemory(buf))
    assert bytes(buf[0x070 + 44 : 0x070 + 48]) == _u32(7)  # version 7 → slot 1
    assert bytes(buf[0x070 + 84 : 0x070 + 88]) == _u32(7)


def test_vision_side_reads_telemetry_of_the_doc_layout() -> None:
    buf = _formatted()
    # TELEMETRY version 1 (slot 1 at 0x140 + 60): tick 9, 3 joints, time 0.5 s (f64), theta f32 × 8
    payload = _u32(9, 3) + bytes.fromhex("3FE0000000000000") + bytes.fromhex("3F800000 BF000000 40000000") + bytes(20)
    buf[0x140 + 60 : 0x140 + 120] = _slot(1, payload)
    tel = VisionServer(BufferMemory(buf)).telemetry()
    assert tel is not None and (tel.tick, tel.time_s, tel.theta) == (9, 0.5, (1.0, -0.5, 2.0))


def test_vision_side_ends_on_robot_silence_after_peer_timeout() -> None:
    buf = _formatted()
    buf[0x010 + 44 : 0x010 + 88] = _slot(1, _u32(1, 5, 1, 0, 1, 0, 0, 0))
    server = VisionServer(BufferMemory(buf), vp.VisionTimeouts(peer_timeout_s=0.125, ending_timeout_s=0.0625))
    server.step(1.0)
    assert server.tracking
    server.step(1.125)  # heartbeat unchanged for exactly the timeout: not yet ("> peer_timeout")
    assert server.tracking
    server.step(1.1875)
    assert server.state is VisionState.IDLE and server.end_reason is VisionEndReason.PEER_TIMEOUT


# --- vision system -------------------------------------------------------------------------
def test_vision_measures_the_target_in_the_camera_frame() -> None:
    theta = [0.4, 0.6, -1.1]
    p, R = ARM.pose(theta)
    target = p + 0.2 * R[:, 0] + 0.05 * R[:, 1]  # ahead and to the left
    vision = VisionSystem(VisionServer.__new__(VisionServer), target, ARM,
                          ee_pose=lambda: ARM.pose(theta))
    e, visible = vision.measure()
    assert e == pytest.approx([0.2, 0.05, 0.0], abs=1e-12) and visible
    vision.params = VisionParams(fov_half_angle_rad=math.radians(10))
    assert not vision.measure()[1]  # 14° off axis


def test_vision_params_are_checked() -> None:
    with pytest.raises(ValueError, match="gain"):
        VisionParams(gain=1.5)
    with pytest.raises(ValueError, match="rate_hz"):
        VisionParams(rate_hz=0)


# --- closed loop, one process, lockstep through the driver ---------------------------------
def _robot_rig(link: Bit3Link, poll: float | None = None):
    crate = Crate("robot")
    card = Bit3Board("bit3", link, window_base=0x400000, window_space="A24", poll_period_s=poll)
    crate.install(card, base=0xC000, space="A16")
    drv = Bit3Driver(crate, 0xC000, 0x400000, window_size=link.mem_size)
    return crate, card, drv


def _closed_loop(latency_s: float, rate_hz: float, use_telemetry: bool, seconds: float = 4.0):
    link = Bit3Link(0x1000)
    remote = Bit3RemotePort(link)
    remote.power_on()
    crate, _, drv = _robot_rig(link)
    format_layout(drv.memory())
    robot = VisionServoClient(drv.memory(), ring=drv.ring_doorbell)
    drv.on_doorbell(robot.notify)
    theta = np.array([0.2, 0.5, -1.0, 0.0, 0.0, 0.0])
    target = ARM.position(theta) + np.array([0.08, -0.12, 0.05])
    params = VisionParams(rate_hz=rate_hz, latency_s=latency_s, gain=0.5, max_step_m=0.01, tolerance_m=0.002)
    server = VisionServer(remote.memory, ring=remote.ring)
    remote.on_doorbell(server.notify)
    vision = VisionSystem(server, target, ARM, params, ee_pose=None if use_telemetry else lambda: ARM.pose(theta))
    dt = 0.008
    robot.publish_joints(theta, 0.0)
    robot.request(crate.now())
    n = 0
    for k in range(1, round(seconds / dt)):
        crate.advance_to(round(k * dt * 1e9))
        t = crate.now()
        vision.step(t)
        cmd = robot.step(t)
        if cmd is not None:
            theta += ARM.ee_delta_to_joint_delta(theta, cmd.dp)
            n += 1
        robot.publish_joints(theta, t)
        if robot.state is RobotState.IDLE and server.state is VisionState.IDLE:
            break
    return robot, server, vision, float(np.linalg.norm(ARM.position(theta) - target)), n


@pytest.mark.parametrize(("latency_s", "rate_hz", "use_telemetry"),
                         [(0.03, 30.0, True), (0.0, 60.0, False), (0.06, 25.0, True)])
def test_closed_loop_visual_servo_converges_in_lockstep(latency_s, rate_hz, use_telemetry) -> None:
    robot, server, vision, err, n = _closed_loop(latency_s, rate_hz, use_telemetry)
    assert server.end_reason is VisionEndReason.TARGET_REACHED
    assert robot.state is RobotState.IDLE and robot.end_reason is EndReason.PEER_ENDED
    assert err < 2 * vision.params.tolerance_m
    assert n > 10 and vision.stats.frames > n // 2
    assert robot.doorbells > 0 and server.doorbells > 0  # hints delivered both ways (not relied on)


# --- closed loop with the vision system as its own process ----------------------------------
# The robot's clock is simulated. While the vision process lives, simulated time advances one
# step only after the peer has shown a new heartbeat, so a loaded machine that delays the vision
# process can never make the robot see it as silent; the vision side (wall clock) is given a
# robot-silence bound a loaded machine cannot reach. Wall-clock bounds only stop a hang.
STEP_NS = 5_000_000


def _vision_process(link: Bit3Link, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "vmehil", "vision", "--shm", link.shm_name, "--peer-timeout-ms", "60000", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_link_up(drv: Bit3Driver, proc: subprocess.Popen, wall_limit: float) -> None:
    while not drv.status().link_up:  # the vision process powers the remote crate on
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        assert time.monotonic() < wall_limit, "vision process did not come up"
        time.sleep(0.01)


def _robot_step(robot: VisionServoClient, crate: Crate, theta: np.ndarray) -> None:
    cmd = robot.step(crate.now())
    if cmd is not None:
        theta += ARM.ee_delta_to_joint_delta(theta, cmd.dp)
    robot.publish_joints(theta, crate.now())


def _until_peer_beats(robot: VisionServoClient, crate: Crate, theta: np.ndarray, proc: subprocess.Popen,
                      wall_limit: float) -> None:
    """Step the robot at the same simulated instant until the peer's heartbeat changes (or the
    task ends)."""
    seen = robot.peer.heartbeat if robot.peer is not None else None
    while robot.state is not RobotState.IDLE and (robot.peer is None or robot.peer.heartbeat == seen):
        assert proc.poll() is None or robot.peer is not None, proc.stderr.read() if proc.stderr else ""
        assert time.monotonic() < wall_limit, "the vision process stopped beating"
        _robot_step(robot, crate, theta)
        time.sleep(0.001)


def _advance(robot: VisionServoClient, crate: Crate, theta: np.ndarray) -> None:
    crate.advance_to(round(crate.now() * 1e9) + STEP_NS)
    _robot_step(robot, crate, theta)


def test_closed_loop_with_vision_emulator_as_a_separate_process() -> None:
    link = Bit3Link.create_shared(0x1000)
    proc = None
    try:
        crate, _, drv = _robot_rig(link, poll=100e-6)
        T = Timeouts(peer_timeout_s=1.0, accept_timeout_s=3.0, ending_timeout_s=0.5)
        theta = np.array([0.2, 0.5, -1.0, 0.0, 0.0, 0.0])
        target = ARM.position(theta) + np.array([0.03, 0.04, -0.02])
        proc = _vision_process(link, "--exit-after-task", "--target", ",".join(f"{x:.6f}" for x in target),
                               "--rate-hz", "50", "--latency-ms", "10", "--duration", "120")
        wall_limit = time.monotonic() + 60.0
        _wait_link_up(drv, proc, wall_limit)
        drv.reset_link()
        robot = VisionServoClient(drv.memory(), T)  # the vision side formatted its memory
        robot.publish_joints(theta, crate.now())
        robot.request(crate.now())
        while robot.state is not RobotState.IDLE:
            assert time.monotonic() < wall_limit, f"no end of task: state {robot.state.name}"
            _until_peer_beats(robot, crate, theta, proc, wall_limit)
            if robot.state is not RobotState.IDLE:
                _advance(robot, crate, theta)
        assert robot.end_reason is EndReason.PEER_ENDED, robot.end_reason
        assert robot.peer is not None and robot.peer.end_reason == EndReason.TARGET_REACHED
        assert np.linalg.norm(ARM.position(theta) - target) < 0.004
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        summary = json.loads(out.strip().splitlines()[-1])
        assert summary["end_reason"] == "TARGET_REACHED" and summary["commands"] >= robot.commands > 0
        assert not link.remote_power  # the vision process powered off on exit
    finally:
        if proc is not None and proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        link.close(unlink=True)


def test_killed_vision_process_leaves_the_robot_holding_after_peer_timeout() -> None:
    """After a SIGKILL no heartbeat comes, simulated time runs on, and the robot ends the task
    with PEER_TIMEOUT on its own clock and holds."""
    link = Bit3Link.create_shared(0x1000)
    proc = None
    try:
        crate, _, drv = _robot_rig(link, poll=100e-6)
        T = Timeouts(peer_timeout_s=0.3, accept_timeout_s=3.0, ending_timeout_s=0.2)
        theta = np.array([0.2, 0.5, -1.0])
        far = ARM.position(theta) + np.array([0.3, 0.0, 0.0])  # takes a while: still servoing when killed
        proc = _vision_process(link, "--target", ",".join(f"{x:.6f}" for x in far), "--max-step-mm", "0.5",
                               "--duration", "120")
        wall_limit = time.monotonic() + 60.0
        _wait_link_up(drv, proc, wall_limit)
        drv.reset_link()
        robot = VisionServoClient(drv.memory(), T)
        robot.publish_joints(theta, crate.now())
        robot.request(crate.now())
        killed_at = None
        while robot.state is not RobotState.IDLE:
            assert time.monotonic() < wall_limit, f"no end of task: state {robot.state.name}"
            if killed_at is None:
                _until_peer_beats(robot, crate, theta, proc, wall_limit)
                if robot.commands >= 3:
                    proc.kill()
                    proc.wait(timeout=30)
                    killed_at = crate.now()
            _advance(robot, crate, theta)
        assert killed_at is not None
        assert robot.state is RobotState.IDLE and robot.holding
        assert robot.end_reason is EndReason.PEER_TIMEOUT
        # ended by the timeout on the robot's clock, within a step of peer_timeout_s after the kill
        assert T.peer_timeout_s <= crate.now() - killed_at <= T.peer_timeout_s + 2 * STEP_NS * 1e-9
        assert link.remote_power  # a killed process cannot power off: only the heartbeat tells
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        link.close(unlink=True)


def test_vision_process_exits_cleanly_on_sigterm() -> None:
    link = Bit3Link.create_shared(0x1000)
    proc = subprocess.Popen([sys.executable, "-m", "vmehil", "vision", "--shm", link.shm_name, "--duration", "20"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.monotonic()
        while not link.remote_power:
            assert proc.poll() is None, proc.stderr.read()
            assert time.monotonic() - t0 < 15, "vision process did not come up"
            time.sleep(0.01)
        proc.terminate()
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        assert json.loads(out.strip().splitlines()[-1])["tasks"] == 0
        assert not link.remote_power
        view = BufferMemory(link.mem)
        probe = VisionServoClient(view)  # the vision side formatted its memory
        probe.step(0.0)
        assert probe.peer is not None and probe.peer.state == VisionState.IDLE
        view.release()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        link.close(unlink=True)


def test_vision_command_reports_a_missing_segment() -> None:
    from vmehil.cli import main

    assert main(["vision", "--shm", "vmehil-test-no-such-segment"]) == 2
