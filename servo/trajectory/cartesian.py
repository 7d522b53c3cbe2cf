"""A Cartesian path as a joint trajectory: (DM)²'s ``blendx_t``, "linear Cartesian space interpolation
with parabolic blends; generates its own time of motion" (docs/cartesian.md).

The tool point moves on straight lines through its points with parabolic blends (an
:class:`~servo.trajectory.lspb.Lspb` path in x, y, z at a nominal :data:`CARTESIAN_SPEED_M_S`), the
hand's frame turning from the start's to the target's about one axis in step with the distance
travelled. The path is tabulated — every :data:`GRID_DT_S` of the nominal path, through the arm's
closed-form inverse kinematics (:meth:`hal.kinematics.ArmModel.solve`), each point on the branch
nearest the one before — and then slowed, by one factor, until no joint exceeds its planning
velocity (and acceleration, when the limits give one): the motion's own time. A sample between
table points is a cubic Hermite of the two.

A point of the path the arm cannot reach, or one at a singularity (where the joint speeds a
straight line needs grow without bound), refuses the path before it starts: a
:class:`~servo.trajectory.bounds.MotionRefused` of kind ``reach`` naming the point. The table's
points are the path's ``points`` (and ``via_times``): :class:`~servo.trajectory.bounds.MotionBounds`
checks every one against the soft limits, and the path at its usual instants against the scene.

:class:`Chain` plays trajectories one after the other as one move (a joint move to an approach
point, then the straight approach: the JPL terminal guidance).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hal.kinematics import ArmModel, slerp
from servo.trajectory.base import JointLimits, Sample, Trajectory, TrajectoryError, check_speed
from servo.trajectory.bounds import MotionRefused, Refusal
from servo.trajectory.lspb import Lspb

__all__ = ["CARTESIAN_ACCEL_M_S2", "CARTESIAN_SPEED_M_S", "CartesianPath", "Chain", "fmt_m", "reach_refusal"]

#: the nominal speed (m/s, per axis) and acceleration (m/s², per axis) of the tool on a straight
#: line at speed factor 1, before the joints' limits stretch the path
CARTESIAN_SPEED_M_S = 0.10
CARTESIAN_ACCEL_M_S2 = 0.20
#: the path is tabulated at this spacing (s) of the nominal path, with at least GRID_MIN and at most
#: GRID_MAX points (a solve is ~1 ms: a long path plans in under a second)
GRID_DT_S = 0.02
GRID_MIN = 20
GRID_MAX = 600


def fmt_m(p: np.ndarray) -> str:
    """A point for a message: ``[x, y, z] m`` to the millimetre (the Cartesian refusals' one format)."""
    return "[" + ", ".join(f"{float(x):.3f}" for x in p) + "] m"


def reach_refusal(detail: str, *, point_index: int | None = None, t_s: float | None = None,
                  theta: np.ndarray | None = None) -> MotionRefused:
    """A move refused because the arm cannot reach (or only singularly reach) a point of it."""
    return MotionRefused([Refusal("reach", detail, point_index=point_index, t_s=t_s,
                                  theta_rad=None if theta is None else tuple(float(x) for x in theta))])


class CartesianPath:
    """A joint trajectory tabulated at ``times`` (s; θ, ω, α per row). Plan one with :meth:`plan`."""

    def __init__(self, times: np.ndarray, theta: np.ndarray, omega: np.ndarray, alpha: np.ndarray) -> None:
        self.via_times = np.asarray(times, float)
        self.points = np.asarray(theta, float)
        self._omega = np.asarray(omega, float)
        self._alpha = np.asarray(alpha, float)
        self.start = self.points[0].copy()
        self.end = self.points[-1].copy()
        self.duration = float(self.via_times[-1])

    @classmethod
    def plan(cls, arm: ArmModel, start: np.ndarray, positions: Sequence[np.ndarray], r_start: np.ndarray,
             r_end: np.ndarray, limits: JointLimits, speed: float = 1.0) -> CartesianPath:
        """From the joint angles ``start`` (rad; the tool at ``positions[0]``, the hand's frame
        ``r_start``) through ``positions`` (m) to the last, the hand's frame turning to ``r_end``."""
        s = check_speed(speed)
        pts = [np.asarray(p, float).reshape(3) for p in positions]
        n = limits.n
        line = Lspb(pts, JointLimits(np.full(3, CARTESIAN_SPEED_M_S), np.full(3, CARTESIAN_ACCEL_M_S2)), s)
        if line.duration <= 0.0:
            raise TrajectoryError("a Cartesian path needs a point other than where the tool is")
        m = int(min(GRID_MAX, max(GRID_MIN, math.ceil(line.duration / GRID_DT_S) + 1)))
        tau = np.linspace(0.0, line.duration, m)
        xyz = np.array([line.sample(float(t)).theta_d for t in tau])
        run = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz, axis=0), axis=1))])
        frac = run / run[-1] if run[-1] > 0.0 else tau / tau[-1]
        theta = np.empty((m, n))
        theta[0] = np.asarray(start, float)
        name = arm.singularity(theta[0])[0]
        if name:
            raise reach_refusal(f"the straight path starts at a singularity ({name}): move the arm off it "
                                "with a joint or cartesian move first", point_index=0, t_s=0.0, theta=theta[0])
        for i in range(1, m):
            res = arm.solve(xyz[i], slerp(r_start, r_end, float(frac[i])), theta0=theta[i - 1])
            where = f"point {i + 1} of {m} of the path, {fmt_m(xyz[i])} (t = {tau[i] / s:.3f} s nominal)"
            if not res.reachable or res.theta is None:
                raise reach_refusal(f"the straight path leaves the workspace at {where}: {res.reason}",
                                    point_index=i, t_s=float(tau[i]))
            crossed = res.singularity or arm.crosses_singularity(theta[i - 1], res.theta)
            if crossed:
                raise reach_refusal(f"the straight path passes through a singularity at {where}: "
                                    f"{crossed}", point_index=i, t_s=float(tau[i]), theta=res.theta)
            theta[i] = res.theta
        omega = np.asarray(np.gradient(theta, tau, axis=0), float)
        alpha = np.asarray(np.gradient(omega, tau, axis=0), float)
        k = max(1.0, float(np.max(np.abs(omega) / (s * limits.v_max))))
        if limits.a_max is not None:
            k = max(k, math.sqrt(float(np.max(np.abs(alpha) / (s * s * limits.a_max)))))
        return cls(tau * k, theta, omega / k, alpha / (k * k))

    def sample(self, t: float) -> Sample:
        ts = self.via_times
        if t >= self.duration:
            z = np.zeros_like(self.end)
            return Sample(self.end.copy(), z, z.copy(), True)
        t = max(float(t), 0.0)
        i = int(np.searchsorted(ts, t, side="right")) - 1
        h = float(ts[i + 1] - ts[i])
        u = (t - float(ts[i])) / h
        p0, p1 = self.points[i], self.points[i + 1]
        v0, v1 = self._omega[i], self._omega[i + 1]
        h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
        theta = h00 * p0 + h10 * h * v0 + h01 * p1 + h11 * h * v1
        omega = (1 - u) * v0 + u * v1
        alpha = (1 - u) * self._alpha[i] + u * self._alpha[i + 1]
        return Sample(theta, omega, alpha, False)


class Chain:
    """Trajectories played one after the other as one: each starts where the one before ends."""

    def __init__(self, parts: Sequence[Trajectory]) -> None:
        self.parts = [p for p in parts if getattr(p, "duration", 0.0) > 0.0] or list(parts[:1])
        if not self.parts:
            raise TrajectoryError("a chain of no trajectories")
        self.start = np.asarray(self.parts[0].start, float)
        self.end = np.asarray(self.parts[-1].end, float)
        self._t0 = np.concatenate([[0.0], np.cumsum([float(p.duration) for p in self.parts])])
        self.duration = float(self._t0[-1])
        rows, times = [self.start], [0.0]
        for t0, part in zip(self._t0, self.parts, strict=False):
            pts = getattr(part, "points", None)
            vt = getattr(part, "via_times", None)
            if pts is not None and vt is not None and len(pts) == len(vt) and len(pts) > 1:
                rows.extend(np.asarray(pts, float)[1:])
                times.extend(float(t0) + np.asarray(vt, float)[1:])
            else:
                rows.append(np.asarray(part.end, float))
                times.append(float(t0) + float(part.duration))
        #: every part's via points (or end), for the soft-limit check
        self.points = np.array(rows)
        self.via_times = np.array(times)

    def sample(self, t: float) -> Sample:
        i = int(np.searchsorted(self._t0, t, side="right")) - 1
        i = min(max(i, 0), len(self.parts) - 1)
        out: Sample = self.parts[i].sample(t - float(self._t0[i]))
        return out._replace(done=bool(t >= self.duration))
