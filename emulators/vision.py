"""The emulated vision system on the far side of the BIT3 link.

A camera on the end effector sees a target at a fixed point of the workspace. Every frame
(``rate_hz``) the vision system measures where the target is in the camera frame, and — after
``latency_s`` of image processing — sends a proportional, saturated end-effector-relative
motion increment toward it over the vision-servo protocol. When the target has been within
``tolerance_m`` for ``hold_frames`` frames it ends the task (``TARGET_REACHED``).

The protocol endpoint is the vision computer's own (:mod:`emulators.vision_protocol`, written
from docs/bit3.md), not the robot side's ``hal.bit3.protocol``.

Where the camera is comes from either
* ``ee_pose()`` — a callable returning (position, rotation) (in one process the lead wires it
  to the plant's true joint angles through :class:`hal.kinematics.ArmModel`), or
* the robot's TELEMETRY record in the shared memory (joint angles → arm model), which is how
  the vision process (``vmehil vision``) sees the arm.

:func:`run_vision_process` is the body of ``vmehil vision``.
"""

from __future__ import annotations

import logging
import math
import signal
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from emulators.bit3 import Bit3Link, Bit3RemotePort
from emulators.faults import FaultInjectable
from emulators.vision_protocol import (
    FLAG_CONVERGED,
    FLAG_TARGET_VISIBLE,
    EndReason,
    VisionServer,
    VisionState,
    VisionTimeouts,
    check_layout,
    format_layout,
)
from hal.kinematics import ArmModel
from hal.shm import BufferMemory

log = logging.getLogger(__name__)

PoseFn = Callable[[], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class VisionParams:
    """Vision-system parameters (SI).

    Attributes:
        rate_hz: camera frame rate.
        latency_s: time from frame capture to the command being written (image processing).
        gain: fraction of the measured error commanded per frame (proportional, 0..1].
        max_step_m: saturation of one translation command.
        tolerance_m: the target counts as reached within this distance.
        hold_frames: consecutive frames within tolerance before ending the task (0: never end).
        fov_half_angle_rad: the target is visible within this angle of the optical axis
            (``math.pi``: always visible).
        lost_frames: consecutive frames without the target before ending (TARGET_LOST).
    """

    rate_hz: float = 30.0
    latency_s: float = 0.03
    gain: float = 0.5
    max_step_m: float = 0.01
    tolerance_m: float = 0.002
    hold_frames: int = 3
    fov_half_angle_rad: float = math.pi
    lost_frames: int = 15

    def __post_init__(self) -> None:
        if not self.rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {self.rate_hz}")
        if self.latency_s < 0:
            raise ValueError(f"latency_s must be >= 0, got {self.latency_s}")
        if not 0 < self.gain <= 1:
            raise ValueError(f"gain must be in (0, 1], got {self.gain}")
        if not self.max_step_m > 0 or not self.tolerance_m > 0:
            raise ValueError("max_step_m and tolerance_m must be > 0")


@dataclass
class VisionStats:
    frames: int = 0
    commands: int = 0
    tasks: int = 0
    last_error_m: float = math.nan
    last_end_reason: str = "NONE"
    errors_m: list[float] = field(default_factory=list)


class VisionSystem(FaultInjectable):
    """The emulated vision computer: camera model + controller + protocol endpoint.

    Fault ``dead``: the vision process dies — :meth:`step` does nothing from then on (no
    heartbeat, no frames, no commands), as a killed process on the vision computer.

    Args:
        server: the protocol endpoint on the vision side's memory.
        target: target position in the base frame (m).
        arm: the arm model (used with telemetry when ``ee_pose`` is not given).
        params: frame rate, latency, gain, ...
        ee_pose: optional callable giving the true camera pose (position, rotation).
    """

    FAULTS = {  # noqa: RUF012 - the FaultInjectable catalogue
        "dead": "the vision process dies: no heartbeat, frames or commands from now on",
    }

    def __init__(
        self,
        server: VisionServer,
        target: Sequence[float],
        arm: ArmModel | None = None,
        params: VisionParams | None = None,
        ee_pose: PoseFn | None = None,
    ) -> None:
        self.server = server
        self.target = np.asarray(target, dtype=float).reshape(3)
        self.arm = arm or ArmModel()
        self.params = params or VisionParams()
        self.ee_pose = ee_pose
        self.stats = VisionStats()
        self._next_frame: float | None = None
        self._queue: deque[tuple[float, np.ndarray, int]] = deque()
        self._good = 0
        self._lost = 0
        self._was = VisionState.IDLE

    def camera_pose(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Where the camera is: ``ee_pose()`` or the arm model on the robot's telemetry."""
        if self.ee_pose is not None:
            p, R = self.ee_pose()
            return np.asarray(p, dtype=float), np.asarray(R, dtype=float)
        tel = self.server.telemetry()
        if tel is None or len(tel.theta) <= max(self.arm.joints):
            return None
        return self.arm.pose(tel.theta)

    def measure(self) -> tuple[np.ndarray, bool] | None:
        """Target position in the camera frame (m) and whether it is in the field of view."""
        pose = self.camera_pose()
        if pose is None:
            return None
        p, R = pose
        e = R.T @ (self.target - p)
        n = float(np.linalg.norm(e))
        visible = n == 0.0 or math.acos(max(-1.0, min(1.0, e[0] / n))) <= self.params.fov_half_angle_rad
        return e, visible

    def step(self, now: float) -> VisionState:
        """Run the protocol, take a frame when one is due, release commands whose latency has
        passed. ``now`` is the vision computer's time (s)."""
        if self.fault("dead") is not None:
            return self._was
        state = self.server.step(now)
        if state is VisionState.TRACKING and self._was is not VisionState.TRACKING:
            self.stats.tasks += 1
            self._next_frame = now
            self._queue.clear()
            self._good = self._lost = 0
        if state is not VisionState.TRACKING:
            if state is VisionState.IDLE and self._was is not VisionState.IDLE:
                self.stats.last_end_reason = self.server.end_reason.name
            self._queue.clear()
            self._was = state
            return state
        self._was = state
        p = self.params
        if self._next_frame is not None and now >= self._next_frame:
            self._next_frame += 1.0 / p.rate_hz
            if self._next_frame <= now:  # we fell behind: skip frames rather than burst
                self._next_frame = now + 1.0 / p.rate_hz
            self._frame(now)
        while self._queue and self._queue[0][0] <= now:
            _, d, flags = self._queue.popleft()
            if self.server.send(now, d.tolist(), flags=flags) is not None:
                self.stats.commands += 1
        return self.server.state

    def _frame(self, now: float) -> None:
        p = self.params
        m = self.measure()
        if m is None:
            return
        self.server.frame()
        self.stats.frames += 1
        e, visible = m
        if not visible:
            self._lost += 1
            self._good = 0
            if self._lost >= p.lost_frames:
                self.server.end(now, EndReason.TARGET_LOST)
            return
        self._lost = 0
        err = float(np.linalg.norm(e))
        self.stats.last_error_m = err
        self.stats.errors_m.append(err)
        if err <= p.tolerance_m:
            self._good += 1
            if p.hold_frames and self._good >= p.hold_frames:
                self.server.end(now, EndReason.TARGET_REACHED)
                return
            return  # within tolerance: no command
        self._good = 0
        d = p.gain * e
        n = float(np.linalg.norm(d))
        if n > p.max_step_m:
            d *= p.max_step_m / n
        flags = FLAG_TARGET_VISIBLE | (FLAG_CONVERGED if err <= 2 * p.tolerance_m else 0)
        self._queue.append((now + p.latency_s, d, flags))


def run_vision_process(
    shm_name: str,
    target: Sequence[float],
    *,
    params: VisionParams | None = None,
    arm: ArmModel | None = None,
    timeouts: VisionTimeouts | None = None,
    offset: int = 0,
    poll_s: float = 0.002,
    duration_s: float | None = None,
    exit_after_task: bool = False,
) -> dict[str, Any]:
    """Run the vision system as its own process on a shared-memory BIT3 link.

    Attaches to the segment ``shm_name`` that the robot side created, formats the protocol
    layout if the memory is blank (:func:`emulators.vision_protocol.format_layout`), powers the
    "remote crate" on (the robot side sees ``STATUS.link_up``), and runs
    :class:`VisionSystem` on the wall clock until SIGTERM/SIGINT, ``duration_s``, or (with
    ``exit_after_task``) the end of the first task. On exit it writes IDLE (end reason
    SHUTDOWN), powers off and detaches; it never unlinks the segment (the creator does).
    Returns a summary dict.
    """
    link = Bit3Link.attach_shared(shm_name)
    port = Bit3RemotePort(link)
    stop = {"flag": False}

    def _stop(signum: int, frame: Any) -> None:
        stop["flag"] = True

    old = {s: signal.signal(s, _stop) for s in (signal.SIGTERM, signal.SIGINT)}
    t0 = time.monotonic()
    vision: VisionSystem | None = None
    server: VisionServer | None = None
    mem = BufferMemory(link.mem, offset)
    try:
        # The dual-port memory is the vision crate's: it formats it at power-up unless the
        # robot side already did (a layout of another version is an error, never overwritten).
        if mem.read(0, 4) == bytes(4):
            format_layout(mem)
        check_layout(mem)
        port.power_on()
        server = VisionServer(mem, timeouts, ring=port.ring)
        vision = VisionSystem(server, target, arm, params)
        log.info("vision: attached to %s, target %s", shm_name, list(target))
        while not stop["flag"]:
            now = time.monotonic() - t0
            vision.step(now)
            if duration_s is not None and now >= duration_s:
                break
            if exit_after_task and vision.stats.tasks and server.state is VisionState.IDLE:
                break
            time.sleep(poll_s)
    finally:
        if server is not None:
            server.shutdown(time.monotonic() - t0)
        port.power_off()
        port.close()
        mem.release()
        link.close(unlink=False)
        for s, h in old.items():
            signal.signal(s, h)
    st = vision.stats if vision is not None else VisionStats()
    return {"frames": st.frames, "commands": st.commands, "tasks": st.tasks,
            "last_error_m": st.last_error_m, "end_reason": st.last_end_reason}
