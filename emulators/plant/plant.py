"""The joint plant: amplifiers, DC motors, Harmonic Drives, links and sensors, vectorised.

One call of :meth:`Plant.step_period` integrates one servo period at the fixed plant rate
(default 4 kHz: 32 substeps of 250 µs per 8 ms period). Per substep, for every joint:

1. amplifier → winding current (exact exponential solutions, speed held; see
   :mod:`emulators.plant.amplifier`);
2. motor torque ``Kt·i`` less the reflected load (gravity, or the flexspline spring) →
   exact stick/slip step of the motor shaft (:func:`emulators.plant.friction.stick_slip_step`);
3. link update (compliant joints), inelastic hard stops;
4. tachometer generator and its filter; encoder x4 position recorded.

Sensor outputs are taken at the end of the period (the next sampling instant), with seeded
noise; the encoder reports what happened during the period as ``QuadratureEvents``.
Ground truth (``PlantSensors.truth``) is for reports and tests only — never for the servo.

Faults of the sensors and power stages that live on the plant side of the connector panel are
named faults (:class:`emulators.faults.FaultInjectable`, ``Plant.FAULTS``): ``pot_open``,
``pot_frozen``, ``tach_stuck`` and ``amp_fault``, each for one joint (``joint=NAME``). They
change what the sensors report (or latch the amplifier's fault), never the mechanics, and
survive :meth:`Plant.reset` like a board's faults survive SYSRESET.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field

import numpy as np

from emulators.faults import FaultInjectable
from emulators.plant import kernel as _kernel
from emulators.plant import kernel_layout as _k
from emulators.plant.amplifier import (
    AmpArrays,
    AmpConsts,
    AmpDrive,
    AmpState,
    EnableWatchdog,
    LaneEnableWatchdog,
    check_slow_faults,
    current_step,
    current_step_linear,
    prepare_drive,
)
from emulators.plant.brake import HoldingBrakes
from emulators.plant.encoder import encoder_events
from emulators.plant.friction import FrictionArrays, StickSlipStepper
from emulators.plant.lanes import LaneStepper, event_of_lane, lane_events
from emulators.plant.link_dynamics import gravity_torque, hard_stop_overshoot
from emulators.plant.params import AMP_LINEAR, PlantParams, plant_params_from_config
from emulators.plant.sensors import NoiseStreams, PotArrays, TachArrays
from emulators.signals import QuadratureEvents
from hal.config import ConfigTable
from hal.lanes import LaneSet, lane, stack


@dataclass
class PlantCommand:
    """What the electronics drive into the plant for one period (per-joint arrays, held ZOH).

    Attributes:
        amp_command_v: transconductance amplifier input (V, from a DAC channel).
        amp_enable: amplifier enable line (bool); for an H-bridge, disabled = coast.
        fault_reset: amplifier fault reset line (bool); a rising edge clears latched faults.
        pwm_duty: H-bridge PWM duty 0..1.
        pwm_direction: H-bridge direction line (True = positive voltage).
        brake: H-bridge brake line (True = winding shorted through the low-side switches).
        watchdog_line: the level of the amplifiers' enable-watchdog (charge-pump) line, one
            line for the whole rig (False where none is wired).
        holding_brake: per joint the holding brake's line (True = energised = released; low
            engages the brake; ignored where a joint has none). Left empty it is all low.
    """

    amp_command_v: np.ndarray
    amp_enable: np.ndarray
    fault_reset: np.ndarray
    pwm_duty: np.ndarray
    pwm_direction: np.ndarray
    brake: np.ndarray
    watchdog_line: bool = False
    holding_brake: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __post_init__(self) -> None:
        if np.size(self.holding_brake) == 0 and np.size(self.amp_enable) != 0:
            self.holding_brake = np.zeros(np.size(self.amp_enable), dtype=bool)

    def copy(self) -> PlantCommand:
        """A copy with its own arrays."""
        return PlantCommand(
            amp_command_v=np.array(self.amp_command_v, dtype=float),
            amp_enable=np.array(self.amp_enable, dtype=bool),
            fault_reset=np.array(self.fault_reset, dtype=bool),
            pwm_duty=np.array(self.pwm_duty, dtype=float),
            pwm_direction=np.array(self.pwm_direction, dtype=bool),
            brake=np.array(self.brake, dtype=bool),
            watchdog_line=bool(self.watchdog_line),
            holding_brake=np.array(self.holding_brake, dtype=bool),
        )

    @classmethod
    def from_lanes(cls, commands: Sequence[PlantCommand]) -> PlantCommand:
        """The commands of B plants (lane order) as one command of the stacked plant
        (:meth:`Plant.from_lanes`): per-joint arrays lane-major, the watchdog line a lane value
        (:func:`hal.lanes.stack`)."""
        def cat(name: str, dtype: type) -> np.ndarray:
            return np.concatenate([np.asarray(getattr(c, name), dtype=dtype) for c in commands])

        return cls(
            amp_command_v=cat("amp_command_v", float), amp_enable=cat("amp_enable", bool),
            fault_reset=cat("fault_reset", bool), pwm_duty=cat("pwm_duty", float),
            pwm_direction=cat("pwm_direction", bool), brake=cat("brake", bool),
            watchdog_line=stack([bool(c.watchdog_line) for c in commands]),
            holding_brake=cat("holding_brake", bool),
        )

    def lane(self, b: int, n: int) -> PlantCommand:
        """Lane ``b``'s command (``n`` joints a lane) of a stacked command (copies)."""
        sl = slice(b * n, (b + 1) * n)
        return PlantCommand(
            amp_command_v=np.array(self.amp_command_v[sl], dtype=float),
            amp_enable=np.array(self.amp_enable[sl], dtype=bool),
            fault_reset=np.array(self.fault_reset[sl], dtype=bool),
            pwm_duty=np.array(self.pwm_duty[sl], dtype=float),
            pwm_direction=np.array(self.pwm_direction[sl], dtype=bool),
            brake=np.array(self.brake[sl], dtype=bool),
            watchdog_line=bool(lane(self.watchdog_line, b)),
            holding_brake=np.array(self.holding_brake[sl], dtype=bool),
        )

    @classmethod
    def idle(cls, n: int) -> PlantCommand:
        """All amplifiers disabled, zero command, no brake, the watchdog line low, every holding
        brake's line low (engaged)."""
        return cls(
            amp_command_v=np.zeros(n),
            amp_enable=np.zeros(n, dtype=bool),
            fault_reset=np.zeros(n, dtype=bool),
            pwm_duty=np.zeros(n),
            pwm_direction=np.ones(n, dtype=bool),
            brake=np.zeros(n, dtype=bool),
            holding_brake=np.zeros(n, dtype=bool),
        )


@dataclass
class PlantSensors:
    """Sensor outputs at the end of a period (the next sampling instant).

    Attributes:
        pot_v: joint potentiometer wiper (V).
        tach_v: joint tachometer (V; 0 where a joint has none).
        imon_v: amplifier current monitor (V).
        amp_fault: amplifier fault line (bool, latched).
        encoder: one :class:`QuadratureEvents` per joint: what the decoder input saw in the period.
        switching: H-bridge PWM switching during the period (bool; for noise coupling into ADCs).
        switching_noise_v: rms noise each joint's H-bridge couples into ADC inputs during the
            period (V; 0 where not switching). The ADC side adds it to its readings.
        truth: ground truth for reports/tests (SI): ``theta_joint``, ``omega_joint``,
            ``theta_motor``, ``omega_motor``, ``current_a``, ``friction_torque_nm`` (motor shaft,
            end of period), ``motor_torque_nm``,
            ``stuck``, ``at_stop``, ``amp_thermal``, ``amp_fault_cause``, ``time_s``;
            ``amp_enabled`` (the output stage is on: enable line high, not latched off by the
            enable watchdog, no latched fault), ``amp_watchdog_cause`` (why the enable watchdog
            latched the amplifier off: ``WATCHDOG_*`` bits, 0 = not latched),
            ``amp_watchdog_tripped`` (cause ≠ 0); ``encoder_x4`` (float encoder position at
            the end); and ``brake_engaged`` (the holding brake's armature holds at the end; False
            where a joint has none).
    """

    pot_v: np.ndarray
    tach_v: np.ndarray
    imon_v: np.ndarray
    amp_fault: np.ndarray
    encoder: list[QuadratureEvents]
    switching: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    switching_noise_v: np.ndarray = field(default_factory=lambda: np.zeros(0))
    truth: dict[str, np.ndarray] = field(default_factory=dict)

    @classmethod
    def from_lanes(cls, sensors: Sequence[PlantSensors]) -> PlantSensors:
        """The answers of B plants (lane order) as one answer of the stacked plant: per-joint
        arrays lane-major, ``encoder`` one lane-mode :class:`QuadratureEvents` per joint
        (:func:`emulators.plant.lanes.lane_events`), truth keys every answer has, lane-major."""
        def cat(name: str) -> np.ndarray:
            return np.concatenate([np.asarray(getattr(s, name)) for s in sensors])

        n = len(sensors[0].encoder)
        keys = [k for k in sensors[0].truth if all(k in s.truth for s in sensors)]
        return cls(
            pot_v=cat("pot_v"), tach_v=cat("tach_v"), imon_v=cat("imon_v"), amp_fault=cat("amp_fault"),
            encoder=[lane_events([s.encoder[j] for s in sensors]) for j in range(n)],
            switching=cat("switching"), switching_noise_v=cat("switching_noise_v"),
            truth={k: np.concatenate([np.asarray(s.truth[k]) for s in sensors]) for k in keys},
        )

    def lane(self, b: int) -> PlantSensors:
        """Lane ``b``'s answer of a stacked answer (what its scalar plant answered; copies)."""
        n = len(self.encoder)
        sl = slice(b * n, (b + 1) * n)

        def part(a: np.ndarray) -> np.ndarray:
            a = np.asarray(a)
            return a[sl].copy() if a.size else a.copy()

        return PlantSensors(
            pot_v=part(self.pot_v), tach_v=part(self.tach_v), imon_v=part(self.imon_v),
            amp_fault=part(self.amp_fault), encoder=[event_of_lane(e, b) for e in self.encoder],
            switching=part(self.switching), switching_noise_v=part(self.switching_noise_v),
            truth={k: part(v) for k, v in self.truth.items()},
        )


class _StepConsts:
    """Everything that depends only on the step length ``h``."""

    def __init__(self, plant: Plant, h: float) -> None:
        self.h = h
        self.amp = AmpConsts(plant.amp, plant.R, plant.L, plant.Ke, h)
        tau = plant.tach.tau
        self.tach_decay = np.where(tau > 0.0, np.exp(-h / np.maximum(tau, 1e-300)), 0.0)
        self.stick_slip = StickSlipStepper(plant.fr, plant.J_m, h)
        self.P: np.ndarray | None = None  #: the compiled kernel's parameter matrix (built on first use)
        self.F = np.zeros(_k.N_FLAGS, dtype=np.int64)

    def kernel_arrays(self, plant: Plant) -> None:
        """Build what the compiled kernel reads (:mod:`emulators.plant.kernel`), once per step."""
        n = plant.n_joints
        P = np.zeros((_k.N_ROWS, n))
        a, amp, fr, st, tach, pot = self.amp, plant.amp, plant.fr, self.stick_slip, plant.tach, plant.pot
        rows = {
            _k.IS_LIN: amp.is_lin, _k.GAIN: amp.gain, _k.LIN_LIMIT: amp.lin_limit,
            _k.HB_DEADTIME: amp.hb_deadtime_duty, _k.HB_SUPPLY: amp.hb_supply, _k.HB_LIMIT: amp.hb_limit,
            _k.HB_TRIP: amp.hb_trip, _k.RL: a.rl, _k.RL_GAIN: a.rl_gain, _k.EMF_GAIN: a.emf_gain,
            _k.RAIL_GAIN: a.rail_gain, _k.LOOP: a.loop, _k.THERMAL: a.thermal, _k.THERMAL_GAIN: a.thermal_gain,
            _k.SAT_FAULT_S: amp.sat_fault_s, _k.KT: plant.Kt, _k.N_RATIO: plant.N, _k.INV_N: plant.inv_N,
            _k.COMPLIANT: plant.compliant, _k.K_FLEX: plant.K_flex, _k.C_FLEX: plant.C_flex,
            _k.KE_AMP: plant.ke_amp, _k.KE_PHASE: plant.ke_phase, _k.J_LINK: plant.J_link,
            _k.G_TORQUE: plant.G, _k.G_PHASE: plant.G_phase, _k.LOWER: plant.lower, _k.UPPER: plant.upper,
            _k.EXT_TORQUE: plant.external_torque_nm, _k.FR_RIPPLE: fr.ripple, _k.FR_PHASE: fr.ripple_phase,
            _k.INV_WS: st.inv_ws, _k.D_TS: st.d_ts, _k.COULOMB: fr.coulomb, _k.BJH: st.bjh, _k.INV_J: st.inv_j,
            _k.BREAKOUT: fr.breakout, _k.VISCOUS: fr.viscous, _k.T_PRESENT: tach.present,
            _k.T_GRADIENT: tach.gradient, _k.T_BRUSH: tach.brush_drop, _k.T_RIPPLE: tach.ripple,
            _k.T_CYCLES: tach.cycles, _k.T_DECAY: self.tach_decay, _k.T_OFFSET: tach.offset,
            _k.T_NOISE: tach.noise, _k.ENC_SCALE: plant.enc_scale, _k.ENC_FS: plant.enc_sample_hz,
            _k.POT_SPAN: pot.span, _k.POT_CENTER: pot.center, _k.POT_VLOW: pot.v_low, _k.POT_VHIGH: pot.v_high,
            _k.POT_BOW: pot.bow, _k.POT_PERIODIC: pot.periodic, _k.POT_CYCLES: pot.cycles,
            _k.POT_NOISE: pot.noise, _k.MON_GAIN: np.where(amp.is_lin, amp.lin_monitor, amp.hb_monitor),
            _k.MON_OFFSET: np.where(amp.is_lin, amp.lin_monitor_offset, amp.hb_monitor_offset),
            _k.MON_NOISE: amp.monitor_noise, _k.SW_NOISE: plant.hb_switching_noise,
            _k.BRAKE_HOLD: plant.brakes.hold_motor_nm,
            _k.CONTACT_K: plant.contact_k_nm_per_rad, _k.CONTACT_RAD: plant.contact_rad,
        }
        for row, values in rows.items():
            P[row] = values
        self.P = P
        F = self.F
        F[_k.F_COMPLIANT] = plant.any_compliant
        F[_k.F_GRAVITY] = plant.has_gravity
        F[_k.F_KE] = plant.has_ke
        F[_k.F_TACH] = plant.has_tach
        F[_k.F_TACH_RIPPLE] = plant.has_tach_ripple
        F[_k.F_DIRECT] = st.direct
        F[_k.F_BRAKE] = plant.has_brakes
        F[_k.F_LAYOUT] = _k.LAYOUT_ID
        self.set_external(plant)
        self.enci = np.ascontiguousarray(np.stack([plant.enc_counts_per_rev, plant.enc_index_phase]), dtype=np.int64)
        self._max_fs = float(np.max(plant.enc_sample_hz, initial=0.0))
        self._buffers: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def kernel_buffers(self, n: int, n_sub: int) -> tuple[np.ndarray, np.ndarray]:
        """The kernel's scratch for periods of ``n_sub`` substeps: x4 positions, index offsets."""
        b = self._buffers.get(n_sub)
        if b is None:
            # index pulses in one period are bounded by the substep transitions plus the decoder samples
            cap = 2 * n_sub + round(n_sub * self.h * self._max_fs) + 4
            b = self._buffers[n_sub] = (np.zeros(n_sub + 1), np.zeros((n, cap), dtype=np.int64))
        return b

    def set_external(self, plant: Plant) -> None:
        """The environment's torque changed (kernel parameters follow)."""
        if self.P is not None:
            self.P[_k.EXT_TORQUE] = plant.external_torque_nm
            self.F[_k.F_EXTERNAL] = plant.has_external
            self.P[_k.CONTACT_K] = plant.contact_k_nm_per_rad
            self.P[_k.CONTACT_RAD] = plant.contact_rad
            self.F[_k.F_CONTACT] = plant.has_contact


def _stack(joints: list, path: str, dtype: type = float) -> np.ndarray:
    out = []
    for j in joints:
        v = j
        for part in path.split("."):
            v = getattr(v, part)
        out.append(v)
    return np.array(out, dtype=dtype)


def _not_in_lanes(why: str) -> Callable[..., None]:
    def refuse(*_args: object, **_kwargs: object) -> None:
        raise NotImplementedError(why)
    return refuse


#: the compiled path's QuadratureEvents without index pulses, by (counts, illegal, phase)
_EVENTS: dict[tuple[int, int, int], QuadratureEvents] = {}

FAULT_INJECTED = 8  #: ``amp_fault`` injected (truth ``amp_fault_cause`` bit; the others: emulators.plant.amplifier)

#: default volts of an open pot wiper: the ADC input's bias resistor pulls a floating input to the
#: +10 V rail (what the servo watchdog's rail check expects of an open wiper)
OPEN_WIPER_V = 10.0


class Plant(FaultInjectable):
    """Vectorised plant of ``n_joints`` joints with their amplifiers and sensors.

    Args:
        params: the joints (see :mod:`emulators.plant.params`).
        seed: seed of all noise streams (``emulators.rng.rng_for(seed, "plant", joint, source)``).
        rate_hz: integration rate; ``None`` takes ``params.rate_hz`` (4 kHz by default). Each
            period is split into ``round(period·rate)`` equal substeps.
        kernel: ``"numba"`` (the compiled period kernel, :mod:`emulators.plant.kernel`) or
            ``"numpy"`` (the vectorised reference path); ``None`` takes ``$VMEHIL_PLANT_KERNEL``,
            else ``"numba"``. The compiled kernel is loaded (or compiled, once, into numba's
            on-disk cache) here, before any loop runs.
    """

    FAULTS = {  # noqa: RUF012 - the FaultInjectable catalogue (a class attribute by design)
        "pot_open": "joint=NAME[, volts=V]: the wiper lifts off the element; the floating ADC input is "
                    f"pulled to V (default {OPEN_WIPER_V:+g} V, the rail)",
        "pot_frozen": "joint=NAME[, volts=V]: the pot's shaft coupling slips: the wiper stays where it was "
                      "(default: its noise-free voltage when injected) while the joint moves on",
        "tach_stuck": "joint=NAME[, volts=V]: the tachometer output is held at V (default 0 V: an open lead or "
                      "lifted brushes; ±10 V: shorted to a rail)",
        "amp_fault": "joint=NAME: the joint's amplifier trips: output stage off, fault line asserted (latched "
                     "again every period while injected, so a fault reset does not clear it)",
    }

    #: lane mode (:meth:`from_lanes`): the batch's lanes (``None``: a scalar plant)
    lanes: LaneSet | None = None
    n_lanes = 1  #: lanes stacked (1: a scalar plant)

    def __init__(self, params: PlantParams, *, seed: int = 0, rate_hz: float | None = None,
                 kernel: str | None = None) -> None:
        params.validate()
        self.kernel, self._kernel_fn = _kernel.kernel_for(kernel)
        self.params = params
        self.seed = int(seed)
        self.rate_hz = float(rate_hz if rate_hz is not None else params.rate_hz)
        if not self.rate_hz > 0:
            raise ValueError("rate_hz must be > 0")
        js = params.joints
        self.names: list[str] = [j.name for j in js]
        self.n_joints = len(js)
        # motor and gear
        self.R = _stack(js, "motor.resistance_ohm")
        self.L = _stack(js, "motor.inductance_h")
        self.Kt = _stack(js, "motor.kt_nm_per_a")
        self.Ke = _stack(js, "motor.ke_v_s_per_rad")
        self.N = _stack(js, "gear.ratio")
        self.compliant = _stack(js, "gear.compliant", bool)
        self.any_compliant = bool(self.compliant.any())
        self.K_flex = _stack(js, "gear.stiffness_nm_per_rad")
        self.C_flex = _stack(js, "gear.damping_nm_s_per_rad")
        self.ke_amp = _stack(js, "gear.kinematic_error_rad")
        self.ke_phase = _stack(js, "gear.kinematic_error_phase_rad")
        self.has_ke = bool(np.any(self.ke_amp != 0.0))
        j_rotor = _stack(js, "motor.rotor_inertia_kg_m2") + _stack(js, "gear.wave_generator_inertia_kg_m2")
        self.J_link = _stack(js, "link.inertia_kg_m2")
        #: inertia at the motor shaft seen by the stick/slip step (rotor only when compliant)
        self.J_m = np.where(self.compliant, j_rotor, j_rotor + self.J_link / self.N**2)
        self.G = _stack(js, "link.gravity_torque_nm")
        self.G_phase = _stack(js, "link.gravity_phase_rad")
        self.has_gravity = bool(np.any(self.G != 0.0))
        self.lower = _stack(js, "link.lower_stop_rad")
        self.upper = _stack(js, "link.upper_stop_rad")
        self.fr = FrictionArrays(
            breakout=_stack(js, "friction.breakout_nm"),
            coulomb=_stack(js, "friction.coulomb_nm"),
            stribeck_w=_stack(js, "friction.stribeck_velocity_rad_s"),
            viscous=_stack(js, "friction.viscous_nm_s_per_rad"),
            ripple=_stack(js, "friction.ripple_fraction"),
            ripple_phase=_stack(js, "friction.ripple_phase_rad"),
        )
        is_lin = np.array([j.amplifier == AMP_LINEAR for j in js])
        self.amp = AmpArrays(
            is_lin=is_lin,
            gain=_stack(js, "linear_amp.gain_a_per_v"),
            bw_rad_s=2.0 * math.pi * _stack(js, "linear_amp.bandwidth_hz"),
            lin_limit=_stack(js, "linear_amp.current_limit_a"),
            lin_supply=_stack(js, "linear_amp.supply_v"),
            lin_monitor=_stack(js, "linear_amp.monitor_v_per_a"),
            lin_monitor_offset=_stack(js, "linear_amp.monitor_offset_v"),
            lin_monitor_noise=_stack(js, "linear_amp.monitor_noise_v"),
            sat_fault_s=_stack(js, "linear_amp.saturation_fault_s"),
            hb_supply=_stack(js, "hbridge.supply_v"),
            hb_deadtime_duty=_stack(js, "hbridge.dead_time_s") * _stack(js, "hbridge.pwm_hz"),
            hb_limit=_stack(js, "hbridge.current_limit_a"),
            hb_trip=_stack(js, "hbridge.overcurrent_trip_a"),
            hb_monitor=_stack(js, "hbridge.monitor_v_per_a"),
            hb_monitor_offset=_stack(js, "hbridge.monitor_offset_v"),
            hb_monitor_noise=_stack(js, "hbridge.monitor_noise_v"),
            i_cont=np.where(is_lin, _stack(js, "linear_amp.continuous_current_a"),
                            _stack(js, "hbridge.continuous_current_a")),
            tau_th=np.where(is_lin, _stack(js, "linear_amp.thermal_time_constant_s"),
                            _stack(js, "hbridge.thermal_time_constant_s")),
        )
        self.pot = PotArrays(
            span=_stack(js, "pot.span_rad"),
            center=_stack(js, "pot.center_rad"),
            v_low=_stack(js, "pot.v_low"),
            v_high=_stack(js, "pot.v_high"),
            bow=_stack(js, "pot.bow_fraction"),
            periodic=_stack(js, "pot.periodic_fraction"),
            cycles=_stack(js, "pot.periodic_cycles"),
            noise=_stack(js, "pot.noise_v"),
        )
        self.tach = TachArrays(
            present=_stack(js, "tach.present", bool),
            gradient=_stack(js, "tach.gradient_v_per_rad_s"),
            brush_drop=_stack(js, "tach.brush_drop_v"),
            ripple=_stack(js, "tach.ripple_fraction"),
            cycles=_stack(js, "tach.ripple_cycles_per_rev"),
            tau=_stack(js, "tach.filter_time_constant_s"),
            offset=_stack(js, "tach.offset_v"),
            noise=_stack(js, "tach.noise_v"),
        )
        self.hb_switching_noise = np.where(is_lin, 0.0, _stack(js, "hbridge.switching_noise_v"))
        self.enc_counts_per_rev = 4 * _stack(js, "encoder.lines_per_rev", np.int64)
        self.enc_index_phase = _stack(js, "encoder.index_phase_x4", np.int64)
        self.enc_sample_hz = _stack(js, "encoder.decoder_sample_hz")
        self.inv_N = 1.0 / self.N
        self.has_tach = bool(self.tach.present.any())
        self.has_tach_ripple = bool(np.any(self.tach.ripple != 0.0))
        self.enc_scale = self.enc_counts_per_rev / (2.0 * math.pi)  #: x4 counts per motor radian
        self.watchdog_timeout_s = params.watchdog_timeout_s
        self.brakes = HoldingBrakes(
            present=_stack(js, "holding_brake.present", bool),
            hold_motor_nm=_stack(js, "holding_brake.holding_torque_nm") / self.N,
            engage_s=_stack(js, "holding_brake.engage_delay_s"),
            release_s=_stack(js, "holding_brake.release_delay_s"),
        )
        self.has_brakes = self.brakes.any
        self._consts: dict[float, _StepConsts] = {}
        # injected sensor faults: per joint the held volts (NaN: healthy); see _fault_changed
        self._held_v = np.full((2, self.n_joints), np.nan)  # rows: pot, tach (the kernel reads both)
        self._pot_held_v = self._held_v[0]
        self._tach_held_v = self._held_v[1]
        self._amp_tripped = np.zeros(self.n_joints, dtype=bool)
        self._sensor_faults = False
        # the compiled path's segments of a period (at most three: start, new command, watchdog out)
        self._segments = (np.zeros(3, dtype=np.int64), np.zeros(3, dtype=np.int64),
                          np.zeros((3, self.n_joints), dtype=bool))
        self.reset()

    # ---- construction helpers -----------------------------------------------------------
    @classmethod
    def from_config(cls, cfg: ConfigTable, *, seed: int = 0, rate_hz: float | None = None,
                    foreign_keys: Collection[str] | None = None, kernel: str | None = None) -> Plant:
        """Build from a rig file's root table (reads ``[plant]`` and ``[[joint]]``; ``foreign_keys``
        as for :func:`~emulators.plant.params.plant_params_from_config`)."""
        return cls(plant_params_from_config(cfg, foreign_keys=foreign_keys), seed=seed, rate_hz=rate_hz,
                   kernel=kernel)

    @classmethod
    def from_lanes(cls, plants: Sequence[Plant], lanes: LaneSet) -> Plant:
        """B scalar plants (lane order; built, reset and stepped as their scalar runs did) as ONE
        plant of B·n joints in lane mode (issue #34, :mod:`hal.lanes`): joint ``j`` of lane ``b``
        at ``b*n + j`` in every per-joint array, command and answer; one compiled kernel call
        steps every lane's period (:mod:`emulators.plant.lanes`), and each lane's values are its
        scalar plant's, bit for bit. Per lane its own parameters, noise generators (the scalar
        plants' objects, drawn in the scalar order), enable watchdog and brakes.

        Refused (``NotImplementedError``: the batch runs such instances scalar): the numpy path,
        an injected plant fault, plants of different joints or rates, at different times or
        noise positions. The stacked plant cannot be reset or take faults (reset the scalar
        plants, then stack them)."""
        plants = list(plants)
        B = len(plants)
        if B != lanes.size:
            raise ValueError(f"{B} plants for {lanes.size} lanes")
        p0 = plants[0]
        n = p0.n_joints
        for p in plants:
            if getattr(p, "lanes", None) is not None:
                raise NotImplementedError("a plant already in lane mode cannot be stacked again")
            if p._kernel_fn is None:
                raise NotImplementedError("plant lanes run the compiled kernel; this plant runs the numpy path")
            if p.active_faults:
                raise NotImplementedError("a plant with an injected fault cannot run in lanes")
            if p.names != p0.names or p.rate_hz != p0.rate_hz:
                raise NotImplementedError("plants of different joints or rates cannot run in lanes")
            if p.time_s != p0.time_s:
                raise NotImplementedError("plants at different times cannot run in lanes")

        def cat(objs: Sequence[object], name: str) -> np.ndarray:  # a per-joint array of each, lane-major
            return np.concatenate([np.asarray(getattr(o, name)) for o in objs])

        def cat_fields(objs: Sequence[object]) -> object:  # a dataclass of per-joint arrays
            return type(objs[0])(**{f: cat(objs, f) for f in vars(objs[0])})

        lp = cls.__new__(cls)
        d = lp.__dict__
        d.update(kernel=p0.kernel, _kernel_fn=p0._kernel_fn, params=p0.params, rate_hz=p0.rate_hz)
        d.update(lanes=lanes, n_lanes=B, lane_joints=n, lane_plants=plants, n_joints=B * n,
                 names=[name for p in plants for name in p.names], seed=stack([p.seed for p in plants]),
                 watchdog_timeout_s=stack([p.watchdog_timeout_s for p in plants]))
        for name in ("R", "L", "Kt", "Ke", "N", "compliant", "K_flex", "C_flex", "ke_amp", "ke_phase", "J_link",
                     "J_m", "G", "G_phase", "lower", "upper", "hb_switching_noise", "enc_counts_per_rev",
                     "enc_index_phase", "enc_sample_hz", "inv_N", "enc_scale", "theta_m", "omega_m", "theta_l",
                     "omega_l", "i", "tach_state", "at_stop", "external_torque_nm", "contact_k_nm_per_rad",
                     "contact_rad"):
            d[name] = cat(plants, name).copy()
        # plant-wide flags of the numpy path; the kernel's flags stay per lane (LaneKernelConsts)
        for name in ("any_compliant", "has_ke", "has_gravity", "has_tach", "has_tach_ripple", "has_external",
                     "has_contact"):
            d[name] = any(p.__dict__[name] for p in plants)
        for name in ("fr", "amp", "pot", "tach"):
            d[name] = cat_fields([p.__dict__[name] for p in plants])
        bs = [p.brakes for p in plants]
        brakes = HoldingBrakes(cat(bs, "present"), cat(bs, "hold_motor_nm"), cat(bs, "engage_s"), cat(bs, "release_s"))
        for name in ("engaged", "line", "switch_s"):
            setattr(brakes, name, cat(bs, name).copy())
        lp.brakes = brakes
        lp.has_brakes = brakes.any
        amp_state = AmpState(B * n)
        for name in ("fault", "cause", "thermal", "sat_time", "saturated"):
            setattr(amp_state, name, cat([p.amp_state for p in plants], name).copy())
        lp.amp_state = amp_state
        lp.watchdog = LaneEnableWatchdog([p.watchdog for p in plants])  # type: ignore[assignment]
        lp.time_s = p0.time_s
        lp._prev_cmd = PlantCommand.from_lanes([p._prev_cmd for p in plants])
        lp._noise = {src: NoiseStreams.from_lanes([p._noise[src] for p in plants]) for src in p0._noise}
        lp._held_v = np.full((2, B * n), np.nan)
        lp._pot_held_v = lp._held_v[0]
        lp._tach_held_v = lp._held_v[1]
        lp._amp_tripped = np.zeros(B * n, dtype=bool)
        lp._sensor_faults = False
        lp._consts = {}
        # lane mode is chosen here, once: the scalar methods stay as they are
        stepper = LaneStepper(lp, lanes, PlantSensors)
        d.update(step_period=stepper.step, _step_consts=stepper.lane_consts, _lane_stepper=stepper,
                 reset=_not_in_lanes("a stacked plant cannot be reset: reset the scalar plants, then stack them"),
                 inject=_not_in_lanes("plant faults cannot be injected in lanes"))
        return lp

    def index_of(self, name: str) -> int:
        """Position of joint ``name`` in the arrays."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no joint named {name!r} (joints: {', '.join(self.names)})") from None

    # ---- faults ---------------------------------------------------------------------------
    def _fault_joint(self, name: str) -> int | None:
        """The joint index of an active fault (``None`` when it is off); a bad joint is refused."""
        f = self.fault(name)
        if f is None:
            return None
        if "joint" not in f:
            self.clear_fault(name)
            raise ValueError(f"plant fault {name}: name the joint (joint=...; joints: {', '.join(self.names)})")
        try:
            return self.index_of(str(f["joint"]))
        except KeyError as e:
            self.clear_fault(name)
            raise ValueError(f"plant fault {name}: {e.args[0]}") from None

    def _fault_changed(self, name: str) -> None:
        f = self.fault(name)
        if f is not None:
            j = self._fault_joint(name)  # refuses a missing or unknown joint
            if name == "pot_frozen" and "volts" not in f:  # the wiper stays where it is now
                f["volts"] = float(self.pot.volts(self.joint_angle())[j])
        self._pot_held_v[:] = np.nan
        self._tach_held_v[:] = np.nan
        self._amp_tripped[:] = False
        held_faults = (("pot_frozen", self._pot_held_v, 0.0), ("pot_open", self._pot_held_v, OPEN_WIPER_V),
                       ("tach_stuck", self._tach_held_v, 0.0))
        for fault, held, default in held_faults:
            j = self._fault_joint(fault)
            params = self.fault(fault)
            if j is not None and params is not None:  # j is only set while the fault is on
                held[j] = float(params.get("volts", default))
        j = self._fault_joint("amp_fault")
        if j is not None:
            self._amp_tripped[j] = True
            self.amp_state.latch(self._amp_tripped, FAULT_INJECTED)
        self._sensor_faults = bool(np.isfinite(self._pot_held_v).any() or np.isfinite(self._tach_held_v).any())

    def idle_command(self) -> PlantCommand:
        return PlantCommand.idle(self.n_joints)

    # ---- state ---------------------------------------------------------------------------
    def reset(self, theta_joint: np.ndarray | None = None) -> None:
        """Return to rest at ``theta_joint`` (rad; default each link's ``initial_angle_rad``),
        currents zero, amplifiers disabled with faults and watchdog latches cleared, noise
        streams restarted."""
        n = self.n_joints
        if theta_joint is None:
            theta = _stack(self.params.joints, "link.initial_angle_rad")
        else:
            theta = np.broadcast_to(np.asarray(theta_joint, dtype=float), (n,)).copy()
        theta = np.clip(theta, self.lower, self.upper)
        self.theta_m = theta * self.N
        if self.has_ke:  # one fixed-point pass so θm/N + ε(θm) ≈ θ
            self.theta_m = (theta - self.ke_amp * np.sin(2.0 * self.theta_m + self.ke_phase)) * self.N
        self.omega_m = np.zeros(n)
        self.theta_l = theta.copy()
        self.omega_l = np.zeros(n)
        self.i = np.zeros(n)
        self.tach_state = np.zeros(n)
        self.amp_state = AmpState(n)
        self.watchdog = EnableWatchdog(n, self.watchdog_timeout_s)
        self.brakes.reset()
        self.at_stop = np.zeros(n, dtype=bool)
        self.external_torque_nm = np.zeros(n)
        self.has_external = False
        self.contact_k_nm_per_rad = np.zeros(n)
        self.contact_rad = np.zeros(n)
        self.has_contact = False
        for c in self._consts.values():
            c.set_external(self)
        self.time_s = 0.0
        self._prev_cmd = PlantCommand.idle(n)
        self._noise = {
            src: NoiseStreams(self.seed, self.names, src) for src in ("pot", "tach", "imon")
        }

    def set_external_torque(self, torque_nm: np.ndarray) -> None:
        """Torque applied to the links by the environment (N·m at the joint; + pushes +),
        e.g. a torque gauge or a contact load. Held until changed; :meth:`reset` clears it."""
        self.external_torque_nm = np.broadcast_to(np.asarray(torque_nm, dtype=float), (self.n_joints,)).copy()
        self.has_external = bool(np.any(self.external_torque_nm != 0.0))
        for c in self._consts.values():
            c.set_external(self)

    def set_contact(self, stiffness_nm_per_rad: np.ndarray, angle_rad: np.ndarray) -> None:
        """A one-sided spring on each rigid joint's link: below ``angle_rad`` it pushes the link
        back up with ``stiffness_nm_per_rad·(angle_rad − θ)`` (N·m at the joint) — the fingers
        meeting a grasped object (:mod:`emulators.grasp`). Evaluated every substep; 0 stiffness: no
        spring. Held until changed; :meth:`reset` clears it."""
        n = self.n_joints
        self.contact_k_nm_per_rad = np.broadcast_to(np.asarray(stiffness_nm_per_rad, dtype=float), (n,)).copy()
        self.contact_rad = np.broadcast_to(np.asarray(angle_rad, dtype=float), (n,)).copy()
        self.has_contact = bool(np.any(self.contact_k_nm_per_rad != 0.0))
        for c in self._consts.values():
            c.set_external(self)

    # ---- kinematics ----------------------------------------------------------------------
    def _theta_out(self, theta_m: np.ndarray) -> np.ndarray:
        th = theta_m / self.N
        if self.has_ke:
            th = th + self.ke_amp * np.sin(2.0 * theta_m + self.ke_phase)
        return th

    def joint_angle(self) -> np.ndarray:
        """True joint (link) angle (rad)."""
        return np.where(self.compliant, self.theta_l, self._theta_out(self.theta_m))

    def joint_speed(self) -> np.ndarray:
        """True joint (link) speed (rad/s)."""
        return np.where(self.compliant, self.omega_l, self.omega_m / self.N)

    # ---- integration ---------------------------------------------------------------------
    def _step_consts(self, h: float) -> _StepConsts:
        c = self._consts.get(h)
        if c is None:
            c = self._consts[h] = _StepConsts(self, h)
        return c

    def _substep(self, c: _StepConsts, drv: AmpDrive, fast_amp: bool, i_ref_term: np.ndarray,
                 brake: np.ndarray | None = None) -> None:
        """One fixed step of every joint (state updated in place); ``brake``: the engaged holding
        brakes' motor-shaft torque (``None``: a plant without brakes)."""
        if fast_amp:
            self.i = current_step_linear(self.amp_state, i_ref_term, self.i, self.omega_m, c.amp)
        else:
            self.i = current_step(self.amp, self.amp_state, drv, self.i, self.omega_m, c.amp)
        t_drive = self.Kt * self.i
        if self.has_external:
            t_drive = t_drive + ~self.compliant * self.external_torque_nm * self.inv_N
        if self.has_contact:  # the one-sided spring of set_contact (rigid joints)
            th_c = self.theta_m * self.inv_N
            t_drive = t_drive + np.where(th_c < self.contact_rad, self.contact_k_nm_per_rad * (self.contact_rad - th_c),
                                         0.0) * self.inv_N
        if self.any_compliant:
            th_out = self._theta_out(self.theta_m)
            tau_s = self.compliant * (
                self.K_flex * (th_out - self.theta_l) + self.C_flex * (self.omega_m * self.inv_N - self.omega_l)
            )
            load = tau_s
            if self.has_gravity:
                load = load + ~self.compliant * gravity_torque(th_out, self.G, self.G_phase)
            t_drive = t_drive - load * self.inv_N
        elif self.has_gravity:
            t_drive = t_drive - gravity_torque(self._theta_out(self.theta_m), self.G, self.G_phase) * self.inv_N
        w1, dth = c.stick_slip(self.omega_m, self.theta_m, t_drive, brake)
        self.theta_m = self.theta_m + dth
        self.omega_m = w1
        if self.any_compliant:
            acc_l = (tau_s - gravity_torque(self.theta_l, self.G, self.G_phase) + self.external_torque_nm) / self.J_link
            self.omega_l = np.where(self.compliant, self.omega_l + c.h * acc_l, self.omega_m * self.inv_N)
            self.theta_l = np.where(self.compliant, self.theta_l + c.h * self.omega_l, self._theta_out(self.theta_m))
            th_j = self.theta_l
        else:
            th_j = self._theta_out(self.theta_m) if self.has_ke else self.theta_m * self.inv_N
        hit = (th_j > self.upper) | (th_j < self.lower)
        if hit.any():
            over = hard_stop_overshoot(th_j, self.lower, self.upper)
            rigid_hit = hit & ~self.compliant
            self.theta_m = self.theta_m - rigid_hit * over * self.N
            self.omega_m = self.omega_m * ~rigid_hit
            if self.any_compliant:
                self.theta_l = self.theta_l - over
                self.omega_l = self.omega_l * ~hit
            th_j = th_j - over
        self.at_stop = hit
        # tachometer generator on the joint axis, then its ripple filter
        if self.has_tach:
            w_j = self.omega_m * self.inv_N
            if self.any_compliant:
                w_j = np.where(self.compliant, self.omega_l, w_j)
            emf = self.tach.gradient * w_j
            if self.has_tach_ripple:
                emf = emf * (1.0 + self.tach.ripple * np.sin(self.tach.cycles * th_j))
            g = (emf - np.minimum(np.maximum(emf, -self.tach.brush_drop), self.tach.brush_drop)) * self.tach.present
            self.tach_state = g + (self.tach_state - g) * c.tach_decay

    def step_period(self, cmd: PlantCommand, period_s: float, delay_s: float = 0.0) -> PlantSensors:
        """Integrate one servo period and return the sensors at its end.

        The previous period's command holds for the first ``delay_s`` seconds (computation
        delay, rounded to the substep grid), then ``cmd`` takes effect; a rising edge of
        ``cmd.fault_reset`` clears latched amplifier faults at that moment, and the enable
        watchdog sees ``cmd.watchdog_line`` then. When the watchdog's pump runs out inside the
        period, the enabled amplifiers open from that substep on.
        """
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        n_sub = max(1, round(period_s * self.rate_hz))
        h = period_s / n_sub
        n_old = min(n_sub, max(0, round(delay_s / h)))
        c = self._step_consts(h)
        if self._amp_tripped.any():  # an injected amplifier fault re-trips after every reset
            self.amp_state.latch(self._amp_tripped, FAULT_INJECTED)
        if self._kernel_fn is not None:
            return self._step_compiled(cmd, period_s, c, n_sub, n_old)
        prev = self._prev_cmd
        wd = self.watchdog
        t0 = self.time_s
        reset_edge = np.asarray(cmd.fault_reset, dtype=bool) & ~np.asarray(prev.fault_reset, dtype=bool)
        x4 = np.empty((n_sub + 1, self.n_joints))
        x4[0] = self.theta_m * self.enc_scale
        switching = np.zeros(self.n_joints, dtype=bool)
        held = prev  # the command the amplifiers obey in the current segment
        drv = self._drive(held)
        s_out = wd.expiry_substep(t0, h, n_sub)
        brakes = self.brakes if self.has_brakes else None
        if brakes is not None:
            brakes.begin(t0, h)
        brake_t = None
        for s in range(n_sub + 1):
            segment = s == 0
            if s == n_old:
                if reset_edge.any():
                    self.amp_state.reset_latches(reset_edge)
                wd.command(cmd.watchdog_line, cmd.amp_enable, prev.amp_enable, t0 + s * h)
                s_out = wd.expiry_substep(t0, h, n_sub)  # an edge retriggers the pump
                held = cmd
                drv = self._drive(held)
                segment = True
                if brakes is not None:
                    brakes.event(s, self._brake_lines(cmd, t0 + s * h))
            if s == s_out:
                if wd.expire(held.amp_enable):
                    drv = self._drive(held)
                    segment = True
                if brakes is not None:  # the pump feeds the brakes' lines too
                    brakes.event(s, np.zeros(self.n_joints, dtype=bool))
            if segment:
                fast = bool(np.all(drv.lin_on & ~self.amp_state.fault))
                i_ref_term = drv.i_ref * (1.0 - c.amp.loop)
                if not drv.hb_drive.any():
                    sw = None
                else:
                    sw = drv.hb_drive & (np.abs(drv.hb_v) < self.amp.hb_supply)
            if s == n_sub:
                break
            if brakes is not None:
                brake_t = brakes.torque_at(s)
            self._substep(c, drv, fast, i_ref_term, brake_t)
            if sw is not None:
                switching |= sw & ~self.amp_state.fault
            x4[s + 1] = self.theta_m * self.enc_scale
        if brakes is not None:
            brakes.finish(n_sub)
        check_slow_faults(self.amp, self.amp_state)
        self._prev_cmd = cmd.copy()  # callers may mutate their command in place
        self.time_s += period_s
        return self._sense(x4, h, c, switching)

    # ---- the compiled path (emulators.plant.kernel) -------------------------------------
    _STATE = ("theta_m", "omega_m", "theta_l", "omega_l", "i", "tach_state")

    def _bind_state(self) -> np.ndarray:
        """The state matrix the kernel integrates in place; the state attributes (``theta_m``,
        ``omega_m``, ..., ``amp_state.thermal``/``sat_time``) are its rows. An attribute replaced
        from outside (a test setting ``omega_m``) is copied in first."""
        X = getattr(self, "_X", None)
        if X is None:
            X = self._X = np.zeros((8, self.n_joints))
            self._X_rows = [X[k] for k in range(8)]
            for k, name in enumerate(self._STATE):
                X[k] = getattr(self, name)
                setattr(self, name, self._X_rows[k])
        rows = self._X_rows
        d = self.__dict__
        st = self.amp_state
        if (d["theta_m"] is rows[0] and d["omega_m"] is rows[1] and d["theta_l"] is rows[2]
                and d["omega_l"] is rows[3] and d["i"] is rows[4] and d["tach_state"] is rows[5]
                and st.thermal is rows[6] and st.sat_time is rows[7] and st.fault.dtype == np.bool_
                and st.cause.dtype == np.int64 and st.saturated.dtype == np.bool_):
            return X  # the usual case: nothing replaced (AmpState's arrays are always contiguous)
        for k, name in enumerate(self._STATE):
            if d[name] is not rows[k]:
                rows[k][:] = d[name]
                d[name] = rows[k]
        st = self.amp_state
        if st.thermal is not rows[6]:
            rows[6][:] = st.thermal
            st.thermal = rows[6]
        if st.sat_time is not rows[7]:
            rows[7][:] = st.sat_time
            st.sat_time = rows[7]
        if st.fault.dtype != np.bool_ or not st.fault.flags.c_contiguous:
            st.fault = np.ascontiguousarray(st.fault, dtype=bool)
        if st.cause.dtype != np.int64 or not st.cause.flags.c_contiguous:
            st.cause = np.ascontiguousarray(st.cause, dtype=np.int64)
        if st.saturated.dtype != np.bool_ or not st.saturated.flags.c_contiguous:
            st.saturated = np.ascontiguousarray(st.saturated, dtype=bool)
        return X

    def _step_compiled(self, cmd: PlantCommand, period_s: float, c: _StepConsts, n_sub: int,
                       n_old: int) -> PlantSensors:
        """:meth:`step_period` by the compiled kernel: the watchdog's events cut the period into
        segments here; the kernel integrates them and computes the sensors."""
        if c.P is None:
            c.kernel_arrays(self)
        assert c.P is not None
        n = self.n_joints
        h = c.h
        prev = self._prev_cmd
        wd = self.watchdog
        t0 = self.time_s
        new_enable = np.asarray(cmd.amp_enable, dtype=bool)
        reset_edge = np.ascontiguousarray(np.asarray(cmd.fault_reset, dtype=bool)
                                          & ~np.asarray(prev.fault_reset, dtype=bool))
        seg_start, seg_cmd, seg_enable = self._segments
        k_seg = 0
        held, held_k = prev.amp_enable, 0
        s_out = wd.expiry_substep(t0, h, n_sub)
        brakes = self.brakes
        brake_on = brakes.begin(t0, h) if self.has_brakes else brakes.present
        s = 0
        while True:
            changed = s == 0
            if s == n_old:
                wd.command(cmd.watchdog_line, new_enable, prev.amp_enable, t0 + s * h)
                s_out = wd.expiry_substep(t0, h, n_sub)  # an edge retriggers the pump
                held, held_k = new_enable, 1
                changed = True
                if self.has_brakes:
                    brakes.event(s, self._brake_lines(cmd, t0 + s * h))
            if s == s_out:
                if wd.expire(held):
                    changed = True
                if self.has_brakes:  # the pump feeds the brakes' lines too
                    brakes.event(s, np.zeros(n, dtype=bool))
            if s >= n_sub:
                break
            if changed:
                seg_start[k_seg] = s
                seg_cmd[k_seg] = held_k
                seg_enable[k_seg] = held
                seg_enable[k_seg] &= wd.cause == 0  # the enables less the watchdog's latches
                k_seg += 1
            nxt = n_sub
            if s < n_old < nxt:
                nxt = n_old
            if s < s_out < nxt:
                nxt = s_out
            s = nxt
        if self.has_brakes:
            brakes.finish(n_sub)
        cmd_f, cmd_b, noise = _k.kernel_inputs(prev, cmd, self._noise, n)
        X = self._bind_state()
        st = self.amp_state
        O = np.empty((_k.O_ROWS, n))
        B = np.empty((_k.B_ROWS, n), dtype=bool)
        E = np.empty((_k.E_ROWS, n), dtype=np.int64)
        x4, idx = c.kernel_buffers(n, n_sub)
        kernel = self._kernel_fn
        assert kernel is not None
        kernel(
            c.P, c.enci, c.F, h, n_sub, n_old, cmd_f, cmd_b, seg_start[:k_seg], seg_cmd[:k_seg],
            seg_enable[:k_seg], reset_edge, X, st.fault, st.cause, st.saturated, noise, self._held_v, x4, O, B, E, idx,
            brake_on, brakes.flips,
        )
        self.at_stop = B[_k.B_AT_STOP]
        self._prev_cmd = cmd.copy()  # callers may mutate their command in place
        self.time_s += period_s
        events = []
        cache = _EVENTS
        counts, illegal, phase, nidx = E.tolist()
        for j in range(n):
            k = nidx[j]
            if k:
                if k > idx.shape[1]:
                    raise RuntimeError(f"plant kernel: {k} index pulses in one period (room for {idx.shape[1]})")
                events.append(QuadratureEvents(counts=counts[j], illegal=illegal[j],
                                               index_offsets=tuple(idx[j, :k].tolist()), phase=phase[j]))
                continue
            key = (counts[j], illegal[j], phase[j])
            ev = cache.get(key)
            if ev is None:  # QuadratureEvents is frozen: equal events can be one object
                if len(cache) > 4096:
                    cache.clear()
                ev = cache[key] = QuadratureEvents(counts=key[0], illegal=key[1], phase=key[2])
            events.append(ev)
        return _k.kernel_sensors(PlantSensors, O, B, events, self.time_s, n, wd.effective(new_enable), st.cause, wd,
                                 brakes.engaged)

    def _drive(self, cmd: PlantCommand) -> AmpDrive:
        """The drive of ``cmd`` as the output stages obey it (watchdog-latched amplifiers off)."""
        return prepare_drive(
            self.amp, cmd.amp_command_v, self.watchdog.effective(cmd.amp_enable), cmd.pwm_duty,
            cmd.pwm_direction, cmd.brake
        )

    # ---- amplifier side's state (the plant node reports it) ------------------------------
    def amplifier_enabled(self) -> np.ndarray:
        """Per joint: the output stage is on under the command in force (its enable line high,
        not latched off by the enable watchdog, no latched fault)."""
        return self.watchdog.effective(self._prev_cmd.amp_enable) & ~self.amp_state.fault

    def amplifier_watchdog_cause(self) -> np.ndarray:
        """Per joint: why the enable watchdog latched the amplifier off (``WATCHDOG_*`` bits)."""
        return self.watchdog.cause.copy()

    def hold_amplifiers_off(self, cause: int) -> np.ndarray:
        """Latch every amplifier enabled now off for ``cause`` (an amplifier-side watchdog outside
        simulated time: the plant node's command timeout); re-armed like a watchdog trip. The
        holding brakes engage at once (:meth:`HoldingBrakes.hold`): the wall-clock time the
        timeout took exceeds their engage delay. Returns the joints this latched."""
        self.brakes.hold()
        return self.watchdog.hold_off(self._prev_cmd.amp_enable, cause)

    def brakes_engaged(self) -> np.ndarray:
        """Per joint: the holding brake's armature holds now (False where a joint has none)."""
        return self.brakes.engaged.copy()

    def _brake_lines(self, cmd: PlantCommand, t_s: float) -> np.ndarray:
        """The brake lines as the brakes see them at ``t_s``: the command's lines, all low while the
        enable watchdog's pump is out, and low for an amplifier the watchdog latched off (its brake
        holds until the amplifier is re-armed)."""
        wd = self.watchdog
        if not wd.alive(t_s):
            return np.zeros(self.n_joints, dtype=bool)
        return np.asarray(cmd.holding_brake, dtype=bool) & (wd.cause == 0)

    def _sense(self, x4: np.ndarray, h: float, c: _StepConsts, switching: np.ndarray) -> PlantSensors:
        th_j = self.joint_angle()
        w_j = self.joint_speed()
        pot_v = self.pot.volts(th_j) + self.pot.noise * self._noise["pot"].draw()
        tach_v = np.where(
            self.tach.present,
            self.tach_state + self.tach.offset + self.tach.noise * self._noise["tach"].draw(),
            0.0,
        )
        if self._sensor_faults:  # injected: the held wiper / tach volts replace the sensor's output
            pot_v = np.where(np.isnan(self._pot_held_v), pot_v, self._pot_held_v)
            tach_v = np.where(np.isnan(self._tach_held_v), tach_v, self._tach_held_v)
        imon_v = self.amp.monitor_volts(self.i) + self.amp.monitor_noise * self._noise["imon"].draw()
        events = encoder_events(x4, h, self.enc_sample_hz, self.enc_counts_per_rev, self.enc_index_phase)
        truth = {
            "time_s": np.full(self.n_joints, self.time_s),
            "theta_joint": th_j,
            "omega_joint": w_j,
            "theta_motor": self.theta_m.copy(),
            "omega_motor": self.omega_m.copy(),
            "current_a": self.i.copy(),
            "motor_torque_nm": self.Kt * self.i,
            "friction_torque_nm": c.stick_slip.friction_torque(),
            "stuck": self.omega_m == 0.0,
            "at_stop": self.at_stop.copy(),
            "amp_thermal": self.amp_state.thermal.copy(),
            "amp_fault_cause": self.amp_state.cause.copy(),
            "amp_enabled": self.amplifier_enabled(),
            "amp_watchdog_cause": self.amplifier_watchdog_cause(),
            "amp_watchdog_tripped": self.watchdog.latched,
            "encoder_x4": x4[-1].copy(),
            "brake_engaged": self.brakes.engaged.copy(),
        }
        return PlantSensors(
            pot_v=pot_v,
            tach_v=tach_v,
            imon_v=imon_v,
            amp_fault=self.amp_state.fault.copy(),
            encoder=events,
            switching=switching,
            switching_noise_v=np.where(switching, self.hb_switching_noise, 0.0),
            truth=truth,
        )
