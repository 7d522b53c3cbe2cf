"""The loop and nonlinearity parameters of one joint of a rig, read defensively from its TOML.

Keys read (all optional; anything missing falls back to the JPL paper's joint-1 figures of DESIGN
section 9 and the fallback is listed in :attr:`JointParams.notes`)::

    [rig]
    servo_rate_hz = 125.0             # sampling rate (T = 1/rate)
    computation_delay_s = 0.004       # sensor sampling → amplifier command write, 0..T

    [[joint]]
    name = "shoulder-azimuth"
    inertia_kg_m2 = 3.0               # total joint inertia J at the output
    [joint.servo]
    gains = { kp = 100, kpi = 5000, kv = 50, kvi = 1000 }
    velocity = "tach"                 # or "encoder"
    switch_off_kp = 1100.0            # position gain while the integrators are switched off
    amplifier_bandwidth_hz = 300.0    # optional current-loop lag
    [joint.tach]
    deadband_rad_s = 0.15             # or gradient_v_per_rad_s and brush_drop_v
    [joint.friction]
    coulomb_nm = 4.24                 # or breakout_nm (output side, N·m)
    [joint.pot]
    quantum_rad = 0.00145             # or bits + range_deg
    [joint.motor]
    peak_torque_nm = 0.847            # with [joint.drive] ratio → acceleration limit
    [joint.drive]
    ratio = 100
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from emulators.presets import DEFAULT_RIG, resolve_rig
from hal.config import ConfigError, ConfigTable, load_toml
from servo.analysis.describing import DeadZone, Nonlinearity, Quantizer, Relay, Saturation
from servo.analysis.loop import Gains, LoopConfig

#: Fallbacks from DESIGN section 9 (JPL arm joint 1).
DEFAULT_RATE_HZ = 125.0
DEFAULT_DELAY_FRACTION = 0.5
DEFAULT_DEADBAND_RAD_S = 0.15
DEFAULT_COULOMB_NM = 4.24  # 600 oz-in breakout at the output shaft
DEFAULT_INERTIA = 3.0
DEFAULT_QUANTUM_RAD = 1.45e-3  # 12-bit pot over ~340°
DEFAULT_PEAK_TORQUE_NM = 0.847
DEFAULT_RATIO = 100.0


@dataclass
class JointParams:
    """Everything ``vmehil tune`` needs about one joint (SI units)."""

    rig: str
    joint: int  #: 1-based
    name: str
    cfg: LoopConfig
    gains_source: str
    tach_deadband_rad_s: float | None
    coulomb_nm: float
    inertia_kg_m2: float
    position_quantum_rad: float
    accel_limit_rad_s2: float
    switch_off_kp: float
    notes: list[str] = field(default_factory=list)

    def switch_off_cfg(self) -> LoopConfig:
        """The loop while the integrators are switched off: no integral action, Kp raised."""
        g = self.cfg.gains
        return self.cfg.replace(gains=Gains(kp=self.switch_off_kp, kpi=0.0, kv=g.kv, kvi=0.0))

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

    def describe(self) -> dict:
        c = self.cfg
        return {
            "rig": self.rig, "joint": self.joint, "joint_name": self.name,
            "gains": c.gains.as_dict(), "gains_source": self.gains_source,
            "sample_period_s": c.sample_period_s, "computation_delay_s": c.delay_s,
            "velocity_source": c.velocity_source, "amplifier_bandwidth_hz": c.amplifier_bandwidth_hz,
            "tach_deadband_rad_s": self.tach_deadband_rad_s, "coulomb_friction_nm": self.coulomb_nm,
            "inertia_kg_m2": self.inertia_kg_m2, "position_quantum_rad": self.position_quantum_rad,
            "accel_limit_rad_s2": self.accel_limit_rad_s2, "switch_off_kp": self.switch_off_kp,
            "notes": list(self.notes),
        }


def _sub(t: ConfigTable, name: str) -> ConfigTable | None:
    return t.table(name) if name in t else None


def _num(t: ConfigTable | None, name: str, **kw) -> float | None:
    if t is None or name not in t:
        return None
    return t.float(name, **kw)


def load_joint(rig: str | Path | None, joint: int = 1, gains: str | None = None,
               switch_off_kp: float | None = None) -> JointParams:
    """Read joint ``joint`` (1-based) of ``rig`` (preset name or path; None = jpl-arm).

    ``gains``: ``"kp=..,kv=.."`` overrides; ``switch_off_kp`` overrides the switch-off gain.
    Raises :class:`hal.config.ConfigError` (a ValueError) for malformed values and
    :class:`~servo.analysis.loop.GainError` for bad gains.
    """
    if isinstance(joint, bool) or not isinstance(joint, int) or joint < 1:
        raise ValueError(f"joint number {joint!r} must be 1 or more (joints are numbered from 1)")
    path = resolve_rig(rig)
    root = load_toml(path)
    rig_name = str(rig or DEFAULT_RIG)
    notes: list[str] = []
    rt = _sub(root, "rig")
    rate = _num(rt, "servo_rate_hz", min=1e-3)
    if rate is None:
        rate = DEFAULT_RATE_HZ
        notes.append(f"servo rate: rig has no [rig] servo_rate_hz, using the paper's {DEFAULT_RATE_HZ:g} Hz")
    T = 1.0 / rate
    delay = _num(rt, "computation_delay_s", min=0.0)
    if delay is None:
        d = DEFAULT_DELAY_FRACTION
        notes.append(f"computation delay: rig has no [rig] computation_delay_s, assuming {d:g}·T = {d * T * 1e3:g} ms")
    else:
        if delay > T * (1 + 1e-9):
            raise ConfigError(root.source, "rig.computation_delay_s", f"a delay between 0 and one period ({T:g} s)",
                              delay)
        d = min(delay / T, 1.0)

    joints = root.tables("joint") if "joint" in root else []
    if joints and joint > len(joints):
        raise ValueError(f"rig {rig_name} has {len(joints)} joints; --joint must be 1..{len(joints)}, not {joint}")
    jt = joints[joint - 1] if joints else None
    if jt is None:
        notes.append("joint: rig has no [[joint]] tables, using the paper's joint-1 figures (DESIGN section 9)")
    name = jt.str("name", f"joint{joint}") if jt is not None else f"joint{joint}"

    st = _sub(jt, "servo") if jt is not None else None
    if st is not None and "gains" in st:
        g = Gains.from_mapping(dict(st.table("gains").data))
        gsrc = "rig"
    else:
        g = Gains.paper()
        gsrc = "paper defaults"
        notes.append("gains: no [joint.servo] gains in the rig, using the paper's Kp=100, Kpi=5000, Kv=50, KvI=1000")
    if gains:
        g = g.with_overrides(gains)
        gsrc += " + --gains overrides"
    velocity = st.str("velocity", "tach", choices=("tach", "encoder")) if st is not None else "tach"
    if st is None or "velocity" not in st.data:
        notes.append("velocity path: not given in the rig, assuming a tachometer")
    amp_bw = _num(st, "amplifier_bandwidth_hz", min=1e-6)
    cfg = LoopConfig(gains=g, sample_period_s=T, delay_fraction=d, velocity_source=velocity,
                     amplifier_bandwidth_hz=amp_bw)

    inertia = _num(jt, "inertia_kg_m2", min=1e-12) if jt is not None else None
    if inertia is None and jt is not None and "link" in jt:
        # plant tables: link inertia plus the rotor reflected through N² (see docs/plant.md)
        n_gear = _num(_sub(jt, "gear"), "ratio", min=1e-9) or DEFAULT_RATIO
        rotor = _num(_sub(jt, "motor"), "rotor_inertia_kg_m2", min=0.0) or 0.0
        inertia = (_num(_sub(jt, "link"), "inertia_kg_m2", min=0.0) or 0.0) + rotor * n_gear**2
    if inertia is None:
        inertia = DEFAULT_INERTIA
        notes.append(f"inertia: not in the rig, assuming J = {DEFAULT_INERTIA:g} kg·m²")

    tach = _sub(jt, "tach") if jt is not None else None
    deadband = _num(tach, "deadband_rad_s", min=0.0)
    if deadband is None and tach is not None and "brush_drop_v" in tach and "gradient_v_per_rad_s" in tach:
        deadband = tach.float("brush_drop_v", min=0.0) / tach.float("gradient_v_per_rad_s", min=1e-12)
    if deadband is None and velocity == "tach":
        deadband = DEFAULT_DEADBAND_RAD_S
        notes.append(f"tach dead band: not in the rig, assuming {DEFAULT_DEADBAND_RAD_S:g} rad/s at the joint")

    fr = _sub(jt, "friction") if jt is not None else None
    coulomb = _num(fr, "coulomb_nm", min=0.0)
    if coulomb is None:
        coulomb = _num(fr, "breakout_nm", min=0.0)
    if coulomb is not None and jt is not None and "gear" in jt:
        coulomb *= _num(_sub(jt, "gear"), "ratio", min=1e-9) or 1.0  # plant friction is input-referred
    if coulomb is None:
        coulomb = DEFAULT_COULOMB_NM
        notes.append(f"friction: not in the rig, assuming {DEFAULT_COULOMB_NM:g} N·m at the output (600 oz-in)")

    pot = _sub(jt, "pot") if jt is not None else None
    quantum = _num(pot, "quantum_rad", min=0.0)
    if quantum is None and pot is not None and "bits" in pot and "range_deg" in pot:
        quantum = math.radians(pot.float("range_deg", min=0.0)) / 2 ** pot.int("bits", min=1, max=32)
    if quantum is None:
        quantum = DEFAULT_QUANTUM_RAD
        notes.append(f"position quantum: not in the rig, assuming {DEFAULT_QUANTUM_RAD * 1e3:g} mrad (12-bit pot)")

    motor = _sub(jt, "motor") if jt is not None else None
    drive = (_sub(jt, "gear") or _sub(jt, "drive")) if jt is not None else None
    peak = _num(motor, "peak_torque_nm", min=0.0)
    ratio = _num(drive, "ratio", min=0.0)
    if peak is None or ratio is None:
        notes.append(f"torque limit: not in the rig, assuming {DEFAULT_PEAK_TORQUE_NM:g} N·m motor peak "
                     f"× {DEFAULT_RATIO:g}:1")
    peak = DEFAULT_PEAK_TORQUE_NM if peak is None else peak
    ratio = DEFAULT_RATIO if ratio is None else ratio
    accel_limit = peak * ratio / inertia if peak > 0 else math.inf

    if switch_off_kp is None:
        switch_off_kp = _num(st, "switch_off_kp", min=0.0)
        if switch_off_kp is None:
            switch_off_kp = g.kp + g.kvi
            notes.append(f"switch-off gain: not in the rig, raising Kp to Kp + KvI = {switch_off_kp:g}")
    elif not (math.isfinite(switch_off_kp) and switch_off_kp > 0):
        raise ValueError(f"--switch-off-kp {switch_off_kp} must be a positive number")

    return JointParams(rig=rig_name, joint=joint, name=name, cfg=cfg, gains_source=gsrc,
                       tach_deadband_rad_s=deadband if velocity == "tach" else None,
                       coulomb_nm=coulomb, inertia_kg_m2=inertia, position_quantum_rad=quantum,
                       accel_limit_rad_s2=accel_limit, switch_off_kp=float(switch_off_kp), notes=notes)
