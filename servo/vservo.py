"""Visual servoing: the ``vservo`` trajectory object and the robot side of the vision link.

While a ``vservo`` move runs, the servo loop follows the vision system's end-effector-relative
commands, which arrive over the BIT3 VME-to-VME link (``hal.bit3``): each tick the robot side
publishes the measured joint angles, runs its protocol state machine and, when a complete new
command arrived, turns the end-effector increment into joint increments with the arm model's
damped-least-squares Jacobian (``hal.kinematics.ArmModel.ee_delta_to_joint_delta``) and adds them
to the joint targets — each new target checked first against the soft limits and the scene
(:class:`servo.trajectory.bounds.MotionBounds`): one they refuse is not used, the arm holds and
the refusal is counted (the report's ``refused_targets``). Whenever the protocol says *hold*
(requested, ending, idle, peer dead) the targets stay where they are. The move ends when the
task ends (either side, or a dead peer) or after ``timeout_s``; the sequencer then goes on from
where the arm is held.

Motion file::

    [[move]]
    type = "vservo"
    timeout_s = 20        # end the task (robot side) after this long

The link is given to the planner as ``PlanContext.extras["vision"]`` (a :class:`VisionLink`);
``vmehil run --vision inprocess|process`` sets it up (see ``vmehil/option_groups/vision_options.py``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.bit3.protocol import RobotState, VisionServoClient
from hal.config import ConfigTable
from hal.kinematics import ArmModel
from servo.trajectory.base import Sample, TrajectoryError
from servo.trajectory.bounds import MotionBounds
from servo.trajectory.sequencer import PlanContext


class VisionLink:
    """The robot side of a visual-servo task, stepped from the servo loop's tick.

    Args:
        client: the protocol endpoint on the BIT3 window memory.
        arm: the arm model (which joints it moves: ``arm.joints``).
        clock: bus time in seconds (the crate's simulated clock, or the hardware clock).
        measure: the latest measured joint angles (rad, all joints).
        n_joints: joints of the rig.
        vision: an in-process vision system stepped before the client (``None`` when it runs
            as its own process or on a real vision computer).
    """

    def __init__(self, client: VisionServoClient, arm: ArmModel, clock: Callable[[], float],
                 measure: Callable[[], np.ndarray | None], n_joints: int, vision=None) -> None:
        self.client = client
        self.arm = arm
        self.clock = clock
        self.measure = measure
        self.n = n_joints
        self.vision = vision
        self.commands = 0
        #: commands whose joint targets the soft limits or the scene refused (the arm held instead)
        self.refused = 0
        self.last_refusal: str | None = None
        self._frozen: np.ndarray | None = None

    def freeze(self) -> None:
        """Keep the joints' measured angles now, at the end of the run's own ticks: the report's
        distance is where the run left the arm (its end-of-run stop and the 2 s watched after it
        are in ``final_stop``)."""
        theta = self.measure()
        self._frozen = None if theta is None else np.asarray(theta, float).copy()

    def summary(self) -> dict[str, Any]:
        """Outcome for the run report: protocol state, commands followed, distance to target
        (at the run's end: :meth:`freeze`; else now)."""
        theta = self._frozen if self._frozen is not None else self.measure()
        out = {"robot_state": self.client.state.name,
               "end_reason": getattr(self.client.end_reason, "name", None),
               "commands": self.commands, "final_distance_mm": None,
               # always there (0, None): docs/motion-safety.md promises the count to a reader
               "refused_targets": self.refused, "last_refusal": self.last_refusal}
        if self.vision is not None and theta is not None:
            ee = np.asarray(self.arm.position(np.asarray(theta, float)[:6]))
            out["final_distance_mm"] = float(np.linalg.norm(ee - np.asarray(self.vision.target)) * 1e3)
        return out

    def step(self, fallback: np.ndarray) -> np.ndarray | None:
        """One tick: publish joints, run both state machines. For a new command, the new joint
        targets (rad): the *measured* angles plus the command's joint increment — the command is
        relative to where the end effector is, so targets never run away from a lagging arm.
        ``None`` when there is no new command."""
        now = self.clock()
        theta = self.measure()
        theta = np.asarray(fallback if theta is None else theta, float)
        self.client.publish_joints(theta[: min(self.n, 8)], now)
        if self.vision is not None:
            self.vision.step(now)
        cmd = self.client.step(now)
        if cmd is None or self.client.holding:
            return None
        self.commands += 1
        d = np.asarray(self.arm.ee_delta_to_joint_delta(theta[:6], cmd.dp), float)
        moved = np.zeros(self.n, bool)
        moved[list(self.arm.joints)] = True
        target = np.asarray(fallback, float).copy()
        dd = np.zeros(self.n)
        dd[: min(d.size, self.n)] = d[: self.n]
        target[moved] = theta[moved] + dd[moved]
        return target


class VisualServoTrajectory:
    """Targets that follow the vision commands; ``duration`` is open until the task ends."""

    def __init__(self, start: np.ndarray, link: VisionLink, timeout_s: float,
                 bounds: MotionBounds | None = None) -> None:
        self.start = np.asarray(start, float).copy()  # where the move began (Trajectory.start)
        self.target = self.start.copy()
        self.link = link
        self.bounds = bounds
        self.timeout_s = float(timeout_s)
        self._t_end: float | None = None
        self._requested = False
        self._zeros = np.zeros_like(self.target)

    @property
    def duration(self) -> float:
        return math.inf if self._t_end is None else self._t_end

    @property
    def end(self) -> np.ndarray:
        return self.target.copy()

    def sample(self, t: float) -> Sample:
        client = self.link.client
        if not self._requested:
            if client.state is not RobotState.IDLE:
                raise TrajectoryError(f"vservo: the vision link is busy ({client.state.name}); cannot start a task")
            client.request(self.link.clock())
            self._requested = True
        if self._t_end is None:
            target = self.link.step(self.target)
            if target is not None:
                refusals = self.bounds.check_pose(target) if self.bounds is not None else []
                if refusals:  # known only now: checked before it is used; the arm holds where it was
                    self.link.refused += 1
                    self.link.last_refusal = refusals[0].detail
                else:
                    self.target = target
            if t >= self.timeout_s and client.state is not RobotState.IDLE:
                client.end(self.link.clock())
            if client.state is RobotState.IDLE and t > 0.0:
                self._t_end = max(t, 1e-9)  # task over: the sequencer moves on, holding here
        return Sample(self.target.copy(), self._zeros, self._zeros, False)


@dataclass(frozen=True)
class VservoMove:
    """Motion-file move ``type = "vservo"``: follow the vision system until the task ends."""

    timeout_s: float = 30.0
    kind: str = "vservo"

    def build(self, start: np.ndarray, ctx: PlanContext) -> VisualServoTrajectory:
        link = ctx.extras.get("vision")
        if link is None:
            raise TrajectoryError("a vservo move needs the vision link: run with --vision inprocess|process")
        return VisualServoTrajectory(start, link, self.timeout_s, ctx.bounds)


def parse_vservo(cfg: ConfigTable, n_joints: int) -> VservoMove:
    move = VservoMove(cfg.get_float("timeout_s", 30.0, min=1e-3))
    cfg.check_unknown({"type", "timeout_s"})
    return move


