"""The loop and nonlinearity parameters of one joint, taken from the real rig file.

Everything comes from the same sources the emulated rig and the servo use, so the analysis and
the full-stack simulation describe the same joint:

* servo rate and computation delay: :func:`servo.rig.load_rig` (``[rig] servo_rate_hz``,
  ``computation_delay_s``);
* gains, switch-off settings and torque limit: :func:`servo.settings.servo_settings` (``[servo]``
  defaults + ``[joint.servo]`` overrides); the switch-off position gain is what the control law
  computes, :meth:`servo.control.law.PidLaw.kp_off` of the controller built from those settings;
* plant: :func:`emulators.plant.plant_params_from_config` (the plant subtables of ``[[joint]]``).

Derived figures (SI, at the joint/output side, N = gear ratio):

* inertia J = :meth:`~emulators.plant.JointParams.inertia_at_joint` (link + rotor·N²);
* friction: Coulomb level at the output N·T_c (``friction.coulomb_nm``, the *kinetic* level: a
  limit cycle keeps the joint sliding through most of each period, so its describing function
  is the sliding friction's); viscous b·N² (``friction.viscous_nm_s_per_rad``), put in the
  linear plant as damping b·N²/J; breakout N·T_s·(1 + ripple) (the largest local breakout, used
  for the switch-off static-error bound: a stopped joint stays stuck while the commanded torque
  is below it);
* tach dead band = ``tach.brush_drop_v / tach.gradient_v_per_rad_s`` (rad/s at the joint), tach
  ripple filter ``tach.filter_time_constant_s`` as a first-order velocity filter;
* position quantum: pot source — one 12-bit ADC LSB (``hal.adc_dac.conversions``, bipolar ±10 V)
  over the pot gradient (V/rad from ``pot.span_rad`` and ``v_low``/``v_high``); encoder source —
  one x4 count, 2π/(4·lines·N);
* velocity source ``[joint.servo] velocity``; amplifier bandwidth ``[joint.linear_amp]
  bandwidth_hz`` (H-bridge joints: no current-loop lag modelled);
* acceleration limit = the session's torque limit (``torque_limit_nm`` or the nominal current
  limit · Kt · N of ``[joint.servo.nominal]``) / J.

The controller normalizes with the rig's nominal values (:mod:`servo.nominal`), the analysis
describes the plant. Where they differ (a study that perturbs the plant) the normalized plant is
r/s² instead of 1/s²; the linear model keeps 1/s², and a note gives r.

A figure whose key is absent from the rig file takes the plant model's default (the JPL paper's
joint 1) — exactly what the emulator then simulates — and is listed in :attr:`JointParams.notes`.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from emulators.plant import plant_params_from_config
from emulators.presets import resolve_rig
from hal.adc_dac.conversions import AdcRange, adc_lsb
from servo.control.errors import GainError
from servo.control.gains import GAIN_NAMES, Gains, parse_gains
from servo.control.linear import delay_periods
from servo.gain_guard import GainVerdict, check_values, judge
from servo.rig import RigSpec, load_rig
from servo.settings import ServoSettings, servo_settings
from vmehil.analysis.describing import DeadZone, Nonlinearity, Quantizer, Relay, Saturation
from vmehil.analysis.loop_model import LoopConfig, VelocitySource
from vmehil.errors import CliError


@dataclass
class JointParams:
    """Everything ``vmehil tune`` needs about one joint (SI units, output side)."""

    rig: str
    rig_path: str
    joint: int  #: 1-based
    name: str
    cfg: LoopConfig
    gains_source: str
    tach_deadband_rad_s: float | None
    coulomb_nm: float  #: N·T_c, kinetic (sliding) friction at the output
    breakout_nm: float  #: N·T_s·(1 + ripple), the largest local breakout at the output
    viscous_nm_s_per_rad: float  #: b·N² at the output
    inertia_kg_m2: float
    position_quantum_rad: float
    position_source: str
    torque_limit_nm: float
    accel_limit_rad_s2: float
    switch_off_kp: float
    switch_off_enabled: bool
    gain_overrides: dict[str, float] = field(default_factory=dict)  #: applied to this joint only
    notes: list[str] = field(default_factory=list)
    spec: RigSpec | None = None  #: the parsed rig (a sweep task's, with its plant values)
    servo: ServoSettings | None = None  #: the rig's servo settings, as parsed (without the overrides)

    def switch_off_cfg(self) -> LoopConfig:
        """The loop while the integrators are switched off: no integral action, Kp raised."""
        g = self.cfg.gains
        # a velocity filter in the KvI channel keeps running (it is no integrator)
        kvi = 0.0 if self.cfg.kvi_filter_hz is None else g.kvi
        return self.cfg.replace(gains=Gains(kp=self.switch_off_kp, kpi=0.0, kv=g.kv, kvi=kvi))

    def verdict(self, switch_off: bool | None = None) -> GainVerdict:
        """:func:`servo.gain_guard.judge` on this joint's gains, at its period and computation delay:
        the servo's own check. ``switch_off``: whether the switched-off loop (Kp_eff =
        :attr:`switch_off_kp`) is judged too; None = as the rig says."""
        on = self.switch_off_enabled if switch_off is None else switch_off
        c = self.cfg
        return judge(c.gains, c.sample_period_s, c.delay_fraction, kp_off=self.switch_off_kp if on else None,
                     filter_hz=c.kvi_filter_hz)

    def nonlinearities(self) -> list[Nonlinearity]:
        """The joint's nonlinearities for the describing-function analysis."""
        out: list[Nonlinearity] = []
        if self.cfg.velocity_source == "tach" and self.tach_deadband_rad_s:
            out.append(DeadZone(self.tach_deadband_rad_s, location="velocity_sensor", name="tach dead band"))
        if self.coulomb_nm > 0:
            out.append(Relay(self.coulomb_nm / self.inertia_kg_m2, location="friction", name="Coulomb friction"))
        if self.position_quantum_rad > 0:
            out.append(Quantizer(self.position_quantum_rad, location="position_sensor", name="position quantization"))
        if math.isfinite(self.accel_limit_rad_s2):
            out.append(Saturation(self.accel_limit_rad_s2, location="actuator", name="torque saturation"))
        return out

    def static_error_bound_rad(self, kp: float | None = None) -> float:
        """T_F/(J·Kp): the largest error a stuck joint can hold with the integral terms frozen at zero
        (T_F = the largest local breakout at the output; Kp defaults to the switch-off gain)."""
        return self.breakout_nm / (self.inertia_kg_m2 * (kp if kp is not None else self.switch_off_kp))

    def describe(self) -> dict[str, Any]:
        c = self.cfg
        return {
            "rig": self.rig, "joint": self.joint, "joint_name": self.name,
            "gains": c.gains.as_dict(), "gains_source": self.gains_source,
            "sample_period_s": c.sample_period_s, "computation_delay_s": c.delay_s,
            "velocity_source": c.velocity_source, "position_source": self.position_source,
            "amplifier_bandwidth_hz": c.amplifier_bandwidth_hz, "velocity_filter_hz": c.velocity_filter_hz,
            "kvi_filter_hz": c.kvi_filter_hz,
            "tach_deadband_rad_s": self.tach_deadband_rad_s, "coulomb_friction_nm": self.coulomb_nm,
            "breakout_friction_nm": self.breakout_nm, "viscous_friction_nm_s_per_rad": self.viscous_nm_s_per_rad,
            "viscous_damping_per_s": c.viscous_damping,
            "inertia_kg_m2": self.inertia_kg_m2, "position_quantum_rad": self.position_quantum_rad,
            "torque_limit_nm": self.torque_limit_nm, "accel_limit_rad_s2": self.accel_limit_rad_s2,
            "switch_off_kp": self.switch_off_kp, "switch_off_enabled": self.switch_off_enabled,
            "notes": list(self.notes),
        }


def _joint_data(spec: RigSpec, index: int) -> dict[str, Any]:
    """The joint's table after its plant template (if any) is applied — to see which keys exist."""
    data = spec.joints[index].table.data
    if "template" in data:
        templates = spec.table.data.get("plant", {}).get("templates", {})
        base = copy.deepcopy(templates.get(data["template"], {}))
        for k, v in data.items():
            if isinstance(v, dict) and isinstance(base.get(k), dict):
                base[k] = {**base[k], **v}
            elif k != "template":
                base[k] = v
        return base
    return data


def load_joint(rig: str | Path | RigSpec | None, joint: int = 1, gains: str | dict[str, float] | None = None,
               switch_off_kp: float | None = None, *, servo: ServoSettings | None = None,
               velocity_filter_hz: float | None = None) -> JointParams:
    """Read joint ``joint`` (1-based) of ``rig`` (preset name or path; None = jpl-arm).

    ``gains``: ``"kp=..,kv=.."`` text (:func:`servo.control.gains.parse_gains`) or a mapping of
    overrides for this joint, refused by :func:`servo.gain_guard.check_values` if no gain may have
    those values (stability is not judged here: :meth:`JointParams.verdict`); ``switch_off_kp``
    overrides the switch-off gain (default: the control law's ``kp_off`` for these gains).
    ``velocity_filter_hz``: the velocity filter alternative to KvI on this joint (0: off, the
    integral of ė; None: as the rig says), in the model and in the settings the full-stack
    simulations run with (:attr:`JointParams.servo`).
    Raises :class:`hal.config.ConfigError` (a ValueError) for a malformed rig file,
    :class:`servo.control.errors.GainError` for bad gains and ValueError for a bad joint number.
    """
    from servo.assembly import build_controller
    from vmehil.rig_setup.system import NON_PLANT_JOINT_KEYS

    if isinstance(joint, bool) or not isinstance(joint, int) or joint < 1:
        raise CliError(f"joint number {joint!r} must be 1 or more (joints are numbered from 1)")
    spec = rig if isinstance(rig, RigSpec) else load_rig(resolve_rig(rig))
    path = spec.path
    if joint > spec.n_joints:
        raise CliError(f"rig {spec.name} has {spec.n_joints} joints; --joint must be 1..{spec.n_joints}, not {joint}")
    plant = plant_params_from_config(spec.table, foreign_keys=NON_PLANT_JOINT_KEYS).joints
    j = joint - 1
    p = plant[j]
    js = spec.joints[j]
    data = _joint_data(spec, j)
    notes: list[str] = []

    def absent(sub: str, key: str) -> bool:
        return not (isinstance(data.get(sub), dict) and key in data[sub])

    def note_default(sub: str, key: str, value: Any, unit: str) -> None:
        if absent(sub, key):
            notes.append(f"[joint.{sub}] {key} not in the rig: the plant model's default {value:g} {unit}")

    rt = spec.table.data.get("rig", {})
    if "servo_rate_hz" not in rt:
        notes.append(f"[rig] servo_rate_hz not in the rig: {spec.servo_rate_hz:g} Hz (the paper's rate)")
    if "computation_delay_s" not in rt:
        notes.append(f"[rig] computation_delay_s not in the rig: {spec.computation_delay_s * 1e3:g} ms (rig default)")
    T = spec.period_s

    # ---- gains and switch-off, as the session resolves them
    rig_settings = servo if servo is not None else servo_settings(spec)
    if velocity_filter_hz is not None:  # the one definition (servo.control.velocity_filter), model and runs alike
        if not (math.isfinite(velocity_filter_hz) and velocity_filter_hz >= 0):
            raise CliError(f"velocity filter {velocity_filter_hz!r} Hz: a cutoff in Hz, or 0 for none")
        hz = rig_settings.filter_hz.copy()
        hz[joint - 1] = velocity_filter_hz if velocity_filter_hz > 0 else math.nan
        rig_settings = dataclasses.replace(
            rig_settings, velocity_filter_hz=tuple(float(x) for x in hz) if not np.all(np.isnan(hz)) else ())
    settings = rig_settings
    base = settings.gains.joint(j).as_dict()
    given = rig_settings.gains_given[j]
    if given.startswith("joint"):
        gsrc = "rig [joint.servo]" + (" + [servo]" if given == "joint+rig" else "")
    elif given == "rig":
        gsrc = "rig [servo]"
    else:
        gsrc = "session defaults (the paper's)"
        notes.append("gains: neither [servo] nor [joint.servo] gives gains; the session default is the "
                     "paper's Kp=100, Kpi=5000, Kv=50, KvI=1000")
    overrides = check_values(parse_gains(gains) if isinstance(gains, str | type(None)) else dict(gains))
    if overrides:
        gsrc += " + --gains overrides"
    g = Gains.from_mapping({**base, **overrides})
    # the point's gains on this joint; judged (classified) by JointParams.verdict, not refused here
    per_joint = {k: [*getattr(settings.gains, k)] for k in GAIN_NAMES}
    for k in GAIN_NAMES:
        per_joint[k][j] = getattr(g, k)
    settings = dataclasses.replace(settings, gains=settings.gains.replace(**per_joint))
    so_enabled = bool(settings.switch_off.enabled[j])
    controller = build_controller(settings)
    law = controller.law
    if switch_off_kp is None:
        if law is not None:
            switch_off_kp = float(law.kp_off()[j])
        else:
            switch_off_kp = g.kp + g.kvi
            notes.append(f"switch-off gain: the rig's controller has no pid object; assuming Kp + KvI = "
                         f"{switch_off_kp:g}")
    elif not (math.isfinite(switch_off_kp) and switch_off_kp > 0):
        raise GainError("switch_off_kp", switch_off_kp, "a positive number of 1/s² (--switch-off-kp)")

    f_hz = float(settings.filter_hz[j])
    kvi_filter = None if math.isnan(f_hz) else f_hz

    # ---- plant
    n_gear = p.gear.ratio
    inertia = p.inertia_at_joint()
    for sub, key, unit in (("link", "inertia_kg_m2", "kg·m²"), ("motor", "rotor_inertia_kg_m2", "kg·m²"),
                           ("gear", "ratio", ":1")):
        note_default(sub, key, getattr(getattr(p, sub), key), unit)
    fr = p.friction
    for key in ("coulomb_nm", "breakout_nm", "viscous_nm_s_per_rad"):
        note_default("friction", key, getattr(fr, key), "(input side)")
    chain = controller.chain
    r = float(chain.j_eff[j] / inertia * (n_gear * p.motor.kt_nm_per_a) / (chain.ratio[j] * chain.kt[j]))
    if p.amplifier == "linear":
        r *= p.linear_amp.gain_a_per_v / float(chain.amp_gain[j])
    if not math.isclose(r, 1.0, rel_tol=1e-9):
        notes.append(f"the controller's nominal J, N, Kt, amplifier gain ([joint.servo.nominal]) differ from the "
                     f"plant's: the normalized plant is {r:.4g}/s², the linear analysis assumes 1/s²")
    coulomb = n_gear * fr.coulomb_nm
    breakout = n_gear * fr.breakout_nm * (1.0 + fr.ripple_fraction)
    viscous = n_gear**2 * fr.viscous_nm_s_per_rad

    # get_str has checked the choices: narrow the str to the literal type LoopConfig takes
    velocity = cast(VelocitySource, settings.velocity_source[j])
    position = settings.position_source[j]
    if not settings.velocity_source_given[j]:
        notes.append("[joint.servo] velocity not in the rig: the servo's default, the tachometer")
    deadband = None
    vel_filter = None
    if velocity == "tach":
        if not p.tach.present:
            raise CliError(f"rig {spec.name} joint {js.name}: the servo uses the tach but "
                             "[joint.tach] present = false")
        for key in ("brush_drop_v", "gradient_v_per_rad_s"):
            note_default("tach", key, getattr(p.tach, key), "V" if key == "brush_drop_v" else "V/(rad/s)")
        deadband = p.tach.brush_drop_v / p.tach.gradient_v_per_rad_s
        if p.tach.filter_time_constant_s > 0:
            vel_filter = 1.0 / (2 * math.pi * p.tach.filter_time_constant_s)

    if position == "pot":
        pot_v_per_rad = (p.pot.v_high - p.pot.v_low) / p.pot.span_rad
        quantum = adc_lsb(AdcRange.BIPOLAR_10V, 1) / abs(pot_v_per_rad)
        note_default("pot", "span_rad", p.pot.span_rad, "rad")
    else:
        quantum = 2 * math.pi / (4 * p.encoder.lines_per_rev * n_gear)

    amp_bw = None
    if p.amplifier == "linear":
        amp_bw = p.linear_amp.bandwidth_hz
        note_default("linear_amp", "bandwidth_hz", amp_bw, "Hz")
    else:
        notes.append("amplifier: H-bridge (PWM voltage drive); no current-loop lag is modelled")

    torque_limit = settings.torque_limit_nm[j] if "torque_limit" in settings.objects else math.inf
    if not math.isfinite(torque_limit):
        limit_a = p.linear_amp.current_limit_a if p.amplifier == "linear" else p.hbridge.current_limit_a
        torque_limit = limit_a * p.motor.kt_nm_per_a * n_gear  # the amplifier's own current limit
    accel_limit = torque_limit / inertia if torque_limit > 0 else math.inf
    if p.link.gravity_torque_nm:
        notes.append(f"gravity ({p.link.gravity_torque_nm:g} N·m) is a steady load the integrators take up; "
                     "the linear analysis leaves it out")

    cfg = LoopConfig(gains=g, sample_period_s=T, delay_fraction=delay_periods(spec.computation_delay_s, T),
                     velocity_source=velocity, amplifier_bandwidth_hz=amp_bw, velocity_filter_hz=vel_filter,
                     viscous_damping=viscous / inertia, kvi_filter_hz=kvi_filter)
    return JointParams(rig=spec.name, rig_path=str(path), joint=joint, name=js.name, cfg=cfg, gains_source=gsrc,
                       tach_deadband_rad_s=deadband, coulomb_nm=coulomb, breakout_nm=breakout,
                       viscous_nm_s_per_rad=viscous, inertia_kg_m2=inertia, position_quantum_rad=quantum,
                       position_source=position, torque_limit_nm=torque_limit, accel_limit_rad_s2=accel_limit,
                       switch_off_kp=float(switch_off_kp), switch_off_enabled=so_enabled,
                       gain_overrides=overrides, notes=notes, spec=spec, servo=rig_settings)


def with_gains(jp: JointParams, gains: Gains[float]) -> JointParams:
    """The same joint re-read with another gain set (so the switch-off gain is again what the
    control law computes for it)."""
    return load_joint(jp.spec if jp.spec is not None else jp.rig_path, jp.joint, gains=gains.as_dict(),
                      servo=jp.servo)
