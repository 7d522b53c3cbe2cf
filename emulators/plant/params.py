"""Plant parameters: one dataclass per sub-model, a joint, the plant, and their TOML reader.

All values are SI (ohm, henry, N·m/A, V·s/rad, kg·m², N·m, rad, rad/s, V, A, s, Hz). Torques
named ``*_input_*`` or listed under ``[joint.friction]`` are referred to the Harmonic Drive
*input* (motor) shaft; link quantities are at the joint (output) side.

Rig-file layout (``emulators/presets/*.toml``)::

    [plant]
    rate_hz = 4000.0                   # integration rate (substeps per second)

    [plant.templates.wrist]            # optional: shared defaults, joint keys override
    motor = { resistance_ohm = 2.0 }

    [[joint]]
    name = "j1"
    amplifier = "linear"               # "linear" (transconductance) or "hbridge"
    template = "wrist"                 # optional
    [joint.motor]    ...               # MotorParams fields
    [joint.gear]     ...               # GearParams
    [joint.friction] ...               # FrictionParams
    [joint.link]     ...               # LinkParams
    [joint.linear_amp] ...             # LinearAmpParams
    [joint.hbridge]  ...               # HBridgeParams
    [joint.pot]      ...               # PotParams
    [joint.encoder]  ...               # EncoderParams
    [joint.tach]     ...               # TachParams
    [joint.holding_brake] ...          # HoldingBrakeParams (optional: joints without one have none)

    [rig.watchdog]                     # optional: the amplifiers' enable watchdog (charge pump)
    line = "pio0:PB7"                  # the PIO output the controller toggles (read by servo.rig)
    timeout_s = 0.05                   # enables drop this long after the line's last edge

Every key has a default (the dataclass default); unknown keys are errors naming file and key.

A ``[[joint]]`` table is shared with the rig file's other readers (the controller's tables sit
beside the plant subtables). The plant does not know them: whoever knows every reader of the file
passes their keys as ``foreign_keys`` (skipped unread, any other key the plant does not own is
an error); without ``foreign_keys`` the plant cannot tell another reader's table from a typo and
leaves the ``[[joint]]`` keys it does not own unchecked. Its own subtables are always checked.

Without ``[rig.watchdog]`` the amplifiers have no enable watchdog.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Collection
from dataclasses import dataclass, field, fields
from typing import Any

from hal.config import ConfigError, ConfigTable

AMP_LINEAR = "linear"
AMP_HBRIDGE = "hbridge"


@dataclass
class MotorParams:
    """Permanent-magnet DC motor. SI: ohm, H, N·m/A, V·s/rad, kg·m²."""

    resistance_ohm: float = 1.0
    inductance_h: float = 1.5e-3
    kt_nm_per_a: float = 0.028
    ke_v_s_per_rad: float = 0.028
    rotor_inertia_kg_m2: float = 1.0e-4
    peak_torque_nm: float = 0.847  #: informational (datasheet peak); the amplifier limits current


@dataclass
class GearParams:
    """Harmonic Drive: ratio, wave-generator inertia, optional flexspline compliance and
    kinematic error (output-side radians, at twice the wave-generator angle)."""

    ratio: float = 100.0
    wave_generator_inertia_kg_m2: float = 0.0
    compliant: bool = False  #: two-mass model (motor side / link side) with the flexspline spring
    stiffness_nm_per_rad: float = 2.0e4  #: flexspline torsional stiffness at the output
    damping_nm_s_per_rad: float = 20.0  #: structural damping of the flexspline at the output
    kinematic_error_rad: float = 0.0  #: amplitude of the output position error (≈ 1 arcmin typical)
    kinematic_error_phase_rad: float = 0.0


@dataclass
class FrictionParams:
    """Harmonic Drive friction referred to the input (motor) shaft.

    Slipping: ``|T_f| = ((T_c + (T_s − T_c)·exp(−(ω/ω_s)²)) + b·|ω|) · (1 + m·sin(2θ_m + φ))``;
    stuck: ``|T_f| ≤ T_s·(1 + m·sin(2θ_m + φ))`` (breakout). ``m < 1`` so friction only ever
    opposes motion (it modulates the magnitude; it is never a conservative torque).
    """

    breakout_nm: float = 0.0459  #: T_s, static (breakout) friction at the input shaft
    coulomb_nm: float = 0.0388  #: T_c, kinetic friction level approached past the Stribeck speed
    stribeck_velocity_rad_s: float = 0.5  #: ω_s at the motor shaft
    viscous_nm_s_per_rad: float = 0.0104  #: b at the motor shaft
    ripple_fraction: float = 0.2  #: m, 0 ≤ m < 1
    ripple_phase_rad: float = 0.0  #: φ


@dataclass
class LinkParams:
    """Link at the joint (output) side. Gravity torque ``T_g = G·cos(θ + φ_g)`` (0 for
    joints that do not lift); inelastic hard stops at the two limits."""

    inertia_kg_m2: float = 2.0
    gravity_torque_nm: float = 0.0
    gravity_phase_rad: float = 0.0
    lower_stop_rad: float = -2.8
    upper_stop_rad: float = 2.8
    initial_angle_rad: float = 0.0


@dataclass
class LinearAmpParams:
    """Linear transconductance amplifier (current source driven by a DAC voltage)."""

    gain_a_per_v: float = 3.0
    bandwidth_hz: float = 1000.0  #: first-order current-loop bandwidth
    current_limit_a: float = 30.0
    supply_v: float = 28.0  #: compliance: |R·i + L·di/dt + Ke·ω| ≤ supply
    monitor_v_per_a: float = 1.0 / 3.0  #: current monitor scale (V per A, = 1/gain by default)
    monitor_offset_v: float = 0.002
    monitor_noise_v: float = 0.001
    continuous_current_a: float = 10.0  #: I²t thermal model: latches when the filtered i² > this²
    thermal_time_constant_s: float = 20.0
    saturation_fault_s: float = 0.5  #: compliance saturation held this long latches a fault (0: off)


@dataclass
class HBridgeParams:
    """PWM H-bridge (sign-magnitude, synchronous) driven by the PIO PWM timer."""

    supply_v: float = 24.0
    pwm_hz: float = 20000.0
    dead_time_s: float = 1.0e-6  #: lost from every on-time: d_eff = max(d − t_dead·f_pwm, 0)
    current_limit_a: float = 5.0  #: cycle-by-cycle chopping limit while driving
    overcurrent_trip_a: float = 8.0  #: latched fault (e.g. braking at speed is not chopped)
    continuous_current_a: float = 3.0
    thermal_time_constant_s: float = 10.0
    monitor_v_per_a: float = 1.0
    monitor_offset_v: float = 0.003
    monitor_noise_v: float = 0.002
    switching_noise_v: float = 0.02  #: rms noise it couples into ADC inputs while switching


@dataclass
class PotParams:
    """Wire-wound joint potentiometer across a ±supply; output volts.

    ``v = v_low + (v_high − v_low)·(x + bow·4x(1−x) + periodic·sin(2π·cycles·x))`` with
    ``x = (θ − center)/span + ½`` clipped to [0, 1]; wiper noise is added per sample.
    """

    span_rad: float = math.radians(340.0)
    center_rad: float = 0.0
    v_low: float = -10.0
    v_high: float = 10.0
    bow_fraction: float = 0.003  #: smooth independent non-linearity, fraction of span
    periodic_fraction: float = 0.0001
    periodic_cycles: float = 3.0
    noise_v: float = 0.0015


@dataclass
class EncoderParams:
    """Motor-shaft incremental encoder (x4 decoded), index once per motor revolution."""

    lines_per_rev: int = 500
    index_phase_x4: int = 0  #: x4 count (mod 4·lines) at which the index pulse occurs
    decoder_sample_hz: float = 2.0e6  #: the decoder's input sampling rate (illegal transitions)


@dataclass
class TachParams:
    """DC tachometer generator on the joint (link) axis, with a brush-contact dead band.

    ``emf = gradient·ω_joint·(1 + ripple·sin(cycles·θ_joint))``; output
    ``sign(emf)·max(|emf| − brush_drop, 0)`` through a first-order filter, plus offset and
    noise at the sampling instant. ``brush_drop/gradient`` is the velocity dead band.
    """

    present: bool = True
    gradient_v_per_rad_s: float = 1.0
    brush_drop_v: float = 0.12
    ripple_fraction: float = 0.02  #: commutator ripple
    ripple_cycles_per_rev: float = 11.0
    filter_time_constant_s: float = 0.002
    offset_v: float = 0.0
    noise_v: float = 0.002


@dataclass(frozen=True)
class HoldingBrakeParams:
    """Spring-applied, power-released holding brake on the motor shaft (optional per joint).

    Its line energised releases it, low engages it (a dead controller, a cut power rail: the
    spring holds). The armature moves ``engage_delay_s`` after the line drops and
    ``release_delay_s`` after it rises; a line that changes back before the armature has moved
    cancels the change. Engaged, it holds up to ``holding_torque_nm`` (at the joint, i.e. N times
    what it holds on the motor shaft) and slips beyond it with kinetic friction equal to the
    holding torque; it adds to the Harmonic Drive's own friction. Released it adds nothing.
    """

    present: bool = False
    holding_torque_nm: float = 0.0  #: static and kinetic torque it holds at the joint (output) side
    engage_delay_s: float = 0.04  #: line low → brake holds
    release_delay_s: float = 0.06  #: line high → brake free


@dataclass
class JointParams:
    """One joint: motor, Harmonic Drive, friction, link, its amplifier and its sensors."""

    name: str = "joint"
    amplifier: str = AMP_LINEAR
    motor: MotorParams = field(default_factory=MotorParams)
    gear: GearParams = field(default_factory=GearParams)
    friction: FrictionParams = field(default_factory=FrictionParams)
    link: LinkParams = field(default_factory=LinkParams)
    linear_amp: LinearAmpParams = field(default_factory=LinearAmpParams)
    hbridge: HBridgeParams = field(default_factory=HBridgeParams)
    pot: PotParams = field(default_factory=PotParams)
    encoder: EncoderParams = field(default_factory=EncoderParams)
    tach: TachParams = field(default_factory=TachParams)
    holding_brake: HoldingBrakeParams = field(default_factory=HoldingBrakeParams)

    # ---- derived quantities -------------------------------------------------------------
    def inertia_at_motor(self) -> float:
        """Rigid-joint inertia referred to the motor shaft (kg·m²)."""
        n = self.gear.ratio
        return (
            self.motor.rotor_inertia_kg_m2
            + self.gear.wave_generator_inertia_kg_m2
            + self.link.inertia_kg_m2 / (n * n)
        )

    def inertia_at_joint(self) -> float:
        """Total joint inertia J at the output (kg·m²): rotor reflected + link."""
        return self.inertia_at_motor() * self.gear.ratio**2

    def breakout_at_output_nm(self) -> float:
        """Nominal output-shaft breakout torque N·T_s (N·m)."""
        return self.gear.ratio * self.friction.breakout_nm

    def validate(self, where: str = "") -> None:
        """Raise ``ValueError`` for physically meaningless values."""
        w = f"{where}joint {self.name!r}: "
        if self.amplifier not in (AMP_LINEAR, AMP_HBRIDGE):
            raise ValueError(w + f"amplifier must be '{AMP_LINEAR}' or '{AMP_HBRIDGE}', got {self.amplifier!r}")
        if not 0.0 <= self.friction.ripple_fraction < 1.0:
            raise ValueError(w + "friction.ripple_fraction must be in [0, 1) so friction never adds energy")
        if self.friction.coulomb_nm < 0 or self.friction.breakout_nm < 0 or self.friction.viscous_nm_s_per_rad < 0:
            raise ValueError(w + "friction levels must be >= 0")
        positive = {
            "motor.resistance_ohm": self.motor.resistance_ohm,
            "motor.inductance_h": self.motor.inductance_h,
            "motor.kt_nm_per_a": self.motor.kt_nm_per_a,
            "motor.rotor_inertia_kg_m2": self.motor.rotor_inertia_kg_m2,
            "gear.ratio": self.gear.ratio,
            "friction.stribeck_velocity_rad_s": self.friction.stribeck_velocity_rad_s,
            "link.inertia_kg_m2": self.link.inertia_kg_m2,
            "linear_amp.bandwidth_hz": self.linear_amp.bandwidth_hz,
            "pot.span_rad": self.pot.span_rad,
            "tach.gradient_v_per_rad_s": self.tach.gradient_v_per_rad_s,
        }
        for k, v in positive.items():
            if not v > 0:
                raise ValueError(w + f"{k} must be > 0, got {v}")
        if self.link.lower_stop_rad >= self.link.upper_stop_rad:
            raise ValueError(w + "link.lower_stop_rad must be below link.upper_stop_rad")
        if not self.link.lower_stop_rad <= self.link.initial_angle_rad <= self.link.upper_stop_rad:
            raise ValueError(w + "link.initial_angle_rad must lie between the hard stops")
        if self.encoder.lines_per_rev < 1:
            raise ValueError(w + "encoder.lines_per_rev must be >= 1")
        b = self.holding_brake
        if b.present and not b.holding_torque_nm > 0:
            raise ValueError(w + "holding_brake.holding_torque_nm must be > 0")
        if not (b.engage_delay_s >= 0 and b.release_delay_s >= 0):
            raise ValueError(w + "holding_brake delays must be >= 0")


@dataclass
class PlantParams:
    """The whole plant: the joints (in order), the integration rate and the amplifiers' enable
    watchdog timeout (``None``: no watchdog)."""

    joints: list[JointParams]
    rate_hz: float = 4000.0
    watchdog_timeout_s: float | None = None

    @property
    def names(self) -> list[str]:
        return [j.name for j in self.joints]

    def validate(self) -> None:
        if not self.joints:
            raise ValueError("a plant needs at least one joint")
        names = self.names
        if len(set(names)) != len(names):
            raise ValueError(f"joint names must be unique, got {names}")
        if not self.rate_hz > 0:
            raise ValueError("plant rate_hz must be > 0")
        if self.watchdog_timeout_s is not None and not self.watchdog_timeout_s > 0:
            raise ValueError("watchdog timeout_s must be > 0")
        for j in self.joints:
            j.validate()


_SUBTABLES: dict[str, type] = {
    "motor": MotorParams,
    "gear": GearParams,
    "friction": FrictionParams,
    "link": LinkParams,
    "linear_amp": LinearAmpParams,
    "hbridge": HBridgeParams,
    "pot": PotParams,
    "encoder": EncoderParams,
    "tach": TachParams,
    "holding_brake": HoldingBrakeParams,
}


def _read_dataclass(cls: type, tbl: ConfigTable) -> Any:
    """Build dataclass ``cls`` from a table, typed by the dataclass defaults."""
    obj = cls()
    values: dict[str, Any] = {}
    for f in fields(cls):
        if f.name not in tbl:
            continue
        default = getattr(obj, f.name)
        if isinstance(default, bool):
            v: Any = tbl.get_bool(f.name)
        elif isinstance(default, int):
            v = tbl.get_int(f.name)
        elif isinstance(default, float):
            v = tbl.get_float(f.name)
        else:
            v = tbl.get_str(f.name)
        values[f.name] = v
    tbl.check_unknown({f.name for f in fields(cls)})
    return cls(**values)  # frozen tables too


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def joint_from_config(tbl: ConfigTable, templates: dict[str, dict[str, Any]] | None = None,
                      foreign_keys: Collection[str] | None = None) -> JointParams:
    """Read one ``[[joint]]`` table (after applying its ``template``); ``foreign_keys``: the keys
    other readers of the rig file own (see the module docstring)."""
    data = tbl.data
    if "template" in data:
        tname = tbl.get_str("template")
        if not templates or tname not in templates:
            raise tbl.error("template", "the name of a [plant.templates.*] table", tname)
        data = _merge(templates[tname], {k: v for k, v in data.items() if k != "template"})
        tbl = ConfigTable(data, tbl.source, tbl.prefix)
    j = JointParams(name=tbl.get_str("name"),
                    amplifier=tbl.get_str("amplifier", AMP_LINEAR, choices=(AMP_LINEAR, AMP_HBRIDGE)))
    for key, cls in _SUBTABLES.items():
        if key in tbl:
            setattr(j, key, _read_dataclass(cls, tbl.table(key)))
    if foreign_keys is not None:
        tbl.check_unknown({"name", "amplifier", "template", *_SUBTABLES, *foreign_keys})
    try:
        j.validate()
    except ValueError as e:
        raise ConfigError(tbl.source, tbl.prefix, "physically meaningful joint parameters", str(e)) from None
    return j


def plant_params_from_config(cfg: ConfigTable, *, foreign_keys: Collection[str] | None = None) -> PlantParams:
    """Read ``[plant]`` and ``[[joint]]`` from a rig file's root table; ``foreign_keys``: the
    ``[[joint]]`` keys other readers of the rig file own (see the module docstring)."""
    plant = cfg.table("plant", {})
    rate = plant.get_float("rate_hz", 4000.0, min=100.0, max=1.0e6)
    templates: dict[str, dict[str, Any]] = {}
    if "templates" in plant:
        ttbl = plant.table("templates")
        for name in list(ttbl.keys()):
            templates[name] = ttbl.table(name).data
    plant.check_unknown({"rate_hz", "templates"})
    joints = [joint_from_config(t, templates, foreign_keys) for t in cfg.tables("joint")]
    if not joints:
        raise cfg.error("joint", "at least one [[joint]] table")
    params = PlantParams(joints=joints, rate_hz=rate, watchdog_timeout_s=watchdog_timeout_from_config(cfg))
    try:
        params.validate()
    except ValueError as e:
        raise ConfigError(cfg.source, "joint", "a valid joint set", str(e)) from None
    return params


#: the keys of ``[rig.watchdog]``: the line is the controller's wiring, the timeout the amplifiers'
WATCHDOG_KEYS = ("line", "timeout_s")


def watchdog_timeout_from_config(cfg: ConfigTable) -> float | None:
    """``[rig.watchdog] timeout_s`` of a rig file's root table (s), ``None`` without the table."""
    rig = cfg.table("rig", {})
    if "watchdog" not in rig:
        return None
    wd = rig.table("watchdog")
    wd.check_unknown(set(WATCHDOG_KEYS))
    return wd.get_float("timeout_s", min=1e-3, max=10.0)
