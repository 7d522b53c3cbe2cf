"""Named controllers per joint, selected at run time ((DM)²: "allows for the definition of several
different controllers, and allows the system to select among them at runtime").

A rig file names controllers per joint; each is the settings of the rig's control objects for
that joint (the pid object's gains and its velocity filter, :mod:`servo.control.velocity_filter`)::

    [[joint]]
    name = "j1"
    [joint.servo]
    controller = "stiff"                   # the rig's default for this joint (default: "default")
    [joint.servo.velocity_filter]          # the joint's own controller ("default") may use the filter
    cutoff_hz = 8.0
    [[joint.controller]]
    name = "stiff"
    objects = ["pid", "torque_limit"]      # optional; the rig's [servo] objects (only those switch)
    [joint.controller.pid]
    kp = 200.0                             # a gain not given: the joint's own ([joint.servo] gains)
    velocity_filter = { cutoff_hz = 5.0 }  # optional: the filter alternative to KvI

Every joint has the controller ``"default"`` (index 0): its ``[joint.servo]`` gains and velocity
filter; the named ones follow in file order (index 1, 2, …: MAVLink's ``J<n>_CTRL``). Each named
controller's gains pass the one gain guard (:mod:`servo.gain_guard`) when the rig file is read.

A switch (:func:`use_controller`, inside a live command: at a tick boundary) is ros2_control's
``switch_controller`` with ``activate = [NAME]`` and ``deactivate = [the joint's active one]`` in
one step (strictness STRICT: any joint refused, none switches). It is refused, naming the guard's
reason, when the new gains fail the gain guard with the joint's switch-off in force. It is
bumpless: :meth:`servo.control.law.PidLaw.switch_joint` sets the joint's position integrator so
the first tick's output is the old controller's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.config import ConfigError, ConfigTable
from servo.control.errors import ControlError
from servo.control.gains import GAIN_NAMES, Gains
from servo.control.law import PidLaw
from servo.control.velocity_filter import NO_FILTER, VelocityFilter
from servo.gain_guard import GainRejected, check_gain_set
from servo.rig import RigSpec

__all__ = ["DEFAULT_CONTROLLER", "ControllerChoices", "NamedController", "parse_controllers",
           "parse_velocity_filter", "use_controller"]

#: the name of each joint's own controller (its [joint.servo] settings)
DEFAULT_CONTROLLER = "default"


@dataclass(frozen=True)
class NamedController:
    """One joint's named controller: the pid object's ``gains`` and velocity filter
    (``filter_hz``, NaN: none — the KvI channel integrates ė)."""

    name: str
    gains: Gains[float]
    filter_hz: float = NO_FILTER

    def describe(self) -> dict[str, Any]:
        return {"name": self.name, "gains": self.gains.as_dict(),
                "velocity_filter_hz": None if math.isnan(self.filter_hz) else self.filter_hz}


@dataclass(frozen=True)
class ControllerChoices:
    """Per joint its controllers (index 0: ``"default"``) and the rig's default (``start``)."""

    per_joint: tuple[tuple[NamedController, ...], ...]
    start: tuple[int, ...]

    def names(self, joint: int) -> list[str]:
        return [c.name for c in self.per_joint[joint]]

    def index(self, joint: int, name: str) -> int | None:
        for i, c in enumerate(self.per_joint[joint]):
            if c.name == name:
                return i
        return None

    @property
    def any_named(self) -> bool:
        """Whether some joint has more than its default controller."""
        return any(len(cs) > 1 for cs in self.per_joint)


def parse_velocity_filter(cfg: ConfigTable) -> float:
    """A ``velocity_filter`` table (``cutoff_hz``) → the cutoff in Hz."""
    hz = cfg.get_float("cutoff_hz", min=0.0)
    if not hz > 0.0:
        raise cfg.error("cutoff_hz", "a cutoff above 0 Hz", hz)
    cfg.check_unknown({"cutoff_hz"})
    return float(VelocityFilter(hz).cutoff_hz)


def parse_controllers(rig: RigSpec, objects: Sequence[str], gains: Gains[np.ndarray], filter_hz: Sequence[float],
                      switch_off: Any, delay: float) -> ControllerChoices:
    """Each joint's ``[[joint.controller]]`` tables and ``[joint.servo] controller`` (the module
    docstring); ``gains``/``filter_hz``: the joints' own settings (the ``"default"`` controllers).
    Errors are :class:`ConfigError` naming the file and key (a guard's refusal included)."""
    per_joint: list[tuple[NamedController, ...]] = []
    start: list[int] = []
    for j, spec in enumerate(rig.joints):
        own = NamedController(DEFAULT_CONTROLLER, gains.joint(j), float(filter_hz[j]))
        found = [own]
        tables = spec.table.tables("controller", [])
        for t in tables:
            name = t.get_str("name")
            if not name or any(c.name == name for c in found) or name.isdigit():
                raise t.error("name", "a controller name not used before for this joint (and not "
                                      f"{DEFAULT_CONTROLLER!r} or a number)", name)
            given = t.raw("objects", list(objects))
            if given != list(objects):
                raise t.error("objects", f"the rig's objects {list(objects)} (a switch changes the parameters of the "
                                         "same objects)", given)
            if "pid" not in objects:
                raise t.error("name", "a rig whose controller has a pid object (the named controllers set its gains)")
            pid = t.table("pid", {})
            changes = {k: pid.get_float(k, min=0.0) for k in GAIN_NAMES if k in pid}
            f_hz = parse_velocity_filter(pid.table("velocity_filter")) if "velocity_filter" in pid else NO_FILTER
            pid.check_unknown({*GAIN_NAMES, "velocity_filter"})
            t.check_unknown({"name", "objects", "pid"})
            hz = np.array(filter_hz, float)
            hz[j] = f_hz
            try:
                check_gain_set(gains, switch_off, changes, rig.period_s, delay, joint=j, filter_hz=hz)
            except GainRejected as e:
                raise ConfigError(t.source, t.key("pid"), "gains the gain guard accepts", e.reason) from None
            found.append(NamedController(name, own.gains.replace(**changes), f_hz))
        chosen = spec.servo.get_str("controller", DEFAULT_CONTROLLER) if "controller" in spec.servo \
            else DEFAULT_CONTROLLER
        idx = next((i for i, c in enumerate(found) if c.name == chosen), None)
        if idx is None:
            raise spec.servo.error("controller", "one of " + ", ".join(c.name for c in found), chosen)
        per_joint.append(tuple(found))
        start.append(idx)
    return ControllerChoices(tuple(per_joint), tuple(start))


def use_controller(law: PidLaw, choices: ControllerChoices, active: list[int], name: str,
                   joints: Sequence[int], period_s: float, delay: float) -> list[int]:
    """Switch ``joints`` (indices) to their controller ``name`` at the next tick, bumpless, all or
    none; ``active`` (per joint the index in force) is updated. Call at a tick boundary (inside a
    live command). Raises :class:`ControlError` for an unknown name, :class:`GainRejected` (the
    guard's reason) for gains the guard refuses. Returns the indices switched to."""
    picks = []
    for j in joints:
        i = choices.index(j, name)
        if i is None:
            raise ControlError(f"joint {j + 1} has no controller {name!r}; it has " + ", ".join(choices.names(j)))
        picks.append((j, choices.per_joint[j][i], i))
    so = getattr(law, "_pending_switch_off", None) or law.switch_off
    for j, c, _ in picks:
        hz = law.filter_hz.copy()
        hz[j] = c.filter_hz
        check_gain_set(law.gains, so, c.gains.as_dict(), period_s, delay, joint=j, filter_hz=hz)
    for j, c, i in picks:
        law.switch_joint(j, c.gains, c.filter_hz)
        active[j] = i
    return [i for _, _, i in picks]
