"""Fine positioning at the end of a Cartesian move: trim the joint targets until the tool is within
a tolerance (docs/cartesian.md, "The tool's final error").

Why. With the integrator switch-off (the JPL paper's cure for the limit cycle, on in jpl-arm) a
joint stops where its error is when the integrators freeze: they freeze at the first zero crossing
of the error after the move, mid-swing, and keep the value they had then — an offset that puts the
joint's rest point 0.2–0.3° off (j1, measured), several millimetres at the tool. Keeping the
integrators fed instead lets the waist stick-slip around the target (a 0.6–0.8° limit cycle,
measured), the very cycle the paper switched them off for.

What. After the move's own trajectory comes a phase of ``timeout_s`` (the move's planned time
includes it) in which the targets are held (``done`` is true: the law's switch-off runs as for any
move, nothing in the law changes) while the joints' *measured* angles are averaged over a window
(the pots' noise is ±0.17° a tick on j1); the tool's measured position (the arm's forward
kinematics) is compared with the target: within ``tolerance_m`` the trimming ends; otherwise each
joint of the arm model gets its target moved by ``gain`` times its mean error — the rest point
moves with the target, the frozen offset stays — and the next window is averaged. The trimmed
targets are held for the rest of the phase and are where the next move starts (the sequencer plans
a move again from where the one before really ended: :meth:`servo.trajectory.Sequencer._advance`).
Each trim is at most :data:`MAX_TRIM_RAD` from the planned angle (inside the switch-off's outer
band: a trim never turns the integrators back on) and within the soft limits.

The measured angles come from ``PlanContext.extras[MEASURE_KEY]`` (a callable returning the
latest measured joint angles, or ``None`` before the first tick), which :class:`servo.loop.ServoLoop`
provides; without it the phase holds the targets until ``timeout_s``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.kinematics import ArmModel
from servo.trajectory.base import Sample, Trajectory

__all__ = ["MAX_TRIM_RAD", "MEASURE_KEY", "FinePositioning", "FineSettings"]

#: the :class:`~servo.trajectory.sequencer.PlanContext` extras key of the measured-angles callable
MEASURE_KEY = "measured_theta"
#: the largest trim of a joint's target from its planned angle (rad): half the switch-off's default
#: outer band (1°), so a trimmed joint never leaves the band and turns its integrators on
MAX_TRIM_RAD = math.radians(0.5)


@dataclass(frozen=True)
class FineSettings:
    """The fine-positioning phase's parameters (SI): ``tolerance_m`` of the tool's measured
    position; ``timeout_s`` the phase's longest duration; ``delay_s`` before the first window (the
    joints come to rest, the switch-off happens); ``window_s`` averaged per decision; ``gain`` of a
    trim (the fraction of the mean error moved; < 1 so one window's misreading does not overshoot)."""

    tolerance_m: float
    timeout_s: float = 3.0
    delay_s: float = 0.3
    window_s: float = 0.3
    gain: float = 0.8

    def __post_init__(self) -> None:
        for name in ("tolerance_m", "timeout_s", "window_s", "gain"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"fine positioning: {name} {v!r} must be a positive number")
        if not (math.isfinite(self.delay_s) and self.delay_s >= 0.0) or self.gain > 1.0:
            raise ValueError(f"fine positioning: delay_s {self.delay_s!r} >= 0 and gain {self.gain!r} <= 1 expected")


class FinePositioning:
    """``base`` (the move's trajectory), then the fine-positioning phase to ``target_m`` (m, the
    base frame). ``extras``: the plan context's extras, read when the phase runs (the loop adds the
    measured-angles callable after the motion is planned); ``min_rad``/``max_rad``: the soft limits
    a trimmed target stays within."""

    def __init__(self, base: Trajectory, arm: ArmModel, target_m: np.ndarray, settings: FineSettings,
                 extras: dict[str, Any], min_rad: np.ndarray | None = None, max_rad: np.ndarray | None = None) -> None:
        self.base = base
        self.arm = arm
        self.target_m = np.asarray(target_m, float).reshape(3)
        self.settings = settings
        self.extras = extras
        self.start = np.asarray(base.start, float)
        self.planned = np.asarray(base.end, float).copy()
        self.setpoint = self.planned.copy()
        n = self.planned.size
        self._lo = np.full(n, -np.inf) if min_rad is None else np.asarray(min_rad, float)
        self._hi = np.full(n, np.inf) if max_rad is None else np.asarray(max_rad, float)
        model = [*arm.joints, *arm.wrist_joints]
        self._moved = np.zeros(n, bool)
        self._moved[[j for j in model if j < n]] = True
        self._zeros = np.zeros(n)
        self._sum = np.zeros(n)
        self._t_seen = -math.inf
        self._reset()
        # the soft-limit and scene checks see the move's own path (the trims stay within MAX_TRIM_RAD)
        for name in ("points", "via_times"):
            if hasattr(base, name):
                setattr(self, name, getattr(base, name))

    def _reset(self) -> None:
        """The phase from its beginning: the planned targets, nothing averaged or decided."""
        self.setpoint = self.planned.copy()
        self._sum[:] = 0.0
        self._count = 0
        self._window_end: float | None = None
        #: trims made; whether the phase ended within the tolerance (``None`` while it runs) and
        #: when (s into the phase); the tool's measured error at the last decision (m)
        self.trims = 0
        self.settled: bool | None = None
        self.settled_after_s: float | None = None
        self.error_m: float | None = None

    @property
    def duration(self) -> float:
        return float(self.base.duration) + self.settings.timeout_s

    @property
    def end(self) -> np.ndarray:
        return self.setpoint.copy()

    def sample(self, t: float) -> Sample:
        if t < self._t_seen:  # sampled again from an earlier time: a check's pass, or the run after one
            self._reset()
        self._t_seen = t
        t_base = float(self.base.duration)
        if t < t_base:
            return self.base.sample(t)
        if self.settled is None:
            self._step(t - t_base)
        return Sample(self.setpoint.copy(), self._zeros, self._zeros, True)

    def _measured(self) -> np.ndarray | None:
        measure: Callable[[], np.ndarray | None] | None = self.extras.get(MEASURE_KEY)
        theta = measure() if measure is not None else None
        if theta is None:
            return None
        theta = np.asarray(theta, float)
        return theta if theta.shape == self.planned.shape and np.all(np.isfinite(theta)) else None

    def _step(self, tau: float) -> None:
        """One tick of the phase, ``tau`` s after the move's own trajectory. Without a measurement
        (planning, the scene check: no loop yet) nothing happens, so sampling then is pure; a
        pass sampled again from an earlier time (the run after a check) starts over (:meth:`sample`)."""
        s = self.settings
        theta = self._measured()
        if theta is None or tau < s.delay_s:
            return
        self._sum += theta
        self._count += 1
        if self._window_end is None:
            self._window_end = tau + s.window_s
        if tau + 1e-9 < self._window_end:
            return
        mean = self._sum / self._count
        self._sum[:] = 0.0
        self._count = 0
        self._window_end = tau + s.window_s
        self.error_m = float(np.linalg.norm(self.arm.tool_position(mean) - self.target_m))
        if self.error_m <= s.tolerance_m:
            self._finish(tau, True)
            return
        if tau + s.window_s > s.timeout_s:  # no window left to see a trim's effect: hold here
            self._finish(tau, False)
            return
        # move each joint's target by a fraction of its mean error: the rest point follows the target
        trimmed = self.setpoint + s.gain * (self.planned - mean)
        trimmed = np.clip(trimmed, self.planned - MAX_TRIM_RAD, self.planned + MAX_TRIM_RAD)
        trimmed = np.clip(trimmed, self._lo, self._hi)
        self.setpoint = np.where(self._moved, trimmed, self.setpoint)
        self.trims += 1

    def _finish(self, tau: float, settled: bool) -> None:
        self.settled_after_s = tau
        self.settled = settled
