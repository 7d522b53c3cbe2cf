"""The servo's settings from the rig file, parsed once into typed frozen values.

Rig-level ``[servo]`` gives defaults; each ``[joint.servo]`` may override them::

    [servo]
    objects = ["pid", "torque_limit"]          # control objects, in order
    gains = { kp = 100.0, kpi = 5000.0, kv = 50.0, kvi = 1000.0 }
    switch_off = { enabled = true, inner_band_deg = 0.3, outer_band_deg = 1.5, kp_boost = 2.0 }
    max_velocity_deg_s = 30.0                  # trajectory planning limit
    following_error_limit_deg = 10.0           # watchdog
    require_homing = false                     # true: no move before the encoders are homed
    blackbox_s = 5.0                           # seconds the black box keeps before a stop (servo.blackbox)

    [joint.servo]
    position = "pot"                           # or "encoder"
    velocity = "tach"                          # or "encoder"
    gains = { kp = 120.0 }                     # per-joint overrides
    torque_limit_nm = 84.7                     # default: nominal current limit · Kt · N

The controller's plant figures (normalizing chain J, N, Kt, amplifier gain; the default torque
limit) are the rig file's ``[joint.servo.nominal]`` values (:mod:`servo.nominal`), never the
emulated plant's.

The gains of the rig file go through the one gain guard (:mod:`servo.gain_guard`), as a gain
set from the command line, the console or MAVLink does: a value beyond its limit or a set whose
sampled loop (at the rig's period and computation delay, with the joint's switch-off) is
unstable is refused with a :class:`hal.config.ConfigError` naming the file and key.

The watchdog's cross-checks (:mod:`servo.watchdog`, docs/faults.md) take their limits from
``[servo.watchdog]`` (rig-wide) and ``[joint.servo.watchdog]`` (per joint, wins); every key is
optional — the defaults are derived from the sensors' resolution and, for the tach dead band,
from the controller's own ``[joint.servo.nominal] tach_dead_band_rad_s`` (the datasheet's brush
drop / gradient; never the plant's table)::

    [servo.watchdog]
    cross_checks = true                # false: encoder/pot, tach and current checks off
    velocity_window_ticks = 12         # rig-wide only (with the other *_ticks and *_fraction keys)
    current_mismatch_ticks = 3
    stale_ticks = 25                   # with stale_travel_deg: a reading that stays put while moving
    position_tolerance_fraction = 0.02
    velocity_tolerance_fraction = 0.05
    [joint.servo.watchdog]
    position_tolerance_deg = 0.7       # encoder vs pot, plus the fraction of the travel
    velocity_tolerance_deg_s = 1.0     # tach vs position derivative, beyond the dead band
    tach_dead_band_deg_s = 6.9
    current_tolerance_a = 0.2          # current monitor vs command
    current_tolerance_fraction = 0.05
    stale_travel_deg = 1.5

Soft limits (docs/motion-safety.md): each joint's ``[joint.limits]`` (inside its hard stops; a
continuous joint states none); moves are refused at plan time beyond them and the watchdog
stops the loop (cause ``soft_limit``, category 1) once a measured position passes one by the
margin::

    [servo]
    soft_limit_margin_deg = 0.5
    collision_check_points = 20        # instants of each planned move checked against the scene
    [joint.limits]
    min_deg = -163.0
    max_deg = 163.0

``[arm]`` is the arm's kinematics (:class:`hal.kinematics.ArmModel`), parsed here once.

Use::

    settings = servo_settings(rig)                       # parse (and guard) once
    settings = settings.overridden({"kp": 120.0}, switch_off=False)   # a CLI override: one check
    loop = servo.assembly.build_loop(plant, io, settings, motion=motion)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.config import ConfigTable
from hal.hand import HandModel
from hal.kinematics import ArmModel
from servo.blackbox import DEFAULT_SECONDS as DEFAULT_BLACKBOX_S
from servo.control.errors import ControlError
from servo.control.gains import DEFAULT_GAINS, GAIN_NAMES, Gains
from servo.control.law import SwitchOffConfig
from servo.control.linear import delay_periods
from servo.control.normalize import NormalizingChain
from servo.control.objects import CONTROL_OBJECTS, cfg_per_joint, parse_switch_off
from servo.gain_guard import GainRejected, check_gain_set, check_values
from servo.named_controllers import ControllerChoices, parse_controllers, parse_velocity_filter
from servo.nominal import JointNominal, nominal_chain, rig_nominal
from servo.rig import RigSpec
from servo.stops import CATEGORIES, HoldingLoad, StopSettings

__all__ = ["MIN_VELOCITY_DEG_S", "ServoSettings", "WatchdogSettings", "servo_settings"]

#: the smallest planning speed limit a rig file may set (deg/s; 0 would plan endless moves)
MIN_VELOCITY_DEG_S = 1e-3

#: the longest black box a rig file may ask for (s): 120 s of 16 joints is ~27 MB
MAX_BLACKBOX_S = 120.0

#: per-joint keys of [servo.watchdog] / [joint.servo.watchdog]: rig-file key → (WatchdogConfig field, to SI)
WATCHDOG_JOINT_KEYS: dict[str, tuple[str, float]] = {
    "position_tolerance_deg": ("position_tolerance_rad", np.pi / 180.0),
    "velocity_tolerance_deg_s": ("velocity_tolerance_rad_s", np.pi / 180.0),
    "tach_dead_band_deg_s": ("tach_dead_band_rad_s", np.pi / 180.0),
    "current_tolerance_a": ("current_tolerance_a", 1.0),
    "current_tolerance_fraction": ("current_tolerance_fraction", 1.0),
    "stale_travel_deg": ("stale_travel_rad", np.pi / 180.0),
}
WATCHDOG_RIG_INTS = ("velocity_window_ticks", "current_mismatch_ticks", "stale_ticks", "encoder_illegal_ticks",
                     "encoder_illegal_window_ticks")
WATCHDOG_RIG_FLOATS = ("position_tolerance_fraction", "velocity_tolerance_fraction")


@dataclass(frozen=True)
class WatchdogSettings:
    """The watchdog's limits from the rig file (SI). ``rig_wide``: the ``*_ticks`` and
    ``*_fraction`` keys given (WatchdogConfig field → value; absent keys keep the watchdog's
    defaults); ``per_joint``: field → one value per joint, NaN = derived from the sensors."""

    cross_checks: bool
    rig_wide: tuple[tuple[str, float], ...]
    per_joint: tuple[tuple[str, tuple[float, ...]], ...]


@dataclass(frozen=True)
class ServoSettings:
    """Everything the servo takes from the rig file, per joint, in SI units (frozen; change it
    with :meth:`overridden` or :func:`dataclasses.replace`).

    ``objects`` the control objects in order; ``gains`` the per-joint gain set (the one
    :class:`~servo.control.gains.Gains` type); ``switch_off`` the integrator switch-off;
    ``torque_limit_nm``, ``max_velocity_rad_s`` (planning limit), ``following_error_rad``
    (watchdog) one value per joint; ``chain`` the normalizing chain from the nominal figures;
    ``watchdog`` the cross-checks' limits; ``position_source`` (``"pot"``/``"encoder"``) and
    ``velocity_source`` (``"tach"``/``"encoder"``) per joint, ``velocity_source_given`` whether the
    rig stated it; ``gains_given`` per joint, which
    tables gave its gains (``"joint"``, ``"rig"``, ``"joint+rig"``, or ``""``: the paper's defaults);
    ``source`` names the rig file in errors."""

    joint_names: tuple[str, ...]
    period_s: float
    computation_delay_s: float
    objects: tuple[str, ...]
    gains: Gains[np.ndarray]
    switch_off: SwitchOffConfig
    torque_limit_nm: tuple[float, ...]
    max_velocity_rad_s: tuple[float, ...]
    following_error_rad: tuple[float, ...]
    chain: NormalizingChain
    watchdog: WatchdogSettings
    position_source: tuple[str, ...]
    velocity_source: tuple[str, ...]
    #: whether each joint's ``[joint.servo] velocity`` was stated (False: the default, the tach)
    velocity_source_given: tuple[bool, ...]
    gains_given: tuple[str, ...]
    source: str

    @property
    def n(self) -> int:
        return len(self.joint_names)

    @property
    def delay_periods(self) -> float:
        """The computation delay in servo periods (0..1), as the gain guard takes it."""
        return delay_periods(self.computation_delay_s, self.period_s)

    #: how a controlled (category-1) stop runs, and the rig file's stricter categories (servo.stops)
    stop: StopSettings = dataclasses.field(default_factory=lambda: StopSettings(decel_rad_s2=()))
    #: the soft limits per joint (rad; ``[joint.limits] min_deg / max_deg``): −inf / +inf where a
    #: joint has none (a continuous joint)
    soft_min_rad: tuple[float, ...] = ()
    soft_max_rad: tuple[float, ...] = ()
    #: how far beyond a soft limit a measured position may go before the watchdog stops the loop
    #: (cause ``soft_limit``; ``[servo] soft_limit_margin_deg``)
    soft_limit_margin_rad: float = float(np.radians(0.5))
    #: the arm's kinematics (``[arm]``; ``None``: the rig states none, no collision check)
    arm: ArmModel | None = None
    #: the instants of each planned move checked against the scene (``[servo] collision_check_points``)
    collision_points: int = 20
    #: moves (console, MAVLink) are refused until every homeable joint is homed (``[servo]
    #: require_homing``; docs/motion-safety.md, "Homing"); jogs are not
    require_homing: bool = False
    #: per joint the velocity filter's cutoff (Hz; ``[joint.servo.velocity_filter] cutoff_hz``), NaN
    #: where the KvI channel integrates ė (the paper's law, every preset); ``()``: none anywhere
    velocity_filter_hz: tuple[float, ...] = ()
    #: per joint its named controllers (``[[joint.controller]]``, servo.named_controllers) and the
    #: rig's default; ``None``: settings made without a rig file
    controllers: ControllerChoices | None = None
    #: the hand's fingers (``[hand]``, :mod:`hal.hand`; ``None``: the rig states none)
    hand: HandModel | None = None
    #: seconds of every joint's signals the black box keeps before a stop (:mod:`servo.blackbox`)
    blackbox_s: float = DEFAULT_BLACKBOX_S

    @property
    def filter_hz(self) -> np.ndarray:
        """:attr:`velocity_filter_hz` as an array of n (NaN: no filter)."""
        if len(self.velocity_filter_hz) == self.n:
            return np.asarray(self.velocity_filter_hz, float)
        return np.full(self.n, np.nan)

    def overridden(self, gains: Mapping[str, float] | None = None, switch_off: bool | None = None) -> ServoSettings:
        """These settings with ``gains`` (name → value) applied to every joint and the switch-off
        forced on or off (None: as the rig says): the one place an override (``--gains``,
        ``--no-integrator-switch-off``) is applied, with the one check — the gain guard's values
        and the stability of every joint's sampled loop with the resulting switch-off. Raises
        :class:`~servo.gain_guard.GainRejected` (nothing is changed)."""
        out = self
        if switch_off is not None:
            out = dataclasses.replace(out, switch_off=dataclasses.replace(
                out.switch_off, enabled=np.full(self.n, bool(switch_off))))
        if gains:
            if "pid" not in self.objects:
                check_values(gains)  # a value no gain may have is refused as such first
                raise ControlError(f"gain overrides {dict(gains)}: the rig's controller has no pid object to take them")
            clean = check_gain_set(out.gains, out.switch_off, gains, self.period_s, self.delay_periods,
                                   filter_hz=self.filter_hz)
            out = dataclasses.replace(out, gains=out.gains.replace(**clean))
        return out


def _collapse(d: dict[str, list[Any]]) -> dict[str, Any]:
    """Per-joint lists; a key absent for some joints takes the control law's default there."""
    out: dict[str, Any] = {}
    for k, vals in d.items():
        if any(v is None for v in vals):
            known = [v for v in vals if v is not None]
            if all(isinstance(v, bool) for v in known):
                vals = [True if v is None else v for v in vals]
            else:
                vals = ["auto" if v is None and k == "kp_boost" else v for v in vals]
                if any(v is None for v in vals):
                    continue
        out[k] = vals
    return out


def servo_settings(rig: RigSpec) -> ServoSettings:
    """The rig's servo settings, per joint (``[servo]`` defaults, ``[joint.servo]`` overrides),
    parsed and checked once: errors are :class:`hal.config.ConfigError` naming the file and key."""
    top = rig.table.table("servo", {})
    objects = top.raw("objects", ["pid", "torque_limit"])
    base_gains = top.table("gains", {})
    base_so = top.table("switch_off", {})
    gains: dict[str, list[float]] = {k: [] for k in GAIN_NAMES}
    so: dict[str, list[Any]] = {}
    tl, vmax, ferr = [], [], []
    so_keys = set(base_so.keys())
    for j in rig.joints:
        so_keys |= set(j.servo.table("switch_off", {}).keys())
    nominal = rig_nominal(rig)
    for j, nom in zip(rig.joints, nominal, strict=True):
        jg = j.servo.table("gains", {})
        for k in GAIN_NAMES:
            default = base_gains.get_float(k, DEFAULT_GAINS[k], min=0.0)
            gains[k].append(jg.get_float(k, default, min=0.0))
        jso = j.servo.table("switch_off", {})
        for k in so_keys:
            v = jso.raw(k) if k in jso else base_so.raw(k, None)  # None: the law's default
            so.setdefault(k, []).append(v)
        tl.append(j.servo.get_float("torque_limit_nm", nom.torque_limit_nm, min=0.0))
        # a planning limit of 0 would make every move infinitely long: refused here, naming the key
        vmax.append(float(np.radians(j.servo.get_float(
            "max_velocity_deg_s", top.get_float("max_velocity_deg_s", 30.0, min=MIN_VELOCITY_DEG_S),
            min=MIN_VELOCITY_DEG_S))))
        ferr.append(float(np.radians(j.servo.get_float("following_error_limit_deg",
                                                       top.get_float("following_error_limit_deg", 10.0, min=0.0)))))
    if not isinstance(objects, list):
        raise top.error("objects", "a list of control object names", objects)
    n = rig.n_joints
    # the controller table the objects were once built from: errors keep naming these keys
    built: dict[str, Any] = {"objects": list(objects), "pid": {"switch_off": _collapse(so)} if so else {},
                             "torque_limit": {"tau_max_nm": tl}}
    cfg = ConfigTable(built, f"{rig.path} (servo settings)")
    names = _check_objects(cfg, list(objects))
    # parsed where the pid object uses it, as its table always was
    switch_off = (parse_switch_off(cfg.table("pid").table("switch_off", {}), n) if "pid" in names
                  else SwitchOffConfig.make(n))
    if "torque_limit" in names:  # validated only where used (a limit of 0 is refused there)
        tau_max = cfg_per_joint(cfg.table("torque_limit"), "tau_max_nm", n, None, positive=True)
        tl = [float(x) for x in tau_max]
    per_joint_gains = Gains.make(n, **gains)
    filter_hz = [parse_velocity_filter(j.servo.table("velocity_filter")) if "velocity_filter" in j.servo else np.nan
                 for j in rig.joints]
    choices = parse_controllers(rig, names, per_joint_gains, filter_hz, switch_off,
                                delay_periods(rig.computation_delay_s, rig.period_s))
    if any(s != 0 for s in choices.start):  # the rig's default is a named controller: the joint starts with it
        start = [cs[i] for cs, i in zip(choices.per_joint, choices.start, strict=True)]
        per_joint_gains = Gains.make(n, **{k: [getattr(c.gains, k) for c in start] for k in GAIN_NAMES})
        filter_hz = [c.filter_hz for c in start]
    settings = ServoSettings(
        joint_names=tuple(j.name for j in rig.joints), period_s=rig.period_s,
        computation_delay_s=rig.computation_delay_s, objects=names, gains=per_joint_gains,
        switch_off=switch_off, torque_limit_nm=tuple(tl), max_velocity_rad_s=tuple(vmax),
        following_error_rad=tuple(ferr), chain=nominal_chain(nominal), watchdog=_watchdog(rig, nominal),
        position_source=tuple(j.servo.get_str("position", "pot", choices=("pot", "encoder")) for j in rig.joints),
        velocity_source=tuple(j.servo.get_str("velocity", "tach", choices=("tach", "encoder")) for j in rig.joints),
        velocity_source_given=tuple("velocity" in j.servo for j in rig.joints),
        stop=_stop_settings(rig, top, nominal),
        **_soft_limits(rig, top),
        arm=ArmModel.from_table(rig.table.table("arm")) if "arm" in rig.table else None,
        require_homing=top.get_bool("require_homing", False),
        hand=_hand(rig),
        blackbox_s=top.get_float("blackbox_s", DEFAULT_BLACKBOX_S, min=rig.period_s, max=MAX_BLACKBOX_S),
        gains_given=tuple("+".join(w for w, t in (("joint", j.servo), ("rig", top)) if "gains" in t)
                          for j in rig.joints),
        velocity_filter_hz=tuple(float(x) for x in filter_hz) if not np.all(np.isnan(filter_hz)) else (),
        controllers=choices,
        source=str(rig.path))
    if "pid" in names:
        _guard_rig_gains(rig, top, settings)
    return settings


def _hand(rig: RigSpec) -> HandModel | None:
    """``[hand]`` (:mod:`hal.hand`), its joint one of the rig's."""
    if "hand" not in rig.table:
        return None
    t = rig.table.table("hand")
    hand = HandModel.from_table(t)
    if hand.joint >= rig.n_joints:
        raise t.error("joint", f"a joint of the rig (0..{rig.n_joints - 1})", hand.joint)
    return hand


#: a controlled stop's deceleration unless the rig file says (deg/s²): 30°/s to rest in 75 ms, over 1.1°
DEFAULT_STOP_DECEL_DEG_S2 = 400.0
#: how long a controlled stop holds with the amplifiers on after dropping the brake lines, when the
#: rig file does not state the brakes' engage delay (s; the presets' brakes engage in 40 ms)
DEFAULT_BRAKE_ENGAGE_S = 0.06


def _stop_settings(rig: RigSpec, top: ConfigTable, nominal: list[JointNominal]) -> StopSettings:
    """``[servo] stop_deceleration_deg_s2`` (per joint in ``[joint.servo]``), ``stop_time_bound_s``,
    ``[servo.stop_categories]`` (cause = 0, 1 or 2: only as strict as the table or stricter), and
    the longest holding-brake engage delay (``[joint.holding_brake] engage_delay_s``), and each
    joint's holding load from its nominal gravity figures (NaN where it states none)."""
    base = top.get_float("stop_deceleration_deg_s2", DEFAULT_STOP_DECEL_DEG_S2, min=1.0)
    decel = tuple(float(np.radians(j.servo.get_float("stop_deceleration_deg_s2", base, min=1.0))) for j in rig.joints)
    # the brakes' engage delay as the plant's table states it where the joint has one; else the
    # controller's own figure (templates are the plant's business), longer than the presets' 40 ms
    default_engage = top.get_float("holding_brake_engage_s", DEFAULT_BRAKE_ENGAGE_S, min=0.0)
    engage = [j.table.table("holding_brake", {}).get_float("engage_delay_s", default_engage, min=0.0)
              if isinstance(j.table.raw("holding_brake", None), dict) else default_engage
              for j in rig.joints if "holding_brake" in j.wiring]
    bound = top.get_float("stop_time_bound_s", 1.5, min=rig.period_s)
    cats = top.table("stop_categories", {})
    stricter: dict[str, int] = {}
    for cause in cats.keys():
        if cause not in CATEGORIES:
            raise cats.error(cause, f"a stop cause ({', '.join(sorted(CATEGORIES))})", cats.raw(cause))
        value = cats.raw(cause)
        if isinstance(value, bool) or not isinstance(value, int) or value not in (0, 1, 2):
            raise cats.error(cause, "a stop category: 0, 1 or 2", value)
        if value > int(CATEGORIES[cause][0]):
            raise cats.error(cause, f"category {int(CATEGORIES[cause][0])} or stricter (a lower number): a rig "
                             "file may make a stop stricter, never looser", value)
        stricter[cause] = value
    load = HoldingLoad(
        gravity_nm=tuple(math.nan if n.gravity_torque_nm is None else n.gravity_torque_nm for n in nominal),
        phase_rad=tuple(0.0 if n.gravity_phase_rad is None else n.gravity_phase_rad for n in nominal))
    return StopSettings(decel_rad_s2=decel, brake_engage_s=max(engage, default=0.0), time_bound_s=bound,
                        stricter=stricter, load=load)


#: the watchdog's margin beyond a soft limit unless the rig file says (deg): the presets' soft
#: limits sit 2° inside the hard stops, and a category-1 stop from 20°/s at 400°/s² runs 0.5° on
DEFAULT_SOFT_LIMIT_MARGIN_DEG = 0.5


def soft_limits_rad(rig: RigSpec) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Each joint's soft limits ``(min_rad, max_rad)`` (−inf / +inf where it has none), parsed and
    checked as :func:`servo_settings` does, for a tool that needs only them (the pot calibration
    on a bench rig that states no controller)."""
    parsed = _soft_limits(rig, rig.table.table("servo", {}))
    return parsed["soft_min_rad"], parsed["soft_max_rad"]


def _soft_limits(rig: RigSpec, top: ConfigTable) -> dict[str, Any]:
    """``[joint.limits] min_deg / max_deg`` per joint (either may be absent: no limit that way), and
    ``[servo] soft_limit_margin_deg``. A limit must lie inside the joint's hard stops where the rig
    file's ``[joint.link]`` states them (``lower_stop_rad`` / ``upper_stop_rad``): a soft limit at
    or past a hard stop would never be reached before the joint hits the stop."""
    lo: list[float] = []
    hi: list[float] = []
    for j in rig.joints:
        lim = j.table.table("limits", {})
        lim.check_unknown({"min_deg", "max_deg"})
        mn = float(np.radians(lim.get_float("min_deg"))) if "min_deg" in lim else -np.inf
        mx = float(np.radians(lim.get_float("max_deg"))) if "max_deg" in lim else np.inf
        if not mn < mx:
            raise lim.error("max_deg", f"a limit above min_deg ({np.degrees(mn):g})", lim.raw("max_deg"))
        link = j.table.raw("link", None)
        if isinstance(link, dict):  # the hard stops, where this joint's table states them
            stops = j.table.table("link")
            for key, value, stop_key, inside in (("min_deg", mn, "lower_stop_rad", lambda v, s: v > s),
                                                 ("max_deg", mx, "upper_stop_rad", lambda v, s: v < s)):
                if key in lim and stop_key in stops:
                    stop = stops.get_float(stop_key)
                    if not inside(value, stop):
                        raise lim.error(key, f"a limit inside the hard stop {stop_key} = {stop:g} rad "
                                             f"({np.degrees(stop):.2f}°)", lim.raw(key))
        lo.append(mn)
        hi.append(mx)
    margin = top.get_float("soft_limit_margin_deg", DEFAULT_SOFT_LIMIT_MARGIN_DEG, min=0.0)
    points = top.get_int("collision_check_points", 20, min=2, max=10_000)
    return {"soft_min_rad": tuple(lo), "soft_max_rad": tuple(hi), "soft_limit_margin_rad": float(np.radians(margin)),
            "collision_points": points}


def _check_objects(cfg: ConfigTable, names: list[Any]) -> tuple[str, ...]:
    """The control objects' names: a non-empty list of known names, each once."""
    if not names or not all(isinstance(x, str) for x in names):
        raise cfg.error("objects", "a non-empty list of control object names", names)
    for i, name in enumerate(names):
        if CONTROL_OBJECTS.get(name) is None:
            raise cfg.error(f"objects[{i}]", "one of " + ", ".join(CONTROL_OBJECTS.names()), name)
        if name in names[:i]:
            raise cfg.error(f"objects[{i}]", "each object at most once", name)
    return tuple(names)


def _guard_rig_gains(rig: RigSpec, top: ConfigTable, settings: ServoSettings) -> None:
    """Every joint's gains as the rig file gives them, through the gain guard (values, then the
    sampled loop's stability with the joint's switch-off), as any other source of gains."""
    try:
        check_gain_set(settings.gains, settings.switch_off, {}, settings.period_s, settings.delay_periods,
                       filter_hz=settings.filter_hz)
    except GainRejected as e:
        spec = rig.joints[e.joint if e.joint is not None else 0]
        table = spec.servo if "gains" in spec.servo else top
        raise table.error("gains", f"gains the gain guard accepts (joint {spec.name}: {e.reason})",
                          table.raw("gains", {})) from None


def _watchdog(rig: RigSpec, nominal: list[Any]) -> WatchdogSettings:
    top = rig.table.table("servo", {}).table("watchdog", {})
    cross_checks = top.get_bool("cross_checks", True)
    rig_wide: list[tuple[str, float]] = []
    for key in WATCHDOG_RIG_INTS:
        if key in top:
            rig_wide.append((key, top.get_int(key, min=1)))
    for key in WATCHDOG_RIG_FLOATS:
        if key in top:
            rig_wide.append((key, top.get_float(key, min=0.0)))
    per_joint: dict[str, list[float]] = {field: [] for field, _ in WATCHDOG_JOINT_KEYS.values()}
    for j, nom in zip(rig.joints, nominal, strict=True):
        jt = j.servo.table("watchdog", {})
        for key, (field, scale) in WATCHDOG_JOINT_KEYS.items():
            table = jt if key in jt else top
            value = table.get_float(key, min=0.0) * scale if key in table else np.nan
            if field == "tach_dead_band_rad_s" and np.isnan(value) and nom.tach_dead_band_rad_s is not None:
                value = nom.tach_dead_band_rad_s  # the tach's datasheet dead band
            per_joint[field].append(float(value))
        jt.check_unknown(set(WATCHDOG_JOINT_KEYS))
    top.check_unknown({*WATCHDOG_JOINT_KEYS, "cross_checks", *WATCHDOG_RIG_INTS, *WATCHDOG_RIG_FLOATS})
    return WatchdogSettings(cross_checks, tuple(rig_wide), tuple((f, tuple(v)) for f, v in per_joint.items()))
