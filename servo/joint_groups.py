"""Mechanical units: a rig's joints grouped by the controller that runs them.

MELMALEC's sixteen motors form five 3-axis units (four legs and the arm; the crawler drive goes
with the unit the rig file names), and the paper runs each unit on its own processor with its
own A/D and D/A converters (docs/melmalec.md). A rig file declares them::

    [[rig.unit]]
    name = "leg1"
    joints = ["leg1_swing", "leg1_lift", "leg1_knee"]

Every joint belongs to exactly one unit, and a unit owns every board its joints are wired to
(and the board of the rig's enable-watchdog line, of calibration references and loopbacks):
no board may serve two units, so a unit controller can be given its own boards and nothing
else (:func:`unit_rig`). A rig without ``[[rig.unit]]`` has no units (:func:`rig_units` → []).

A unit controller runs its columns of one global motion (:class:`UnitSegments`): every unit
plans the same global move list from the same start and samples only its own joints, so the
units' segments start and end together and the numbers are the single controller's, column
for column.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from hal.config import ConfigError, ConfigTable
from servo.rig import RigSpec, rig_from_table
from servo.trajectory.base import Sample
from servo.trajectory.sequencer import MoveSpec, PlanContext, Sequencer


@dataclass(frozen=True)
class UnitSpec:
    """One unit: its name, its joints (rig order) with their indices in the rig, its boards."""

    name: str
    joints: tuple[str, ...]
    indices: tuple[int, ...]
    boards: tuple[str, ...]


def rig_units(spec: RigSpec) -> list[UnitSpec]:
    """The rig's ``[[rig.unit]]`` tables, checked (every joint in exactly one unit, no board
    shared between units); ``[]`` when the rig declares none."""
    rig = spec.table.table("rig", {})
    if "unit" not in rig:
        return []
    tables = rig.tables("unit")
    index = {j.name: j.index for j in spec.joints}
    owner: dict[str, str] = {}
    board_owner: dict[str, str] = {}
    units: list[UnitSpec] = []
    for t in tables:
        name = t.get_str("name")
        if any(u.name == name for u in units):
            raise t.error("name", "a unit name not used before", name)
        raw = t.raw("joints")
        if not isinstance(raw, list) or not raw or not all(isinstance(x, str) for x in raw):
            raise t.error("joints", "a non-empty list of joint names", raw)
        for jn in raw:
            if jn not in index:
                raise t.error("joints", f"names of [[joint]] tables ({', '.join(index)})", jn)
            if jn in owner:
                raise t.error("joints", f"joints of this unit only ({jn!r} is in unit {owner[jn]!r} too)", jn)
            owner[jn] = name
        t.check_unknown({"name", "joints"})
        idx = tuple(sorted(index[jn] for jn in raw))
        boards = _unit_boards(spec, idx)
        for b in boards:
            if b in board_owner:
                raise t.error("joints", f"joints on boards of this unit only (board {b!r} serves unit "
                                        f"{board_owner[b]!r} too; give each unit its own boards)", raw)
            board_owner[b] = name
        units.append(UnitSpec(name, tuple(spec.joints[i].name for i in idx), idx, boards))
    missing = [j.name for j in spec.joints if j.name not in owner]
    if missing:
        raise ConfigError(spec.table.source, "rig.unit", f"every joint in a unit ({', '.join(missing)} in none)")
    extra = _rig_level_boards(spec)
    for b in extra:
        if b not in board_owner:
            raise ConfigError(spec.table.source, "rig.unit",
                              f"a unit owning board {b!r} (the watchdog line or a calibration pin is on it, "
                              f"no unit's joint is)")
    return units


def _unit_boards(spec: RigSpec, indices: tuple[int, ...]) -> tuple[str, ...]:
    boards: list[str] = []
    for i in indices:
        for pin in spec.joints[i].wiring.values():
            if pin.board not in boards:
                boards.append(pin.board)
    return tuple(boards)


def _rig_level_boards(spec: RigSpec) -> list[str]:
    """Boards wired by the rig rather than by a joint: the watchdog line, references, loopbacks."""
    pins = [*spec.references, *spec.loopback.keys(), *spec.loopback.values()]
    if spec.watchdog is not None:
        pins.append(spec.watchdog.line)
    return sorted({p.board for p in pins})


def unit_named(units: list[UnitSpec], name: str, source: str) -> UnitSpec:
    """The unit called ``name``; a ConfigError listing the rig's units otherwise."""
    for u in units:
        if u.name == name:
            return u
    known = ", ".join(u.name for u in units) or "none: the rig file has no [[rig.unit]] tables"
    raise ConfigError(source, "rig.unit", f"a unit of this rig ({known})", name)


def unit_rig(spec: RigSpec, unit: UnitSpec) -> RigSpec:
    """The rig file as the unit controller sees it: the unit's joints (rig order), the boards it
    owns, the watchdog line and calibration pins only when they are on its boards."""
    data = copy.deepcopy(spec.table.data)
    mine = set(unit.joints)
    boards = set(unit.boards)
    data["joint"] = [j for j in data.get("joint", []) if j.get("name") in mine]
    crate = data.setdefault("crate", {})
    crate["board"] = [b for b in crate.get("board", []) if b.get("name") in boards]
    rig = data.setdefault("rig", {})
    rig["unit"] = [u for u in rig.get("unit", []) if u.get("name") == unit.name]
    wd = spec.watchdog
    if wd is not None and wd.line.board not in boards:
        rig.pop("watchdog", None)
    def on_mine(pin_text: object) -> bool:
        return str(pin_text).partition(":")[0] in boards

    if isinstance(rig.get("references"), dict):
        rig["references"] = {k: v for k, v in rig["references"].items() if on_mine(k)}
    if isinstance(rig.get("loopback"), dict):  # a DAC → ADC pair across two units' boards is dropped
        rig["loopback"] = {k: v for k, v in rig["loopback"].items() if on_mine(k) and on_mine(v)}
    if isinstance(rig.get("readback"), dict):  # digital read-back stays on one board
        rig["readback"] = {k: v for k, v in rig["readback"].items() if on_mine(k)}
    return rig_from_table(ConfigTable(data, spec.table.source), spec.path)


def watchdog_unit(spec: RigSpec, units: list[UnitSpec]) -> str | None:
    """The unit whose board carries the enable-watchdog line (``None``: no line)."""
    if spec.watchdog is None:
        return None
    for u in units:
        if spec.watchdog.line.board in u.boards:
            return u.name
    return None


class UnitSegments(Sequencer):
    """A unit's segment of the global motion: the whole move list planned from the whole rig's
    start (exactly as one controller of every joint plans it), sampled for the unit's joints
    only. Every unit's segments therefore start and end together, with the same numbers."""

    def __init__(self, moves: list[MoveSpec], start: np.ndarray, ctx: PlanContext, indices: tuple[int, ...]) -> None:
        super().__init__(moves, start, ctx)
        self.indices = np.asarray(indices, dtype=np.intp)

    def sample(self, t: float) -> Sample:
        s = super().sample(t)
        idx = self.indices
        alpha = np.asarray(s.alpha_d, float)
        return Sample(np.asarray(s.theta_d)[idx], np.asarray(s.omega_d)[idx], alpha[idx] if alpha.ndim else alpha,
                      s.done)
