"""The paper's normalized quintic point-to-point move.

θ(t) = θ0 + Δθ·g(u), u = t/T, g(u) = 10u³ − 15u⁴ + 6u⁵ (g(0)=0, g(1)=1, zero first and second
derivatives at both ends, monotonic). All joints share u, so they start and stop together. The
peak of g' is 15/8 at u = ½, so a joint's peak velocity is 1.875·|Δθ|/T; the duration is set by
the slowest joint at its maximum allowed velocity (scaled by the speed factor s)::

    T = max_j 1.875·|Δθ_j| / (s·v_max_j)

and, when accelerations are limited, at least max_j sqrt(5.7735·|Δθ_j| / (s²·a_max_j))
(peak |g''| = 10/√3 at u = ½ ∓ √3/6).
"""

from __future__ import annotations

import math

import numpy as np

from servo.trajectory.base import JointLimits, Sample, TrajectoryError, as_positions, check_speed

PEAK_VELOCITY_FACTOR = 1.875  # max g'(u)
PEAK_ACCEL_FACTOR = 10.0 / math.sqrt(3.0)  # max |g''(u)|
MIN_DURATION_S = 1e-9  #: moves shorter than this are a step to the target (done at once)


def g(u: float) -> tuple[float, float, float]:
    """The normalized quintic and its first two derivatives with respect to u."""
    u2 = u * u
    return (u2 * u * (10.0 - 15.0 * u + 6.0 * u2),
            30.0 * u2 * (1.0 - 2.0 * u + u2),
            60.0 * u * (1.0 - 3.0 * u + 2.0 * u2))


def quintic_duration(delta: np.ndarray, limits: JointLimits, speed: float = 1.0) -> float:
    """Duration (s) of a coordinated quintic move by ``delta`` (rad per joint) under ``limits``."""
    s = check_speed(speed)
    d = np.abs(np.asarray(delta, float))
    t = float(np.max(PEAK_VELOCITY_FACTOR * d / (s * limits.v_max))) if d.size else 0.0
    if limits.a_max is not None and d.size:
        t = max(t, float(np.max(np.sqrt(PEAK_ACCEL_FACTOR * d / (s * s * limits.a_max)))))
    return t


class Quintic:
    """A coordinated quintic move from ``start`` to ``target`` (rad) lasting ``duration`` s."""

    def __init__(self, start: np.ndarray, target: np.ndarray, duration: float) -> None:
        self.start = np.asarray(start, float).copy()
        self.end = as_positions("target", target, self.start.shape[0])
        if not (math.isfinite(duration) and duration >= 0.0):
            raise TrajectoryError(f"quintic duration {duration!r} must be a finite number of seconds >= 0")
        self.duration = float(duration)
        self.delta = self.end - self.start

    @classmethod
    def plan(cls, start: np.ndarray, target: np.ndarray, limits: JointLimits, speed: float = 1.0) -> Quintic:
        """The paper's move: the slowest joint at ``speed``·v_max sets the duration."""
        start = as_positions("start", start, limits.n)
        target = as_positions("target", target, limits.n)
        return cls(start, target, quintic_duration(target - start, limits, speed))

    def sample(self, t: float) -> Sample:
        T = self.duration
        if T < MIN_DURATION_S or t >= T:
            z = np.zeros_like(self.start)
            return Sample(self.end.copy(), z, z.copy(), True)
        u = max(t, 0.0) / T
        p, v, a = g(u)
        return Sample(self.start + self.delta * p, self.delta * (v / T), self.delta * (a / (T * T)), False)
