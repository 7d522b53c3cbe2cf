"""Jog: velocity moves with a deadman, bounded by the soft limits and the velocity limits.

An operator (the console's ``jog J SPEED_DEG_S``, MAVLink's MANUAL_CONTROL) commands joint speeds;
the jog's targets move at those speeds, ramped at the joints' controlled-stop deceleration. The
jog is a trajectory (:class:`JogTrajectory`) the sequencer plays like any move, so the loop, the
watchdog and the stops treat it as they treat a planned move:

* **deadman** — each command renews it; when none came for ``deadman_s`` (0.5 s) of the loop's
  time (its ticks: the trajectory's own sample times, never the wall clock) every joint
  decelerates to rest and the jog ends, holding where it stopped. A command of 0 for every joint
  ends it the same way at once;
* **velocity** — a commanded speed beyond the joint's planning limit (``[servo]
  max_velocity_deg_s``) is clamped to it;
* **soft limits** — the targets never pass a joint's ``[joint.limits]``: toward a limit the jog
  brakes at the ramp's rate down to a creep speed (:data:`CREEP_DEG_S` over the last
  :data:`CREEP_DEG`) and its target comes to rest :data:`LIMIT_ALLOWANCE_DEG` inside the limit,
  so the joint, which runs on past a target that stops, stays inside too (a target known only at
  run time, checked before each is used: docs/motion-safety.md);
* **the scene** — where the rig has an arm model and obstacles: each tick, the pose where the
  target would come to rest if it braked now is checked, further on by the creep distance and
  the allowance (a link in an obstacle there: the jog creeps) and by the allowance alone (then it
  stops: :attr:`JogTrajectory.refusal` names the link and the obstacle).

:func:`jog` is the one entry point: called at a tick boundary (inside a live command), it renews
the running jog or starts one from where the loop holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from servo.trajectory.base import Sample, TrajectoryError
from servo.trajectory.bounds import MotionBounds
from servo.trajectory.sequencer import PlanContext, Sequencer

#: toward a soft limit the jog's target stops this far inside it (°): the loop's joint runs ahead of
#: a target that stops (velocity integrator, the tach's dead band) — on jpl-arm's j1 a jog at
#: 20°/s into the limit overshot its target by up to 0.5° (measured: tests/vmehil/console/
#: test_home_jog.py), and the watchdog stops the loop 0.5° past the limit (``soft_limit``)
LIMIT_ALLOWANCE_DEG = 1.0
#: the last CREEP_DEG before that point are crept at CREEP_DEG_S (the overshoot grows with the
#: speed the target stops from: 1.5° from 20°/s)
CREEP_DEG, CREEP_DEG_S = 2.0, 2.0
#: the deadman: a jog not renewed for this long (s of loop time) stops
DEADMAN_S = 0.5
#: the ramp's rate (rad/s²) where a loop has no stop settings: 400°/s², a controlled stop's default
DEFAULT_JOG_ACCEL_RAD_S2 = math.radians(400.0)


class JogTrajectory:
    """Targets moving at the commanded speeds (see the module docstring); ``duration`` is open
    until the jog has come to rest after its deadman ran out (or a command of all zeros)."""

    def __init__(self, start: np.ndarray, v_max: np.ndarray, accel: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 deadman_s: float = DEADMAN_S, bounds: MotionBounds | None = None) -> None:
        self.start = np.asarray(start, float).copy()
        self.theta = self.start.copy()
        n = self.start.shape[0]
        self.v_max = np.asarray(v_max, float)
        self.accel = np.asarray(accel, float)
        # the target stops the allowance inside each limit; a target already past that point may
        # only come back toward it (the bound moves out to it)
        allowance = math.radians(LIMIT_ALLOWANCE_DEG)
        self.lo = np.fmin(np.asarray(lo, float) + allowance, self.start)
        self.hi = np.fmax(np.asarray(hi, float) - allowance, self.start)
        self.deadman_s = float(deadman_s)
        self.creep_rad = math.radians(CREEP_DEG)
        self.creep_rad_s = math.radians(CREEP_DEG_S)
        self.v = np.zeros(n)
        self.v_cmd = np.zeros(n)
        self._t = 0.0
        self._renewed = 0.0
        self._t_end: float | None = None
        #: the jog ran out of its deadman (not stopped by a command of zeros)
        self.expired = False
        #: the scene the targets are checked against as they are made (``None``: none)
        self.bounds = bounds if bounds is not None and bounds.checks_collisions else None
        #: why the jog stopped short of an obstacle (``None``: it did not)
        self.refusal: str | None = None

    @property
    def duration(self) -> float:
        return math.inf if self._t_end is None else self._t_end

    @property
    def end(self) -> np.ndarray:
        return self.theta.copy()

    @property
    def running(self) -> bool:
        """It still takes commands (not ended)."""
        return self._t_end is None

    def command(self, speeds: dict[int, float]) -> dict[int, float]:
        """Renew the deadman and set joint speeds (rad/s, joint index → speed; others keep theirs);
        returns the speeds in force, clamped to the velocity limits."""
        if self.refusal is not None:
            raise TrajectoryError(self.refusal)
        if not self.running:
            raise TrajectoryError("the jog has ended: start a new one")
        out = {}
        for j, v in speeds.items():
            if not math.isfinite(v):
                raise TrajectoryError(f"jog speed {v!r} of joint {j + 1} is not a finite number")
            self.v_cmd[j] = float(np.clip(v, -self.v_max[j], self.v_max[j]))
            out[j] = float(self.v_cmd[j])
        self._renewed = self._t
        if self.bounds is not None and not self.v.any() and self.v_cmd.any():
            # from rest, toward an obstacle already within the allowance: refused at once
            self._stop_if_hit(self.theta + np.sign(self.v_cmd) * math.radians(LIMIT_ALLOWANCE_DEG))
            if self.refusal is not None:
                raise TrajectoryError(self.refusal)
        return out

    def _approach(self, room: np.ndarray) -> np.ndarray:
        """The fastest speed toward a limit ``room`` (rad) away: the ramp's braking curve down to
        the creep speed at ``creep_rad`` from the limit, then the creep speed, braking at the end."""
        with np.errstate(invalid="ignore"):
            room = np.maximum(room, 0.0)
            brake = np.sqrt(2.0 * self.accel * np.maximum(room - self.creep_rad, 0.0))
            creep = np.fmin(self.creep_rad_s, np.sqrt(2.0 * self.accel * room))
        return np.fmax(brake, creep)

    def _look_ahead(self) -> None:
        """Where the target would come to rest if it braked now, plus the creep distance and the
        allowance: a link in an obstacle there slows the jog to the creep speed; plus the allowance
        alone: it stops the jog now (a target known only at run time, checked before it is used),
        as at a soft limit. A jog that starts in an obstacle's envelope is not held there."""
        assert self.bounds is not None
        brake = self.v * np.abs(self.v) / (2.0 * self.accel)
        way = np.sign(self.v)
        allowance = math.radians(LIMIT_ALLOWANCE_DEG)
        if not self.bounds.collisions_at(self.theta + brake + way * (allowance + self.creep_rad)):
            return
        self.v_cmd = np.clip(self.v_cmd, -self.creep_rad_s, self.creep_rad_s)  # near an obstacle: creep
        self._stop_if_hit(self.theta + brake + way * allowance)

    def _stop_if_hit(self, pose: np.ndarray) -> None:
        """A link in an obstacle at ``pose`` (and not where the target is now): stop the jog."""
        assert self.bounds is not None
        hits = self.bounds.collisions_at(pose)
        if hits and not self.bounds.collisions_at(self.theta):
            link, obstacle = hits[0]
            self.refusal = (f"jog stopped: link {link} would hit obstacle {obstacle} "
                            f"(joints {', '.join(f'{math.degrees(x):.2f}' for x in self.theta)} deg)")
            self.v_cmd[:] = 0.0

    def sample(self, t: float) -> Sample:
        dt = max(0.0, t - self._t)
        self._t = t
        if t - self._renewed > self.deadman_s and self.v_cmd.any():
            self.v_cmd[:] = 0.0  # the deadman ran out: come to rest
            self.expired = True
        v0 = self.v.copy()
        if self.bounds is not None and self.refusal is None and self.v.any():
            self._look_ahead()
        if dt > 0.0:
            step = self.accel * dt
            v = np.clip(self.v_cmd, self.v - step, self.v + step)
            # toward a limit: no faster than what stops at it at the ramp's rate (and never past it)
            up = self._approach(self.hi - self.theta)
            down = self._approach(self.theta - self.lo)
            v = np.clip(v, -np.fmin(down, (self.theta - self.lo) / dt), np.fmin(up, (self.hi - self.theta) / dt))
            self.theta = np.clip(self.theta + v * dt, self.lo, self.hi)
            self.v = v
            if self._t_end is None and not self.v_cmd.any() and not self.v.any():
                self._t_end = t  # at rest with nothing commanded: the sequencer holds here
        alpha = (self.v - v0) / dt if dt > 0.0 else np.zeros_like(self.v)
        return Sample(self.theta.copy(), self.v.copy(), alpha, False)


@dataclass(frozen=True)
class JogMove:
    """A jog as a move (a sequencer plays it): the ramp's rate per joint (rad/s²); the velocity
    limits and the soft limits come from the planning context."""

    accel_rad_s2: tuple[float, ...]
    deadman_s: float = DEADMAN_S
    kind: str = "jog"

    def build(self, start: np.ndarray, ctx: PlanContext) -> JogTrajectory:
        n = len(start)
        bounds = ctx.bounds
        lo = np.full(n, -np.inf) if bounds is None else np.asarray(bounds.min_rad, float)
        hi = np.full(n, np.inf) if bounds is None else np.asarray(bounds.max_rad, float)
        return JogTrajectory(start, ctx.limits.v_max, np.asarray(self.accel_rad_s2, float), lo, hi, self.deadman_s,
                             bounds)


def running_jog(loop: Any) -> JogTrajectory | None:
    """The loop's jog when one runs and takes commands."""
    seq = loop.sequencer
    cur = seq.current
    if isinstance(cur, JogTrajectory) and not seq.finished and cur.running:
        return cur
    return None


def jog(loop: Any, speeds: dict[int, float], hold: np.ndarray) -> tuple[dict[int, float], bool]:
    """At a tick boundary: renew the running jog with ``speeds`` (joint index → rad/s), or start one
    from ``hold`` (where the loop holds now). Returns the speeds in force (clamped to the velocity
    limits) and whether a jog was started. The caller checks that the loop may move."""
    cur = running_jog(loop)
    started = cur is None
    if cur is None:
        settings = loop.stop_settings
        decel = settings.decel_rad_s2 if settings is not None and len(settings.decel_rad_s2) == loop.n else ()
        accel = tuple(float(a) for a in decel) or (DEFAULT_JOG_ACCEL_RAD_S2,) * loop.n
        ctx = loop.plan_context or loop.sequencer.ctx
        seq = Sequencer([JogMove(accel)], hold, ctx)
        if seq.plan_error is not None:
            raise seq.plan_error
        seq.sample(0.0)  # the jog starts now: its time runs from this tick
        loop.set_motion(seq)
        first = seq.current
        assert isinstance(first, JogTrajectory)
        cur = first
    return cur.command(speeds), started
