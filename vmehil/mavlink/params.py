"""The MAVLink parameter table of a servo loop: names, units, ranges, read and apply.

Every parameter is a REAL32 (MAVLink ``MAV_PARAM_TYPE_REAL32``), SI units, named
``J<n>_<FIELD>`` with ``<n>`` the 1-based joint number (the rig's joint order) — at most 16
characters. Per joint, in this order (the index of a parameter is its position in the table):

============  ========  =======================  ==========================================
name          unit      writable range           meaning
============  ========  =======================  ==========================================
J1_KP         1/s²      0 … 1e5                  position gain Kp
J1_KPI        1/s³      0 … 1e7                  position integral gain Kpi
J1_KV         1/s       0 … 1e4                  velocity gain Kv
J1_KVI        1/s²      0 … 1e6                  velocity integral gain KvI
J1_SO_EN      —         0 or 1                   integrator switch-off enabled
J1_SO_IN      rad       0 … 0.5, < J1_SO_OUT     switch-off inner band (switch off at or below)
J1_SO_OUT     rad       0 … 0.5, > J1_SO_IN      switch-off outer band (switch back on above)
J1_SO_BOOST   —         0 (auto) or 1 … 10       Kp factor while switched off; 0 = (Kp+KvI)/Kp
J1_SO_SETTLE  s         0 … 10                   time in the inner band before switching off
J1_TAU_MAX    N·m       > 0 … configured value   torque limit at the joint (if the rig has one)
J1_FERR_MAX   rad       > 0 … configured value   watchdog following-error limit
J1_VEL_MAX    rad/s     read-only                trajectory planning velocity limit
J1_CTRL       —         0 … controllers − 1      the joint's controller in force, an index
                                                 (0 "default", then the rig's named ones)
============  ========  =======================  ==========================================

``J<n>_CTRL`` is there only when the rig file names controllers (``[[joint.controller]]``,
:mod:`servo.named_controllers`), for every joint; setting it switches that joint at the tick
boundary, bumpless, refused (``out_of_range``, with the guard's reason) when the gain guard
refuses the controller's gains.

and, after the joints, ``SERVO_RATE_HZ`` (read-only, the loop rate). Gains, switch-off settings
and limits are checked when received (finite, in range) and again when applied at the tick
boundary: a gain or boost that :mod:`servo.gain_guard` refuses for that joint (the one rule of the
console and the command line: the sampled loop unstable or marginal, integrating or switched off)
is refused, with the guard's reason. Limits may
be tightened, and loosened back up to the value the run started with — never beyond it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from servo.control.gains import GAIN_DESCRIPTIONS, GAIN_NAMES, GAIN_UNITS
from servo.control.law import SwitchOffConfig
from servo.gain_guard import GAIN_MAX, GainRejected, check_gain_change
from servo.named_controllers import use_controller
from vmehil.errors import VmehilError

MAX_NAME_LEN = 16

# refusal codes (mapped to MAV_PARAM_ERROR_* by the endpoint)
DOES_NOT_EXIST = "does_not_exist"
READ_ONLY = "read_only"
OUT_OF_RANGE = "out_of_range"
PERMISSION_DENIED = "permission_denied"


class ParamRefused(VmehilError):
    """A parameter read or write was refused: ``code`` (one of the codes above) and ``reason``."""

    def __init__(self, code: str, name: str, reason: str) -> None:
        self.code = code
        self.name = name
        self.reason = reason
        super().__init__(f"{name}: {reason}")


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: ``name``, ``key`` (what it controls), ``joint`` (0-based, None for global),
    ``unit``, inclusive range ``lo``..``hi`` (``lo_open``: lo itself excluded), ``special`` values
    allowed outside the range (e.g. 0 = auto), ``integer`` (0/1 flags), ``writable``, ``doc``."""

    name: str
    key: str
    joint: int | None
    unit: str
    lo: float
    hi: float
    writable: bool
    doc: str
    lo_open: bool = False
    special: tuple[float, ...] = ()
    integer: bool = False

    def describe_range(self) -> str:
        if not self.writable:
            return "read-only"
        lo = f"> {self.lo:g}" if self.lo_open else f"{self.lo:g}"
        text = f"{lo} … {self.hi:g}"
        if self.integer:
            text = " or ".join(f"{v:g}" for v in np.arange(self.lo, self.hi + 1))
        if self.special:
            text = " or ".join(f"{v:g}" for v in self.special) + " or " + text
        return text


#: gain name → (upper limit, unit, description): the guard's limits, advertised as the writable ranges
GAIN_RANGES = {k: (GAIN_MAX[k], GAIN_UNITS[k], GAIN_DESCRIPTIONS[k]) for k in GAIN_NAMES}
BAND_MAX_RAD = 0.5
BOOST_MAX = 10.0
SETTLE_MAX_S = 10.0


class ParamTable:
    """The parameters of ``loop`` (a :class:`servo.loop.ServoLoop` or an object with the same
    attributes: ``n``, ``period_s``, ``law``, ``controller.active.find``, ``watchdog``, and
    optionally ``plan_context``).

    ``delay_periods`` is the computation delay used by the stability check (0..1 periods),
    ``min_margin`` the stability margin (1 − spectral radius) a new gain set must keep.
    Limits seen at construction are the ceilings of the writable limit parameters.
    """

    def __init__(self, loop: Any, *, delay_periods: float = 0.0, min_margin: float = 0.0) -> None:
        self.loop = loop
        self.delay = float(delay_periods)
        self.min_margin = float(min_margin)
        self.period_s = float(loop.period_s)
        self._staged_so: tuple[int, SwitchOffConfig] | None = None
        n = int(loop.n)
        tl = self._torque_limit()
        self._tau_ceiling = None if tl is None else np.array(tl.tau_max, float).copy()
        self._ferr_ceiling = np.array(loop.watchdog.following_error_rad, float).copy()
        specs: list[ParamSpec] = []
        for j in range(n):
            p = f"J{j + 1}_"
            if loop.law is not None:
                for key, (hi, unit, doc) in GAIN_RANGES.items():
                    specs.append(ParamSpec(p + key.upper(), key, j, unit, 0.0, hi, True, doc))
                specs += [
                    ParamSpec(p + "SO_EN", "so_enabled", j, "", 0.0, 1.0, True, "integrator switch-off enabled",
                              integer=True),
                    ParamSpec(p + "SO_IN", "so_inner", j, "rad", 0.0, BAND_MAX_RAD, True,
                              "switch-off inner band (switch off at or below)"),
                    ParamSpec(p + "SO_OUT", "so_outer", j, "rad", 0.0, BAND_MAX_RAD, True,
                              "switch-off outer band (integrate again above)", lo_open=True),
                    ParamSpec(p + "SO_BOOST", "so_boost", j, "", 1.0, BOOST_MAX, True,
                              "Kp factor while switched off (0 = auto, (Kp+KvI)/Kp)", special=(0.0,)),
                    ParamSpec(p + "SO_SETTLE", "so_settle", j, "s", 0.0, SETTLE_MAX_S, True,
                              "time in the inner band before switching off"),
                ]
            if self._tau_ceiling is not None:
                specs.append(ParamSpec(p + "TAU_MAX", "tau_max", j, "N·m", 0.0, float(self._tau_ceiling[j]), True,
                                       "torque limit at the joint", lo_open=True))
            specs.append(ParamSpec(p + "FERR_MAX", "ferr_max", j, "rad", 0.0, float(self._ferr_ceiling[j]), True,
                                   "watchdog following-error limit", lo_open=True))
            if getattr(loop, "plan_context", None) is not None:
                specs.append(ParamSpec(p + "VEL_MAX", "vel_max", j, "rad/s", 0.0, 0.0, False,
                                       "trajectory planning velocity limit"))
            choices = getattr(loop, "controllers", None)
            if choices is not None and choices.any_named and loop.law is not None:
                specs.append(ParamSpec(p + "CTRL", "ctrl", j, "", 0.0, float(len(choices.per_joint[j]) - 1), True,
                                       "controller in force (index: 0 default, then the rig's named ones)",
                                       integer=True))
        specs.append(ParamSpec("SERVO_RATE_HZ", "rate", None, "Hz", 0.0, 0.0, False, "servo loop rate"))
        for s in specs:
            if len(s.name) > MAX_NAME_LEN:
                raise ValueError(f"parameter name {s.name!r} is longer than {MAX_NAME_LEN} characters")
        self.specs = specs
        self._index = {s.name: i for i, s in enumerate(specs)}

    # --- lookup ------------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.specs)

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.specs]

    def find(self, name: str) -> tuple[int, ParamSpec]:
        """(index, spec) of ``name``; :class:`ParamRefused` (does_not_exist) if unknown."""
        i = self._index.get(name)
        if i is None:
            raise ParamRefused(DOES_NOT_EXIST, name, "no such parameter (names look like J1_KP; see docs/mavlink.md)")
        return i, self.specs[i]

    def at(self, index: int) -> ParamSpec:
        if not 0 <= index < len(self.specs):
            raise ParamRefused(DOES_NOT_EXIST, f"#{index}", f"no parameter with index {index} (0..{len(self) - 1})")
        return self.specs[index]

    # --- read ----------------------------------------------------------------------------------------
    def _torque_limit(self) -> Any:
        find = getattr(self.loop.controller.active, "find", None)
        return None if find is None else find("torque_limit")

    def value(self, spec: ParamSpec) -> float:
        """The value in force now (SI)."""
        loop, j, key = self.loop, spec.joint, spec.key
        if key == "rate":
            return 1.0 / self.period_s
        if key in GAIN_RANGES:
            return float(getattr(loop.law.gains, key)[j])
        if key.startswith("so_"):
            so = loop.law.switch_off
            if key == "so_enabled":
                return 1.0 if so.enabled[j] else 0.0
            if key == "so_boost":
                b = float(so.kp_boost[j])
                return 0.0 if math.isnan(b) else b
            return float({"so_inner": so.inner_band, "so_outer": so.outer_band, "so_settle": so.settle_time}[key][j])
        if key == "tau_max":
            tl = self._torque_limit()
            return math.nan if tl is None else float(tl.tau_max[j])
        if key == "ferr_max":
            return float(loop.watchdog.following_error_rad[j])
        if key == "vel_max":
            return float(loop.plan_context.limits.v_max[j])
        if key == "ctrl":
            return float(loop.active_controller[j])
        raise AssertionError(key)  # pragma: no cover

    # --- write ---------------------------------------------------------------------------------------
    def check(self, spec: ParamSpec, value: float) -> float:
        """Static checks (no loop state needed): writable, finite, in range. Returns the value."""
        if not spec.writable:
            raise ParamRefused(READ_ONLY, spec.name, "is read-only")
        v = float(value)
        if not math.isfinite(v):
            raise ParamRefused(OUT_OF_RANGE, spec.name, f"{v} is not a finite number")
        if v in spec.special:
            return v
        below = v <= spec.lo if spec.lo_open else v < spec.lo
        if below or v > spec.hi or (spec.integer and v != round(v)):
            raise ParamRefused(OUT_OF_RANGE, spec.name,
                               f"{v:g} {spec.unit} is out of range (allowed: {spec.describe_range()})")
        return v

    def apply_command(self, spec: ParamSpec, value: float) -> Callable[[Any], float]:
        """A live command for :meth:`servo.loop.ServoLoop.submit`: re-checks against the state at
        the tick boundary (stability, band order), applies the change and returns the new value."""
        v = self.check(spec, value)

        def command(loop: Any) -> float:
            return self._apply(spec, v)

        return command

    def _apply(self, spec: ParamSpec, v: float) -> float:
        loop, j, key = self.loop, spec.joint, spec.key
        assert j is not None
        if key in GAIN_RANGES or key.startswith("so_"):
            law = loop.law
            so = self._switch_off_now()
            enabled, inner, outer = so.enabled.copy(), so.inner_band.copy(), so.outer_band.copy()
            boost, settle = so.kp_boost.copy(), so.settle_time.copy()
            if key == "so_enabled":
                enabled[j] = bool(v)
            elif key == "so_inner":
                inner[j] = v
            elif key == "so_outer":
                outer[j] = v
            elif key == "so_boost":
                boost[j] = math.nan if v == 0.0 else v
            elif key == "so_settle":
                settle[j] = v
            new = SwitchOffConfig(enabled, inner, outer, boost, settle, so.zero_crossing.copy())
            if key in GAIN_RANGES or key in ("so_enabled", "so_boost"):
                try:  # the one guard, as the console and the command line use it
                    check_gain_change(law, j, {key: v} if key in GAIN_RANGES else {}, self.period_s, self.delay,
                                      min_margin=self.min_margin, switch_off=new)
                except GainRejected as e:
                    raise ParamRefused(OUT_OF_RANGE, spec.name, f"{v:g} refused: {e.reason}") from None
            if key in GAIN_RANGES:
                law.set_gains(**{key: v}, joint=j)
                return v
            if key in ("so_inner", "so_outer") and not outer[j] > inner[j]:
                raise ParamRefused(OUT_OF_RANGE, spec.name,
                                   f"{v:g} rad refused: the outer band ({outer[j]:g} rad) must exceed the inner band "
                                   f"({inner[j]:g} rad)")
            law.set_switch_off(new)
            self._staged_so = (int(loop.tick_count), new)
            return v
        if key == "tau_max":
            tl = self._torque_limit()
            if tl is None:
                raise ParamRefused(DOES_NOT_EXIST, spec.name, "the active controller has no torque limit")
            tau = np.array(tl.tau_max, float)
            tau[j] = v
            tl.tau_max = tau
            return v
        if key == "ctrl":
            name = loop.controllers.per_joint[j][int(v)].name
            try:  # the switch the console's `controller use` makes: guarded, bumpless, at this tick boundary
                use_controller(loop.law, loop.controllers, loop.active_controller, name, [j], self.period_s,
                               self.delay)
            except GainRejected as e:
                raise ParamRefused(OUT_OF_RANGE, spec.name, f"{v:g} ({name}) refused: {e.reason}") from None
            return v
        if key == "ferr_max":
            ferr = np.array(loop.watchdog.following_error_rad, float)
            ferr[j] = v
            loop.watchdog.following_error_rad = ferr
            return v
        raise ParamRefused(READ_ONLY, spec.name, "is read-only")  # pragma: no cover

    def _switch_off_now(self) -> SwitchOffConfig:
        """The switch-off configuration in force at this tick, including one staged earlier in it."""
        if self._staged_so is not None and self._staged_so[0] == int(self.loop.tick_count):
            return self._staged_so[1]
        return self.loop.law.switch_off
