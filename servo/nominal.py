"""The controller's own plant figures: the datasheet/nominal values of the rig file's servo side.

A real controller knows its joints only from datasheets and the rig file, never from the plant
itself. Each joint states them in ``[joint.servo.nominal]`` (SI units)::

    [joint.servo.nominal]
    ratio = 100.0                    # gear ratio N (motor turns per joint turn)
    kt_nm_per_a = 0.028              # motor torque constant
    current_limit_a = 30.0           # amplifier current limit
    inertia_kg_m2 = 3.0              # total inertia at the joint (link + rotor·N²)
    amp_gain_a_per_v = 3.0           # linear amplifiers: transconductance
    pot_v_per_rad = 3.3704           # wired pot: gradient (V/rad of joint angle)
    pot_zero_v = 0.0                 #            volts at joint angle 0
    tach_v_per_rad_s = 1.0           # wired tach: gradient (V per rad/s of joint velocity)
    tach_dead_band_rad_s = 0.12      #   optional: below this speed it reads 0 (brush drop / gradient)
    encoder_counts_per_rev = 200000  # wired encoder: x4 counts per JOINT revolution (4·lines·N)
    monitor_v_per_a = 0.3333         # wired current monitor
    supply_v = 24.0                  # H-bridges: supply, motor resistance and back-emf constant
    resistance_ohm = 3.0             #   (the voltage command V = R·i + Ke·ω_motor)
    ke_v_s_per_rad = 0.01
    pwm_period_s = 5.0e-5            #   PWM period programmed into the PIO timer
    gravity_torque_nm = 9.0          # optional: the joint's gravity load m·g·l (N·m at the joint)
    gravity_phase_rad = 0.0          #   optional: the load is gravity_torque_nm · cos(θ + phase)

Which keys a joint must give follows from the joint itself: ``ratio``, ``kt_nm_per_a``,
``current_limit_a`` and ``inertia_kg_m2`` always; ``amp_gain_a_per_v`` for a linear amplifier;
``supply_v``, ``resistance_ohm``, ``ke_v_s_per_rad`` and ``pwm_period_s`` for an H-bridge; the
sensor keys for each sensor in ``[joint.wiring]``. ``gravity_torque_nm`` and ``gravity_phase_rad``
are optional (the link's mass properties, as a datasheet or CAD gives them): a joint that states
them lets a re-enable take up its load at the angle its holding brake kept it at
(:class:`servo.stops.HoldingLoad`). A missing required key is an error naming the key:
there is no fallback, because the only other source would be the plant, which the controller
must not see. Keys a joint does not need may be given and are carried along unused.

From these come the drivers' :class:`servo.io.SensorScaling` (before calibration), the
normalizing chain's J, N, Kt and amplifier gain, and the default torque limit
``current_limit_a · Kt · N``. Calibration (``servo.io.JointIO.apply_calibration``) may then
replace the encoder counts and the amplifier gain with measured values.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from hal.config import ConfigTable
from servo.control.normalize import NormalizingChain, normalizing_chain
from servo.io import SensorScaling
from servo.rig import JointSpec, RigSpec

#: Keys every joint gives, and the keys its amplifier type and its wired sensors add.
ALWAYS_KEYS = ("ratio", "kt_nm_per_a", "current_limit_a", "inertia_kg_m2")
AMPLIFIER_KEYS = {
    "linear": ("amp_gain_a_per_v",),
    "hbridge": ("supply_v", "resistance_ohm", "ke_v_s_per_rad", "pwm_period_s"),
}
SENSOR_KEYS = {
    "pot": ("pot_v_per_rad", "pot_zero_v"),
    "tach": ("tach_v_per_rad_s",),
    "encoder": ("encoder_counts_per_rev",),
    "imon": ("monitor_v_per_a",),
}
#: Keys whose value must be > 0 (a gradient may be negative: a sensor wired the other way round).
POSITIVE_KEYS = frozenset({*ALWAYS_KEYS, "amp_gain_a_per_v", "monitor_v_per_a", "supply_v", "resistance_ohm",
                           "pwm_period_s"})
#: An H-bridge is a voltage drive with no transconductance stage: JointIO turns the commanded
#: current into PWM duty itself, so the chain's volts stage of such a joint is this neutral 1 A/V,
#: which nothing converts through.
HBRIDGE_CHAIN_AMP_GAIN_A_PER_V = 1.0


@dataclass(frozen=True)
class JointNominal:
    """One joint's nominal values (SI); ``None``: not given (the joint does not need it)."""

    name: str
    amplifier: str
    ratio: float
    kt_nm_per_a: float
    current_limit_a: float
    inertia_kg_m2: float
    amp_gain_a_per_v: float | None = None
    pot_v_per_rad: float | None = None
    pot_zero_v: float | None = None
    tach_v_per_rad_s: float | None = None
    tach_dead_band_rad_s: float | None = None
    encoder_counts_per_rev: float | None = None
    monitor_v_per_a: float | None = None
    supply_v: float | None = None
    resistance_ohm: float | None = None
    ke_v_s_per_rad: float | None = None
    pwm_period_s: float | None = None
    gravity_torque_nm: float | None = None
    gravity_phase_rad: float | None = None

    @property
    def torque_limit_nm(self) -> float:
        """The torque the amplifier's current limit gives at the joint: I_max · Kt · N."""
        return self.current_limit_a * self.kt_nm_per_a * self.ratio

    @property
    def chain_amp_gain_a_per_v(self) -> float:
        """The normalizing chain's amplifier gain (see :data:`HBRIDGE_CHAIN_AMP_GAIN_A_PER_V`)."""
        if self.amp_gain_a_per_v is not None:
            return self.amp_gain_a_per_v
        return HBRIDGE_CHAIN_AMP_GAIN_A_PER_V

    def scaling(self) -> SensorScaling:
        """A new :class:`SensorScaling` (the drivers' calibration updates it in place); values the
        joint does not give keep SensorScaling's placeholders, which nothing of the joint reads."""
        given = {k: getattr(self, k) for k in SCALING_KEYS if getattr(self, k) is not None}
        return SensorScaling(**given)


NOMINAL_KEYS = tuple(f.name for f in fields(JointNominal) if f.name not in ("name", "amplifier"))
SCALING_KEYS = tuple(k for k in NOMINAL_KEYS
                     if k not in ("inertia_kg_m2", "tach_dead_band_rad_s", "gravity_torque_nm", "gravity_phase_rad"))


def required_keys(joint: JointSpec) -> tuple[str, ...]:
    """The nominal keys ``joint`` must give (its amplifier type and its wired sensors)."""
    keys = [*ALWAYS_KEYS, *AMPLIFIER_KEYS[joint.amplifier]]
    for signal, needs in SENSOR_KEYS.items():
        if signal in joint.wiring:
            keys.extend(needs)
    return tuple(keys)


def joint_nominal(joint: JointSpec) -> JointNominal:
    """Read ``[joint.servo.nominal]`` of one joint (errors name the file and the key)."""
    if "nominal" not in joint.servo:
        raise joint.servo.error("nominal", "a [joint.servo.nominal] table: the controller's datasheet values "
                                           "(see servo.nominal)")
    tbl: ConfigTable = joint.servo.table("nominal")
    tbl.check_unknown(set(NOMINAL_KEYS))
    values: dict[str, float] = {}
    required = required_keys(joint)
    for key in NOMINAL_KEYS:
        if key not in tbl and key not in required:
            continue
        v = tbl.get_float(key)
        if key in POSITIVE_KEYS and not v > 0.0:
            raise tbl.error(key, "a number > 0", v)
        if key in ("pot_v_per_rad", "encoder_counts_per_rev") and v == 0.0:
            raise tbl.error(key, "a non-zero number", v)
        values[key] = v
    return JointNominal(joint.name, joint.amplifier, **values)


def rig_nominal(rig: RigSpec) -> list[JointNominal]:
    """Every joint's nominal values, in rig order."""
    return [joint_nominal(j) for j in rig.joints]


def nominal_scaling(nominal: list[JointNominal]) -> list[SensorScaling]:
    """New sensor scalings for the drivers (one per joint)."""
    return [n.scaling() for n in nominal]


def nominal_chain(nominal: list[JointNominal]) -> NormalizingChain:
    """The normalizing chain from the nominal J, N, Kt and amplifier gain."""
    return normalizing_chain([n.inertia_kg_m2 for n in nominal], [n.ratio for n in nominal],
                             [n.kt_nm_per_a for n in nominal], [n.chain_amp_gain_a_per_v for n in nominal])
