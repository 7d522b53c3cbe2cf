"""Build a servo loop for an emulated rig: controller from the rig's servo tables, the motion,
the watchdog and the recorder.

Rig-level ``[servo]`` gives defaults; each ``[joint.servo]`` may override them::

    [servo]
    objects = ["pid", "torque_limit"]          # control objects, in order
    gains = { kp = 100.0, kpi = 5000.0, kv = 50.0, kvi = 1000.0 }
    switch_off = { enabled = true, inner_band_deg = 0.3, outer_band_deg = 1.5, kp_boost = 2.0 }
    max_velocity_deg_s = 30.0                  # trajectory planning limit
    following_error_limit_deg = 10.0           # watchdog

    [joint.servo]
    position = "pot"                           # or "encoder"
    velocity = "tach"                          # or "encoder"
    gains = { kp = 120.0 }                     # per-joint overrides
    torque_limit_nm = 84.7                     # default: nominal current limit · Kt · N

The controller's plant figures (normalizing chain J, N, Kt, amplifier gain; the default torque
limit) are the rig file's ``[joint.servo.nominal]`` values (:mod:`servo.nominal`), never the
emulated plant's.

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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.config import ConfigTable
from servo.control.gains import DEFAULT_GAINS, GAIN_NAMES
from servo.control.linear import delay_periods
from servo.control.objects import Controller, build_controller
from servo.gain_guard import check_gain_change, check_values
from servo.loop import Recorder, ServoLoop, WatchdogConfig
from servo.motion import Motion, default_demo_motion
from servo.nominal import nominal_chain, rig_nominal
from servo.rig import RigSpec
from servo.trajectory.base import JointLimits
from servo.trajectory.sequencer import PlanContext, Sequencer
from vmehil.system import EmulatedRig

#: the smallest planning speed limit a rig file may set (deg/s; 0 would plan endless moves)
MIN_VELOCITY_DEG_S = 1e-3


@dataclass
class ServoSettings:
    """Per-joint servo settings resolved from the rig (SI units)."""

    objects: list[str]
    gains: dict[str, list[float]]
    switch_off: dict[str, list[Any]]
    torque_limit_nm: list[float]
    max_velocity_rad_s: list[float]
    following_error_rad: list[float]


def servo_settings(rig: RigSpec) -> ServoSettings:
    """The rig's servo settings, per joint (``[servo]`` defaults, ``[joint.servo]`` overrides)."""
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
    for j, nominal in zip(rig.joints, rig_nominal(rig), strict=True):
        jg = j.servo.table("gains", {})
        for k in GAIN_NAMES:
            default = base_gains.get_float(k, DEFAULT_GAINS[k], min=0.0)
            gains[k].append(jg.get_float(k, default, min=0.0))
        jso = j.servo.table("switch_off", {})
        for k in so_keys:
            v = jso.raw(k) if k in jso else base_so.raw(k, None)  # None: the law's default
            so.setdefault(k, []).append(v)
        tl.append(j.servo.get_float("torque_limit_nm", nominal.torque_limit_nm, min=0.0))
        # a planning limit of 0 would make every move infinitely long: refused here, naming the key
        vmax.append(np.radians(j.servo.get_float("max_velocity_deg_s",
                                                 top.get_float("max_velocity_deg_s", 30.0, min=MIN_VELOCITY_DEG_S),
                                                 min=MIN_VELOCITY_DEG_S)))
        ferr.append(np.radians(j.servo.get_float("following_error_limit_deg",
                                             top.get_float("following_error_limit_deg", 10.0, min=0.0))))
    if not isinstance(objects, list):
        raise top.error("objects", "a list of control object names", objects)
    return ServoSettings(list(objects), gains, so, tl, vmax, ferr)


def build_controller_for(rig: RigSpec, settings: ServoSettings) -> Controller:
    """The rig's controller for ``settings``, normalized with the rig's nominal values."""
    chain = nominal_chain(rig_nominal(rig))
    table: dict[str, Any] = {"objects": settings.objects}
    pid: dict[str, Any] = dict(settings.gains)
    if settings.switch_off:
        pid["switch_off"] = _collapse(settings.switch_off)
    table["pid"] = pid
    if "torque_limit" in settings.objects:
        table["torque_limit"] = {"tau_max_nm": settings.torque_limit_nm}
    return build_controller(ConfigTable(table, f"{rig.path} (servo settings)"), chain, rig.period_s)


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


def watchdog_config(system: EmulatedRig, settings: ServoSettings, *, enabled: bool = True) -> WatchdogConfig:
    """The watchdog's limits from the rig file (see the module docstring); NaN = derived default."""
    rig = system.rig
    top = rig.table.table("servo", {}).table("watchdog", {})
    wd = WatchdogConfig(following_error_rad=np.asarray(settings.following_error_rad), enabled=enabled,
                        cross_checks=top.get_bool("cross_checks", True))
    for key in WATCHDOG_RIG_INTS:
        setattr(wd, key, top.get_int(key, getattr(wd, key), min=1))
    for key in WATCHDOG_RIG_FLOATS:
        setattr(wd, key, top.get_float(key, getattr(wd, key), min=0.0))
    per_joint: dict[str, list[float]] = {field: [] for field, _ in WATCHDOG_JOINT_KEYS.values()}
    for j, nominal in zip(rig.joints, rig_nominal(rig), strict=True):
        jt = j.servo.table("watchdog", {})
        for key, (field, scale) in WATCHDOG_JOINT_KEYS.items():
            table = jt if key in jt else top
            value = table.get_float(key, min=0.0) * scale if key in table else np.nan
            if field == "tach_dead_band_rad_s" and np.isnan(value) and nominal.tach_dead_band_rad_s is not None:
                value = nominal.tach_dead_band_rad_s  # the tach's datasheet dead band
            per_joint[field].append(value)
        jt.check_unknown(set(WATCHDOG_JOINT_KEYS))
    top.check_unknown({*WATCHDOG_JOINT_KEYS, "cross_checks", *WATCHDOG_RIG_INTS, *WATCHDOG_RIG_FLOATS})
    # a free-running plant node answers late; a real rig or an in-process plant does not
    wd.command_lag_ticks = int(getattr(system, "answer_lag_ticks", 0))
    for field, values in per_joint.items():
        setattr(wd, field, np.asarray(values, float))
    return wd


def build_loop(system: EmulatedRig, *, motion: Motion | None = None, gains: dict[str, float] | None = None,
               switch_off: bool | None = None, n_ticks: int = 0, watchdog: bool = True,
               sequencer: Sequencer | None = None) -> ServoLoop:
    """A ready-to-start :class:`ServoLoop` for ``system`` (all settings from the rig file, with
    optional gain overrides applied to every joint and the switch-off forced on or off).

    Gain overrides go through :func:`servo.gain_guard.check_gain_change` first, as a live change
    would (the rig's period and computation delay, the switch-off as configured): a set the guard
    refuses raises :class:`~servo.gain_guard.GainRejected` and no loop is built.

    ``sequencer``: the motion already planned (a unit controller's segments of the global plan,
    :class:`servo.units.UnitSegments`); the joints are then not read here."""
    settings = servo_settings(system.rig)
    rig = system.rig
    n = rig.n_joints
    clean = check_values(gains or {})
    for k, v in clean.items():
        settings.gains[k] = [v] * n
    if switch_off is not None:
        settings.switch_off["enabled"] = [bool(switch_off)] * n
    controller = build_controller_for(system.rig, settings)
    if clean:
        if controller.law is None:
            raise ValueError(f"gain overrides {gains}: the rig's controller has no pid object to take them")
        check_gain_change(controller.law, None, clean, rig.period_s,
                          delay_periods(rig.computation_delay_s, rig.period_s))
    limits = JointLimits.make(n, settings.max_velocity_rad_s)
    if sequencer is None:
        motion = motion or default_demo_motion(n)
        sequencer = Sequencer(list(motion.moves), system.io.read().theta, PlanContext(limits))
    wd = watchdog_config(system, settings, enabled=watchdog)
    recorder = Recorder(n_ticks, n) if n_ticks else None
    loop = ServoLoop(system.io, controller, sequencer, wd, recorder=recorder, names=[j.name for j in system.rig.joints],
                     plan_context=PlanContext(limits))
    # an emulated rig's free-running plant: its answers may skip or repeat plant steps
    loop.sample_clock = getattr(system, "sample_clock", None)
    return loop


def plan_context_of(loop: ServoLoop) -> PlanContext:
    """The limits ``loop`` plans new moves with (:func:`build_loop` always sets them)."""
    if loop.plan_context is None:
        raise RuntimeError("the servo loop has no plan context (it was not built by vmehil.session.build_loop)")
    return loop.plan_context
