"""Cartesian moves: the tool to a point in the arm's base frame (docs/cartesian.md).

Two motion-file types (:data:`servo.motion.MOVE_TYPES`) and the console's ``move_to``:

- ``cartesian`` — the JPL arm's "move arm to specified position with specified or default hand
  orientation": the target is turned into joint angles (:meth:`hal.kinematics.ArmModel.solve`) and
  every joint moves by the one normalized quintic, as a joint move does (the paper: "target
  position/orientation … are transformed to changes in joint variables");
- ``blendx`` — (DM)²'s ``blendx_t``: the tool on straight lines with parabolic blends through the
  ``via_m`` points to the target (:class:`servo.trajectory.cartesian.CartesianPath`).

Either takes ``approach_m``: the JPL terminal guidance's "intermediate point removed from the
target along the direction of the final desired approach vector" — the tool goes to the point
``approach_m`` back along the hand's approach axis (x̂ of the hand's frame at the target), then
straight in to the target. ``orientation_deg = [roll, pitch, yaw]``: the hand's frame at the target
(:func:`hal.kinematics.rotation_rpy`); without it the default, the hand level and pointing away from
the waist axis (:meth:`hal.kinematics.ArmModel.default_hand_rotation`).

A target the arm cannot reach within the soft limits, or reaches only at a singularity, and a
straight path that leaves the workspace or passes through a singularity, refuse the move before it
starts: :class:`~servo.trajectory.bounds.MotionRefused` of kind ``reach`` (``vmehil run`` exits 2,
``vmehil plan`` lists it, the console answers ``ERR REACH``). The joint path the move produces is
then checked as every move is, against the soft limits and the scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hal.config import ConfigTable
from hal.kinematics import ArmModel, IkResult, rotation_rpy
from servo.fine_positioning import FinePositioning, FineSettings
from servo.trajectory import MoveSpec, PlanContext, Quintic, Trajectory, TrajectoryError
from servo.trajectory.cartesian import CartesianPath, Chain, fmt_m, reach_refusal
from servo.trajectory.lspb import MAX_VIA_POINTS

__all__ = ["BlendxMove", "CartesianMove", "CartesianTarget", "parse_blendx", "parse_cartesian"]

#: no Cartesian coordinate is farther than this from the base (m): a sanity bound on the file, not
#: the arm's reach (which the inverse kinematics checks)
MAX_COORDINATE_M = 100.0
#: the smallest fine-positioning tolerance (mm): a floor, not a measured limit — finer than the
#: averaged pots resolve, the phase would only run to its timeout (0.5 mm settled on six targets)
MIN_SETTLE_TOLERANCE_MM = 0.1
#: the motion-file keys of the fine-positioning phase
FINE_KEYS = ("settle_tolerance_mm", "settle_timeout_s")


@dataclass(frozen=True)
class CartesianTarget:
    """Where the tool goes: ``position_m`` (base frame) and the hand's frame there (``rotation``;
    ``None``: the default hand orientation at that point)."""

    position_m: np.ndarray
    rotation: np.ndarray | None = None

    @classmethod
    def make(cls, position_m: list[float] | np.ndarray, orientation_deg: list[float] | np.ndarray | None = None
             ) -> CartesianTarget:
        p = np.asarray(position_m, float).reshape(3)
        if orientation_deg is None:
            return cls(p)
        r, pi, y = (math.radians(float(a)) for a in orientation_deg)
        return cls(p, rotation_rpy(r, pi, y))

    def hand_rotation(self) -> np.ndarray:
        return ArmModel.default_hand_rotation(self.position_m) if self.rotation is None else self.rotation


def _arm_and_limits(ctx: PlanContext, kind: str) -> tuple[ArmModel, np.ndarray | None, np.ndarray | None]:
    b = ctx.bounds
    if b is None or b.arm is None:
        raise TrajectoryError(f"a {kind} move needs the arm's kinematics: this rig's file states no [arm]")
    return b.arm, b.min_rad, b.max_rad


def _solve(arm: ArmModel, point: np.ndarray, rot: np.ndarray, theta0: np.ndarray, lo: np.ndarray | None,
           hi: np.ndarray | None, names: tuple[str, ...], what: str) -> np.ndarray:
    """The joint angles of a point the move must reach, or a ``reach`` refusal saying why not."""
    res: IkResult = arm.solve(point, rot, theta0=theta0, min_rad=lo, max_rad=hi)
    if not res.reachable or res.theta is None:
        reason = res.reason
        if res.limit_joint is not None and res.limit_joint < len(names):
            reason = reason.replace(f"joint index {res.limit_joint}", f"joint {names[res.limit_joint]}")
        raise reach_refusal(f"{what} {fmt_m(point)} cannot be reached: {reason}")
    if res.singular:
        raise reach_refusal(f"{what} {fmt_m(point)} is at a singularity: {res.singularity} "
                            f"(manipulability {res.manipulability:.2e} m³)", theta=res.theta)
    return res.theta


def _finely(ctx: PlanContext, base: Trajectory, target: CartesianTarget, fine: FineSettings | None,
            kind: str) -> Trajectory:
    """``base``, or with ``fine`` the move's trajectory followed by the fine-positioning phase
    (:mod:`servo.fine_positioning`; checked by the sequencer as every move is: the phase holds the
    planned targets while nothing is measured)."""
    if fine is None:
        return base
    arm, lo, hi = _arm_and_limits(ctx, kind)
    return FinePositioning(base, arm, target.position_m, fine, ctx.extras, lo, hi)


def _plan(ctx: PlanContext, start: np.ndarray, target: CartesianTarget, vias: tuple[np.ndarray, ...],
          approach_m: float, speed: float, kind: str) -> Trajectory:
    arm, lo, hi = _arm_and_limits(ctx, kind)
    names = ctx.bounds.names if ctx.bounds is not None else ()
    start = np.asarray(start, float)
    rot = target.hand_rotation()
    goal = target.position_m
    end = _solve(arm, goal, rot, start, lo, hi, names, "target")
    approach = goal - approach_m * rot[:, 0] if approach_m > 0.0 else None
    if kind == "cartesian":
        if approach is None:  # the JPL move: every joint by one normalized quintic
            return Quintic.plan(start, end, ctx.limits, speed)
        at = _solve(arm, approach, rot, end, lo, hi, names, "approach point")  # the target's branch
        return Chain([Quintic.plan(start, at, ctx.limits, speed),
                      CartesianPath.plan(arm, at, [approach, goal], rot, rot, ctx.limits, speed)])
    points = [arm.tool_position(start), *vias]
    if approach is not None:
        _solve(arm, approach, rot, end, lo, hi, names, "approach point")
        points.append(approach)
    points.append(goal)
    return CartesianPath.plan(arm, start, points, arm.hand_rotation(start), rot, ctx.limits, speed)


@dataclass(frozen=True)
class CartesianMove:
    """The JPL move to a Cartesian target: joint angles by the inverse kinematics, one quintic."""

    target: CartesianTarget
    approach_m: float = 0.0
    speed: float = 1.0
    kind: str = "cartesian"
    #: the fine-positioning phase after the move (``settle_tolerance_mm``); ``None``: none
    fine: FineSettings | None = None

    @property
    def tool_target_m(self) -> np.ndarray:
        """Where the tool should end (m, base frame): the run's ``tool.final_error_mm`` is against it."""
        return self.target.position_m

    def build(self, start: np.ndarray, ctx: PlanContext) -> Trajectory:
        return _finely(ctx, _plan(ctx, start, self.target, (), self.approach_m, self.speed, self.kind),
                       self.target, self.fine, self.kind)


@dataclass(frozen=True)
class BlendxMove:
    """``blendx_t``: straight lines with parabolic blends through ``vias_m`` to the target."""

    target: CartesianTarget
    vias_m: tuple[np.ndarray, ...] = ()
    approach_m: float = 0.0
    speed: float = 1.0
    kind: str = "blendx"
    fine: FineSettings | None = None

    @property
    def tool_target_m(self) -> np.ndarray:
        return self.target.position_m

    def build(self, start: np.ndarray, ctx: PlanContext) -> Trajectory:
        return _finely(ctx, _plan(ctx, start, self.target, self.vias_m, self.approach_m, self.speed, self.kind),
                       self.target, self.fine, self.kind)


# ---- the motion file ----------------------------------------------------------------------------------
def _point(cfg: ConfigTable, key: str, raw: object) -> np.ndarray:
    if (not isinstance(raw, list) or len(raw) != 3
            or not all(isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in raw)):
        raise cfg.error(key, "a point [x, y, z] in metres", raw)
    p = np.array(raw, float)
    if np.any(np.abs(p) > MAX_COORDINATE_M):
        raise cfg.error(key, f"coordinates within ±{MAX_COORDINATE_M:g} m", raw)
    return p


def _target(cfg: ConfigTable) -> CartesianTarget:
    pos = _point(cfg, "position_m", cfg.raw("position_m"))
    orient = cfg.floats("orientation_deg", length=3) if "orientation_deg" in cfg else None
    if orient is not None and any(abs(a) > 360.0 for a in orient):
        raise cfg.error("orientation_deg", "[roll, pitch, yaw] in degrees, each within ±360", orient)
    return CartesianTarget.make(pos, orient)


def _common(cfg: ConfigTable) -> tuple[float, float]:
    approach = cfg.get_float("approach_m", 0.0, min=0.0, max=MAX_COORDINATE_M)
    speed = cfg.get_float("speed", 1.0)
    if not 0.0 < speed <= 1.0:
        raise cfg.error("speed", "a speed factor in (0, 1] (0.5 makes the move twice as long)", speed)
    return approach, speed


def _fine(cfg: ConfigTable) -> FineSettings | None:
    """``settle_tolerance_mm`` (and ``settle_timeout_s``, default 3): the fine-positioning phase."""
    if "settle_tolerance_mm" not in cfg:
        if "settle_timeout_s" in cfg:
            raise cfg.error("settle_timeout_s", "settle_tolerance_mm beside it (the phase's tolerance)")
        return None
    tol_mm = cfg.get_float("settle_tolerance_mm", 1.0, min=MIN_SETTLE_TOLERANCE_MM, max=1000.0)
    timeout_s = cfg.get_float("settle_timeout_s", 3.0, min=0.1, max=600.0)
    return FineSettings(tol_mm * 1e-3, timeout_s)


def parse_cartesian(cfg: ConfigTable, n: int) -> MoveSpec:
    """``type = "cartesian"``: ``position_m``, optional ``orientation_deg``, ``approach_m``, ``speed``,
    ``settle_tolerance_mm``, ``settle_timeout_s``."""
    target = _target(cfg)
    approach, speed = _common(cfg)
    fine = _fine(cfg)
    cfg.check_unknown({"type", "position_m", "orientation_deg", "approach_m", "speed", *FINE_KEYS})
    return CartesianMove(target, approach, speed, fine=fine)


def parse_blendx(cfg: ConfigTable, n: int) -> MoveSpec:
    """``type = "blendx"``: ``position_m`` (the target), optional ``via_m`` (points before it),
    ``orientation_deg``, ``approach_m``, ``speed``."""
    target = _target(cfg)
    raw = cfg.raw("via_m", [])
    if not isinstance(raw, list):
        raise cfg.error("via_m", "a list of points [x, y, z] in metres", raw)
    if len(raw) > MAX_VIA_POINTS:
        raise cfg.error("via_m", f"at most {MAX_VIA_POINTS} via points", f"{len(raw)} points")
    vias = tuple(_point(cfg, f"via_m[{i}]", p) for i, p in enumerate(raw))
    approach, speed = _common(cfg)
    fine = _fine(cfg)
    cfg.check_unknown({"type", "position_m", "via_m", "orientation_deg", "approach_m", "speed", *FINE_KEYS})
    return BlendxMove(target, vias, approach, speed, fine=fine)
