"""Motion files (TOML): a list of moves played by :class:`servo.trajectory.Sequencer`.

Format (angles in degrees at this edge, or radians with the ``_rad`` keys)::

    name = "demo"                      # optional
    [[move]]                           # type defaults to "quintic"
    targets_deg = [10, -20, 30, 0, 0, 0]
    speed = 0.5                        # speed factor in (0, 1]: 0.5 → twice as long
    [[move]]
    deltas_deg = [5, 0, 0, 0, 0, 0]    # relative to where the move starts
    [[move]]
    type = "wait"                      # hold the current target ("stay" is an alias)
    duration_s = 8
    [[move]]
    type = "lspb"
    via_deg = [[0, 10, 0, 0, 0, 0], [20, 0, 10, 0, 0, 0]]   # the last via is the target
    speed = 1.0
    [[move]]
    type = "cartesian"                 # the tool to a point (m, the arm's base frame): servo.cartesian
    position_m = [0.8, 0.0, 0.3]
    orientation_deg = [0, 30, 0]       # optional: the hand's roll, pitch, yaw (default: level, outward)
    approach_m = 0.05                  # optional: straight in over the last 5 cm along the hand's axis
    settle_tolerance_mm = 1.0          # optional: trim the targets until the tool is within 1 mm
    [[move]]
    type = "blendx"                    # straight lines with parabolic blends through via_m
    via_m = [[0.7, 0.2, 0.3]]
    position_m = [0.7, 0.3, 0.1]
    [[move]]
    type = "hand"                      # the fingers by a fixed current (servo.hand, docs/hand.md)
    action = "close"                   # open | close | squeeze
    current_a = 0.5                    # optional (default: open/close 0.5 A, squeeze 1.0 A)
    duration_s = 3                     # the arm holds meanwhile (default 3 s)

Limits (docs/control.md): a file of at most :data:`MAX_MOTION_FILE_BYTES`, at most
:data:`MAX_MOVES` moves, an LSPB move of at most :data:`servo.trajectory.lspb.MAX_VIA_POINTS`
vias — so loading and planning a motion is bounded (a 74 MB file of 10⁶ moves took 107 s and
1.5 GB to load).

Move types are looked up in :data:`MOVE_TYPES`, a plain table of the built-in types (the
visual-servo move ``"vservo"`` among them); a new type is a new entry there. A parser
receives the move's :class:`hal.config.ConfigTable` (whose errors name the file and key, e.g.
``move[2].duration_s``) and the number of joints, and returns a
:class:`servo.trajectory.MoveSpec`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hal.config import ConfigError, ConfigTable, load_toml
from hal.si import deg_to_rad
from servo.cartesian import parse_blendx, parse_cartesian
from servo.hand import ACTIONS, HandStay
from servo.trajectory import Lspb, MoveSpec, PlanContext, Quintic, Sequencer, Stay, Trajectory
from servo.trajectory.lspb import MAX_VIA_POINTS
from servo.vservo import parse_vservo

MoveParser = Callable[[ConfigTable, int], MoveSpec]

#: the largest motion file read (a hand-written one is a few kB; 1 MiB holds ~10 000 moves)
MAX_MOTION_FILE_BYTES = 1 << 20
#: the most moves in one motion
MAX_MOVES = 10_000


# ---- the built-in moves ------------------------------------------------------------------------------
@dataclass(frozen=True)
class QuinticMove:
    """Coordinated quintic move to ``target`` (rad), or by ``delta`` (rad) from the start."""

    target: np.ndarray | None
    delta: np.ndarray | None
    speed: float = 1.0
    kind: str = "quintic"

    def build(self, start: np.ndarray, ctx: PlanContext) -> Trajectory:
        target = self.target if self.target is not None else start + self.delta
        return Quintic.plan(start, target, ctx.limits, self.speed)


@dataclass(frozen=True)
class LspbMove:
    """LSPB path from the start through ``vias`` (rad; the last one is the target)."""

    vias: tuple[np.ndarray, ...]
    speed: float = 1.0
    kind: str = "lspb"

    def build(self, start: np.ndarray, ctx: PlanContext) -> Trajectory:
        return Lspb([start, *self.vias], ctx.limits, self.speed)


@dataclass(frozen=True)
class WaitMove:
    """Hold the current target for ``duration`` s (``done`` is True: the motion has ended)."""

    duration: float
    kind: str = "wait"

    def build(self, start: np.ndarray, ctx: PlanContext) -> Trajectory:
        return Stay(start, self.duration)


@dataclass(frozen=True)
class HandMove:
    """The hand by ``action`` at ``current_a`` (A; ``None``: the action's default) while the arm
    holds its target for ``duration`` s (:class:`servo.hand.HandStay`)."""

    action: str
    current_a: float | None
    duration: float = 3.0
    kind: str = "hand"

    def build(self, start: np.ndarray, ctx: PlanContext) -> Trajectory:
        return HandStay(start, self.duration, self.action, self.current_a)


def _angles(cfg: ConfigTable, base: str, n: int, required: bool = True) -> np.ndarray | None:
    """``base_deg`` or ``base_rad`` (exactly one) as n angles in rad."""
    has_deg, has_rad = f"{base}_deg" in cfg, f"{base}_rad" in cfg
    if has_deg and has_rad:
        raise cfg.error(f"{base}_deg", f"either {base}_deg or {base}_rad, not both")
    if has_deg:
        return deg_to_rad(np.array(cfg.floats(f"{base}_deg", length=n)))
    if has_rad:
        return np.array(cfg.floats(f"{base}_rad", length=n))
    if required:
        raise cfg.error(f"{base}_deg", f"a list of {n} angles in degrees (or {base}_rad in radians)")
    return None


def _speed(cfg: ConfigTable) -> float:
    s = cfg.get_float("speed", 1.0)
    if not 0.0 < s <= 1.0:
        raise cfg.error("speed", "a speed factor in (0, 1] (0.5 makes the move twice as long)", s)
    return s


def parse_quintic(cfg: ConfigTable, n: int) -> MoveSpec:
    target = _angles(cfg, "targets", n, required=False)
    delta = _angles(cfg, "deltas", n, required=False)
    if (target is None) == (delta is None):
        raise cfg.error("targets_deg", f"exactly one of targets_deg/targets_rad/deltas_deg/deltas_rad ({n} angles)")
    move = QuinticMove(target, delta, _speed(cfg))
    cfg.check_unknown({"type", "targets_deg", "targets_rad", "deltas_deg", "deltas_rad", "speed"})
    return move


def parse_lspb(cfg: ConfigTable, n: int) -> MoveSpec:
    if ("via_deg" in cfg) == ("via_rad" in cfg):
        raise cfg.error("via_deg", f"exactly one of via_deg/via_rad: a list of points of {n} angles")
    key = "via_deg" if "via_deg" in cfg else "via_rad"
    raw = cfg.raw(key)
    if not isinstance(raw, list) or not raw:
        raise cfg.error(key, f"a non-empty list of points of {n} angles", raw)
    if len(raw) > MAX_VIA_POINTS:
        raise cfg.error(key, f"at most {MAX_VIA_POINTS} via points (split a longer path into several moves)",
                        f"{len(raw)} points")
    vias = []
    for i, p in enumerate(raw):
        if (not isinstance(p, list) or len(p) != n
                or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in p)):
            raise cfg.error(f"{key}[{i}]", f"a list of {n} numbers", p)
        arr = np.array(p, float)
        vias.append(deg_to_rad(arr) if key == "via_deg" else arr)
    move = LspbMove(tuple(vias), _speed(cfg))
    cfg.check_unknown({"type", "via_deg", "via_rad", "speed"})
    return move


def parse_wait(cfg: ConfigTable, n: int) -> MoveSpec:
    move = WaitMove(cfg.get_float("duration_s", min=0.0))
    cfg.check_unknown({"type", "duration_s"})
    return move


def parse_hand(cfg: ConfigTable, n: int) -> MoveSpec:
    action = cfg.get_str("action", choices=tuple(ACTIONS))
    amps = cfg.get_float("current_a", min=1e-3, max=100.0) if "current_a" in cfg else None
    move = HandMove(action, amps, cfg.get_float("duration_s", 3.0, min=0.0, max=3600.0))
    cfg.check_unknown({"type", "action", "current_a", "duration_s"})
    return move


MOVE_TYPES: dict[str, MoveParser] = {"quintic": parse_quintic, "lspb": parse_lspb, "wait": parse_wait,
                                     "stay": parse_wait, "vservo": parse_vservo,
                                     "cartesian": parse_cartesian, "blendx": parse_blendx,
                                     "hand": parse_hand}


# ---- files --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Motion:
    """A parsed motion: its ``moves``, ``name`` and ``source`` (file path or "<demo>")."""

    moves: tuple[MoveSpec, ...]
    name: str
    source: str

    def sequencer(self, start: np.ndarray, ctx: PlanContext) -> Sequencer:
        """A fresh :class:`~servo.trajectory.Sequencer` playing this motion from ``start`` (rad)."""
        return Sequencer(list(self.moves), start, ctx)


def parse_motion(cfg: ConfigTable, n_joints: int) -> Motion:
    """Parse a motion table; :class:`hal.config.ConfigError` names the file and key on any problem."""
    moves: list[MoveSpec] = []
    tables = cfg.tables("move")
    if len(tables) > MAX_MOVES:
        raise cfg.error("move", f"at most {MAX_MOVES} moves", f"{len(tables)} moves")
    for mv in tables:
        kind = mv.get_str("type", "quintic")
        if kind not in MOVE_TYPES:
            raise mv.error("type", "one of " + ", ".join(sorted(MOVE_TYPES)), kind)
        moves.append(MOVE_TYPES[kind](mv, n_joints))
    if not moves:
        raise cfg.error("move", "at least one [[move]]")
    name = cfg.get_str("name", Path(cfg.source).stem)
    cfg.check_unknown({"move", "name", "description"})
    return Motion(tuple(moves), name, cfg.source)


def load_motion(path: str | Path, n_joints: int) -> Motion:
    """Read (at most :data:`MAX_MOTION_FILE_BYTES`) and parse a motion file for a rig with
    ``n_joints`` joints."""
    return parse_motion(load_toml(path, MAX_MOTION_FILE_BYTES), n_joints)


#: the ``--motion`` value that means "no motion: hold the joints where they are"
NO_MOTION = "none"


def hold_motion(source: str = "<hold>") -> Motion:
    """No motion: the loop holds the joints where they are (a console then moves them)."""
    return Motion((WaitMove(0.0),), "hold", source)


DEMO_DELTAS_DEG = (20.0, -15.0, 10.0, -10.0, 15.0, -20.0)


def default_demo_motion(n_joints: int, hold_s: float = 10.0, speed: float = 0.5) -> Motion:
    """The default demo: one coordinated quintic move of every joint (by 20, −15, 10, −10, 15, −20°,
    repeated for more joints, relative to where it starts) at ``speed``, then a hold of ``hold_s``
    (≥ 8 s, long enough to measure a limit cycle)."""
    if hold_s < 8.0:
        raise ConfigError("<demo>", "hold_s", "a hold of at least 8 s", hold_s)
    deltas = deg_to_rad(np.array([DEMO_DELTAS_DEG[j % len(DEMO_DELTAS_DEG)] for j in range(n_joints)]))
    return Motion((QuinticMove(None, deltas, speed), WaitMove(hold_s)), "demo", "<demo>")


