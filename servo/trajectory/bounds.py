"""Motion within bounds: every planned move checked against the joints' soft limits and the
scene's obstacles before it starts (docs/motion-safety.md).

After the JPL paper: "if the boundary points are within the allowable range of motion for each
joint, then so are all intermediate points" — each move's boundary and via points are checked
against ``[joint.limits]`` (a quintic's monotonic blend and an LSPB path's blends stay between
their points, joint by joint); and "the path is checked at planning time for potential
collisions with obstacles … we check for collisions at twenty points along the trajectory": the
arm's links, as line segments of :class:`hal.kinematics.ArmModel`, against every obstacle's box
(:mod:`servo.scene`) at ``points`` instants spread evenly over the move (both ends included).

A refusal names what the paper's does — the colliding link, the obstacle and the point of the
trajectory (its index, time and joint angles) — or, for a limit, the joint, the target and the
limit. :class:`MotionRefused` carries them all; the :class:`~servo.trajectory.Sequencer` raises
it for a move its context's :class:`MotionBounds` refuses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.kinematics import ArmModel, segment_box_span
from servo.scene import Scene
from servo.trajectory.base import Trajectory, TrajectoryError

__all__ = ["DEFAULT_COLLISION_POINTS", "MotionBounds", "MotionRefused", "Refusal"]

#: the paper's "twenty points along the trajectory"
DEFAULT_COLLISION_POINTS = 20
#: a target this close to a limit (rad) is at it, not past it (rounding of degrees at the edges)
LIMIT_TOLERANCE_RAD = 1e-9


@dataclass(frozen=True)
class Refusal:
    """Why a move is refused. ``kind``: ``limit`` (a target past a soft limit), ``collision`` (a
    link in an obstacle at a point of the trajectory) or ``reach`` (a point the arm cannot reach:
    Cartesian targets). ``move``: the move's index (0-based) in its motion; ``joint``: the joint's
    name; ``link``/``obstacle``: the colliding pair; ``point_index``: the via point (limit) or the
    check point (collision); ``t_s``: when the trajectory is there; ``theta_rad``: the joint angles
    there (collision); ``detail``: one line saying it all."""

    kind: str
    detail: str
    move: int | None = None
    joint: str | None = None
    link: str | None = None
    obstacle: str | None = None
    point_index: int | None = None
    t_s: float | None = None
    theta_rad: tuple[float, ...] | None = None

    def as_dict(self) -> dict[str, Any]:
        """The JSON form (``vmehil plan --json``): kind, joint, link, obstacle, point_index, t_s,
        move, theta_deg, detail."""
        return {"kind": self.kind, "joint": self.joint, "link": self.link, "obstacle": self.obstacle,
                "point_index": self.point_index, "t_s": None if self.t_s is None else round(self.t_s, 6),
                "move": self.move,
                "theta_deg": None if self.theta_rad is None else [round(math.degrees(x), 4) for x in self.theta_rad],
                "detail": self.detail}


class MotionRefused(TrajectoryError):
    """A move the bounds refuse (before it starts): ``refusals``, the first named in the message."""

    def __init__(self, refusals: list[Refusal]) -> None:
        self.refusals = list(refusals)
        more = f" (and {len(self.refusals) - 1} more)" if len(self.refusals) > 1 else ""
        super().__init__(f"move refused: {self.refusals[0].detail}{more}")

    @property
    def code(self) -> str:
        """The console's error code: ``LIMIT``, ``COLLISION`` or ``REACH`` (the first refusal's kind)."""
        return self.refusals[0].kind.upper()


def _fmt_deg(theta: np.ndarray) -> str:
    return "[" + ", ".join(f"{math.degrees(x):.2f}" for x in theta) + "]"


@dataclass
class MotionBounds:
    """What a move must stay within: per joint the soft limits ``min_rad``/``max_rad`` (±inf: none),
    the ``arm`` and the ``scene`` (either ``None``: no collision check), checked at ``points``
    instants of each move. ``names``: the joints' names, for the refusals."""

    names: tuple[str, ...]
    min_rad: np.ndarray
    max_rad: np.ndarray
    arm: ArmModel | None = None
    scene: Scene | None = None
    points: int = DEFAULT_COLLISION_POINTS

    # --- soft limits ---------------------------------------------------------------------------------
    def check_targets(self, targets: np.ndarray, *, move: int | None = None,
                      times: np.ndarray | None = None) -> list[Refusal]:
        """Each target (rows of joint angles, rad) against the soft limits: a refusal per joint and
        point past one, naming the joint, the target and the limit."""
        pts = np.atleast_2d(np.asarray(targets, float))
        lo, hi = np.asarray(self.min_rad, float), np.asarray(self.max_rad, float)
        below = pts < lo - LIMIT_TOLERANCE_RAD
        above = pts > hi + LIMIT_TOLERANCE_RAD
        bad = ~np.isfinite(pts) | below | above
        out: list[Refusal] = []
        where = "" if move is None else f"move {move + 1}: "
        for i, j in zip(*np.nonzero(bad), strict=True):
            side, lim = ("min_deg", lo[j]) if below[i, j] else ("max_deg", hi[j])
            via = f" (point {i + 1} of {len(pts)})" if len(pts) > 1 else ""
            out.append(Refusal(
                "limit", f"{where}joint {self.names[j]} target {math.degrees(pts[i, j]):.2f}° is past its soft "
                         f"limit {side} = {math.degrees(lim):.2f}°{via}",
                move=move, joint=self.names[j], point_index=int(i) if len(pts) > 1 else None,
                t_s=None if times is None else float(times[i])))
        return out

    # --- collisions ----------------------------------------------------------------------------------
    @property
    def checks_collisions(self) -> bool:
        return self.arm is not None and self.scene is not None and len(self.scene) > 0

    def collisions_at(self, theta: np.ndarray) -> list[tuple[str, str]]:
        """The (link, obstacle) pairs in contact at the joint angles ``theta`` (rad)."""
        if not self.checks_collisions:
            return []
        assert self.arm is not None and self.scene is not None
        hits = []
        for link, p0, p1 in self.arm.segments(theta):
            for ob in self.scene.obstacles:
                if segment_box_span(p0, p1, ob.min_m, ob.max_m) is not None:
                    hits.append((link, ob.name))
        return hits

    def check_path(self, trajectory: Trajectory, *, move: int | None = None) -> list[Refusal]:
        """The trajectory at ``points`` instants (0 and its duration included) against every
        obstacle: a refusal for the first point where each (link, obstacle) pair collides."""
        if not self.checks_collisions or not (0.0 < trajectory.duration < math.inf):
            return []
        where = "" if move is None else f"move {move + 1}: "
        n = max(2, int(self.points))
        seen: set[tuple[str, str]] = set()
        out: list[Refusal] = []
        for i in range(n):
            t = trajectory.duration * i / (n - 1)
            theta = np.asarray(trajectory.sample(t).theta_d, float)
            for link, ob in self.collisions_at(theta):
                if (link, ob) in seen:
                    continue
                seen.add((link, ob))
                out.append(Refusal(
                    "collision", f"{where}link {link} hits obstacle {ob} at point {i + 1} of {n} "
                                 f"(t = {t:.3f} s, joints {_fmt_deg(theta)}°)",
                    move=move, link=link, obstacle=ob, point_index=i, t_s=t, theta_rad=tuple(float(x) for x in theta)))
        return out

    # --- one move, one target -----------------------------------------------------------------------
    def check_trajectory(self, trajectory: Trajectory, *, move: int | None = None) -> list[Refusal]:
        """A planned move: its targets (the via points where it has them, else its end) against the
        soft limits, then its path against the scene. A move that goes nowhere (a wait) is checked
        for neither: it holds where the previous one ended."""
        start, end = np.asarray(trajectory.start, float), np.asarray(trajectory.end, float)
        points = getattr(trajectory, "points", None)
        if points is not None and len(points) > 1:
            targets = np.asarray(points, float)[1:]
            vt = getattr(trajectory, "via_times", None)
            times = np.asarray(vt, float)[1:] if vt is not None and len(vt) == len(points) else None
        else:
            if np.array_equal(start, end):
                return []
            targets, times = end[None, :], np.array([float(trajectory.duration)])
        refusals = self.check_targets(targets, move=move, times=times)
        return refusals + self.check_path(trajectory, move=move)

    def check_pose(self, theta: np.ndarray) -> list[Refusal]:
        """A target known only at run time (visual servoing, the console's jog): the soft limits and
        the scene at that one pose."""
        th = np.asarray(theta, float)
        out = self.check_targets(th[None, :])
        for link, ob in self.collisions_at(th):
            out.append(Refusal("collision", f"link {link} hits obstacle {ob} at joints {_fmt_deg(th)}°",
                               link=link, obstacle=ob, theta_rad=tuple(float(x) for x in th)))
        return out
