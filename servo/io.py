"""Joint I/O through the drivers: the servo loop's only window on the rig.

:class:`JointIO` opens one driver per board named in the rig's ``[crate]`` table (base
addresses and spaces come from there, for emulated and real crates alike) and, once per tick,

* reads every sensor it needs with one ADC sequencer scan per board and one latched read of
  each quadrature decoder, and the PIO ports for amplifier fault lines;
* converts volts and counts to SI with each joint's nominal scaling (``SensorScaling``) and
  the loaded calibration (piecewise-linear potentiometer tables);
* writes all amplifier commands of a DAC board with one simultaneous update strobe;
* while the amplifiers are enabled, toggles the rig's enable-watchdog line (``[rig.watchdog]``,
  a charge pump on the amplifier side) once per torque write, i.e. once per tick: one PIO
  write. A controller that is killed or hangs stops toggling, and the amplifiers drop their
  enables (and the holding brakes' lines) on their own;
* drives the joints' holding-brake lines (``[joint.wiring] holding_brake``; energised =
  released): after an enable a brake's line rises only with the first torque write, after the
  DAC strobe, so the amplifier carries the joint's load before the brake lets go (it releases
  its release delay later); every stop drops the lines with the enables and reads them back.

It imports ``hal`` only: it cannot tell an emulated crate from real hardware.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any, ClassVar, Protocol

import numpy as np

from hal.adc_dac.adc import AdcDriver
from hal.adc_dac.calibration import Calibration
from hal.adc_dac.conversions import DAC_LSB_V, DAC_V_MAX, DAC_V_MIN
from hal.adc_dac.dac import DacDriver
from hal.amplifiers import duty_for_current
from hal.board_types import BOARD_TYPES, board_role
from hal.lanes import LaneSet
from hal.pio.pio import PioDriver, PwmRangeError
from hal.quadrature.quad import QuadratureDriver, QuadratureError
from hal.vme.bus import VmeBus
from servo.interrupts import INTERRUPTS, SignalsDeferred
from servo.rig import DIGITAL_OUTPUTS, WATCHDOG_NET, RigSpec


class CalibrationEntry(Protocol):
    """One measured entry of a joint (``values``: the procedure's figures, SI units)."""

    @property
    def values(self) -> Mapping[str, Any]: ...


class CalibrationSource(Protocol):
    """The calibration data the drivers apply: per ADC/DAC board a per-channel offset and gain,
    per joint the measured ``pot`` table (``volts``, ``angles_rad``), ``encoder``
    (``counts_per_joint_rev``) and ``amplifier`` (``gain_a_per_v``, ``offset_a``). Where it comes
    from (a calibration file, a procedure in progress) is the application's business
    (``vmehil.calibration.store``)."""

    def board_calibration(self, board: str) -> Calibration | None: ...

    def joint_entry(self, joint: str, procedure: str) -> CalibrationEntry | None: ...


@dataclass
class SensorScaling:
    """Nominal (datasheet) scaling of one joint's sensors and actuator, SI units (on a rig:
    :func:`servo.nominal.nominal_scaling` from ``[joint.servo.nominal]``).

    Attributes:
        pot_v_per_rad: potentiometer gradient (V/rad of joint angle).
        pot_zero_v: pot volts at joint angle 0.
        tach_v_per_rad_s: tachometer gradient (V per rad/s of joint velocity); 0 = no tach.
        encoder_counts_per_rev: decoder x4 counts per JOINT revolution (lines·4·ratio).
        ratio: gear ratio N; kt_nm_per_a: motor torque constant.
        amp_gain_a_per_v: transconductance amplifier gain (A/V), amp_offset_a: its output
            current at 0 V command (A); monitor_v_per_a: current monitor.
        current_limit_a: amplifier current limit.
        supply_v, resistance_ohm, ke_v_s_per_rad: H-bridge voltage command model.
        pwm_period_s: H-bridge PWM period programmed into the PIO timer.
    """

    pot_v_per_rad: float = 1.0
    pot_zero_v: float = 0.0
    tach_v_per_rad_s: float = 0.0
    encoder_counts_per_rev: float = 0.0
    ratio: float = 1.0
    kt_nm_per_a: float = 1.0
    amp_gain_a_per_v: float = 1.0
    amp_offset_a: float = 0.0
    monitor_v_per_a: float = 1.0
    current_limit_a: float = 1.0
    supply_v: float = 24.0
    resistance_ohm: float = 1.0
    ke_v_s_per_rad: float = 0.0
    pwm_period_s: float = 50e-6

    #: bumped by every attribute write of any instance (not a field): :class:`JointIO` keeps the
    #: scalings as per-joint arrays for its per-tick conversions and rebuilds them when it moves
    generation: ClassVar[int] = 0

    def __setattr__(self, name: str, value: Any) -> None:
        object.__setattr__(self, name, value)
        SensorScaling.generation += 1


@dataclass
class Measurement:
    """One tick's sensor readings in SI units (arrays over joints; NaN where not wired)."""

    theta_pot: np.ndarray
    theta_enc: np.ndarray
    omega_tach: np.ndarray
    omega_enc: np.ndarray
    current: np.ndarray
    pot_v: np.ndarray
    fault: np.ndarray
    theta: np.ndarray = field(default_factory=lambda: np.zeros(0))
    omega: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: per joint: its decoder flagged an illegal transition (A and B changed in one decoder
    #: sample: counts were lost) since the previous read; the flag is cleared after each read
    encoder_illegal: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    #: per joint: the decoder's unwrapped count as the driver read it (NaN where not wired)
    encoder_counts: np.ndarray = field(default_factory=lambda: np.zeros(0))


@dataclass(frozen=True)
class SensorResolution:
    """Per joint (arrays): the size of one step of each wired sensor and of the amplifier command,
    from the nominal scaling (SI units: one ADC code, one x4 encoder count, one DAC code); NaN
    where the sensor is not wired. The watchdog's tolerances are multiples of these."""

    pot_rad: np.ndarray
    encoder_rad: np.ndarray
    tach_rad_s: np.ndarray
    monitor_a: np.ndarray
    command_a: np.ndarray  #: linear amplifiers: one DAC code of command; NaN for H-bridges
    current_limit_a: np.ndarray
    linear: np.ndarray  #: bool: a linear (transconductance) amplifier, else an H-bridge


class PotCalibration:
    """Piecewise-linear pot volts → joint angle (the paper's nine points, eight segments)."""

    def __init__(self, volts: list[float], angles_rad: list[float]) -> None:
        v = np.asarray(volts, float)
        a = np.asarray(angles_rad, float)
        if v.shape != a.shape or v.size < 2:
            raise ValueError("a pot calibration needs matching volts and angles, at least two points")
        order = np.argsort(v)
        self.volts, self.angles = v[order], a[order]
        if np.any(np.diff(self.volts) <= 0):
            raise ValueError("pot calibration volts must be distinct")

    def angle(self, volts: float) -> float:
        """Interpolate inside the table; extrapolate the end segments linearly outside it."""
        v, a = self.volts, self.angles
        if volts <= v[0]:
            return float(a[0] + (volts - v[0]) * (a[1] - a[0]) / (v[1] - v[0]))
        if volts >= v[-1]:
            return float(a[-1] + (volts - v[-1]) * (a[-1] - a[-2]) / (v[-1] - v[-2]))
        return float(np.interp(volts, v, a))

    def angles_of(self, volts: np.ndarray) -> np.ndarray:
        """:meth:`angle` of each of ``volts`` (the same operations elementwise: the same numbers)."""
        v, a = self.volts, self.angles
        x = np.asarray(volts, float)
        low = a[0] + (x - v[0]) * (a[1] - a[0]) / (v[1] - v[0])
        high = a[-1] + (x - v[-1]) * (a[-1] - a[-2]) / (v[-1] - v[-2])
        return np.where(x <= v[0], low, np.where(x >= v[-1], high, np.interp(x, v, a)))


def _not_in_lanes(name: str, *args: Any, **kwargs: Any) -> Any:
    raise NotImplementedError(f"JointIO.{name} cannot run in lanes (batched lockstep)")


class JointIO:
    """All joints' sensors and amplifiers through the board drivers.

    ``calibration``: the calibration data to apply at start (:class:`CalibrationSource`, e.g.
    a store loaded by ``vmehil.calibration.store.load_store``), or ``None`` (nominal values).
    """

    #: how often :meth:`safe_stop` makes one write (or its read-back) that an interrupt cut short
    STOP_STEP_ATTEMPTS = 5

    def __init__(self, bus: VmeBus, rig: RigSpec, scaling: list[SensorScaling],
                 calibration: CalibrationSource | None = None) -> None:
        self.bus = bus
        self.rig = rig
        self.n = rig.n_joints
        self.scaling = scaling
        self.period_s = rig.period_s
        boards = {b.get_str("name"): b for b in rig.table.table("crate").tables("board", [])}
        self._types = {name: b.get_str("type") for name, b in boards.items()}

        def loc(name: str) -> tuple[int, str]:
            if name not in boards:
                raise ValueError(f"rig {rig.name}: wiring names board {name!r}, which is not in [crate]")
            return boards[name].get_int("base"), boards[name].get_str("space")

        self.adc: dict[str, AdcDriver] = {}
        self.dac: dict[str, DacDriver] = {}
        self.pio: dict[str, PioDriver] = {}
        self.quad: dict[str, QuadratureDriver] = {}
        pio_lines: dict[str, dict[str, str]] = {}
        quad_cpr: dict[str, dict[int, float]] = {}
        #: each board's role (hal.board_types): a board type of role "adc" is wired as an ADC
        self._roles = {name: board_role(kind) for name, kind in self._types.items()}
        for j in rig.joints:
            for sig, pin in j.wiring.items():
                kind = self._roles.get(pin.board)
                if pin.board not in self._types:
                    loc(pin.board)
                if kind == "pio":
                    pio_lines.setdefault(pin.board, {})[j.net(sig)] = str(pin.channel)
                elif kind == "quad":
                    quad_cpr.setdefault(pin.board, {})[pin.index] = scaling[j.index].encoder_counts_per_rev
        wd = rig.watchdog
        if wd is not None:
            pio_lines.setdefault(wd.line.board, {})[WATCHDOG_NET] = str(wd.line.channel)
        for name, type_name in self._types.items():
            base, space = loc(name)
            used = any(p.board == name for j in rig.joints for p in j.wiring.values()) or (
                wd is not None and wd.line.board == name)
            if not used:
                continue
            kind = self._roles[name]
            if kind not in ("adc", "dac", "pio", "quad"):
                continue  # wired boards are of these roles (servo.rig checks the wiring)
            # the board type's driver, by its role's factory signature (hal.board_types)
            factory = BOARD_TYPES[type_name].load_driver()
            if kind == "adc":
                self.adc[name] = factory(bus, base, space=space)
            elif kind == "dac":
                self.dac[name] = factory(bus, base, space=space, clamp=True)
            elif kind == "pio":
                lines = {k: v for k, v in pio_lines.get(name, {}).items() if v != "PWM"}
                # [rig.readback]: outputs wired back into inputs (only boards whose driver takes it)
                readback = {str(o.channel): str(i.channel) for o, i in rig.readback.items() if o.board == name}
                extra = {"loopback": readback} if readback else {}
                self.pio[name] = factory(bus, base, space=space, lines=lines, **extra)
            else:
                cpr = quad_cpr[name]
                self.quad[name] = factory(bus, base, space=space, counts_per_rev=cpr,
                                          channels=sorted(cpr), errors="report")
        # Configure PIO output lines (enables, resets, direction, brakes, watchdog) low = safe
        # (a holding brake's line low: the brake holds).
        for pname, drv in self.pio.items():
            outs = [j.net(s) for j in rig.joints for s, p in j.wiring.items()
                    if p.board == pname and s in DIGITAL_OUTPUTS]
            if wd is not None and wd.line.board == pname:
                outs.append(WATCHDOG_NET)
            drv.configure(outputs=outs, initial={o: False for o in outs})
        #: the holding brakes' lines, (joint index, PIO board, net), in joint order
        self._holding_brakes = [(j.index, j.wiring["holding_brake"].board, j.net("holding_brake"))
                                for j in rig.joints if "holding_brake" in j.wiring]
        #: the rig has holding brakes (a stop then leaves gravity-loaded joints held)
        self.has_holding_brakes = bool(self._holding_brakes)
        #: the brakes' lines are to rise with the next torque write (set by enabling)
        self._release_pending = False
        #: per joint: its holding brake's line is high (energised: released or releasing)
        self.brake_released = np.zeros(self.n, dtype=bool)
        #: per joint of the rig its place in the per-joint arrays (in lanes: that joint of every lane)
        self._joint_slot: list[int | slice] = list(range(self.n))
        #: per joint: it has a holding brake
        self.holding_brake_mask = np.zeros(self.n, dtype=bool)
        for i, _, _ in self._holding_brakes:
            self.holding_brake_mask[i] = True
        #: per joint the torque (N·m) the last torque write commanded (kept through a stop)
        self.last_torque_nm = np.zeros(self.n)
        #: the PIO driver of the watchdog line (None: no watchdog), its level, and whether it toggles
        self._watchdog_pio = self.pio[wd.line.board] if wd is not None else None
        self._watchdog_level = False
        self.watchdog_running = False
        for j in rig.joints:
            if "pwm" in j.wiring:
                try:
                    self.pio[j.wiring["pwm"].board].set_pwm_period(scaling[j.index].pwm_period_s)
                except PwmRangeError as e:
                    raise j.servo.error("nominal.pwm_period_s", f"a period the PIO's PWM timer can take ({e})",
                                        scaling[j.index].pwm_period_s) from None
        # ADC scan plans: per board, the last channel to convert.
        self._adc_last = {name: max(p.index for j in rig.joints for p in j.wiring.values() if p.board == name)
                          for name in self.adc}
        self.pot_cal: dict[int, PotCalibration] = {}
        self.position_source = [j.servo.get_str("position", "pot", choices=("pot", "encoder")) for j in rig.joints]
        self.velocity_source = [j.servo.get_str("velocity", "tach", choices=("tach", "encoder")) for j in rig.joints]
        self._position_from_pot = np.array([p == "pot" for p in self.position_source])
        self._velocity_from_tach = np.array([v == "tach" for v in self.velocity_source])
        for j in rig.joints:
            for src, sig in ((self.position_source[j.index], "pot"), (self.velocity_source[j.index], "tach")):
                need = "encoder" if src == "encoder" else sig
                if need not in j.wiring:
                    raise j.servo.error("position" if sig == "pot" else "velocity",
                                        f"a sensor wired in [joint.wiring] ('{need}' is not wired)", src)
        #: per joint: it can be homed to its encoder's index (a pot to choose the index, an encoder,
        #: and the loop closed on the pot; docs/motion-safety.md, "Homing"). The others — a
        #: continuous joint (no pot: melmalec's crawler) — are exempt
        self.homeable = np.array(["pot" in j.wiring and "encoder" in j.wiring and self.position_source[j.index] == "pot"
                                  for j in rig.joints], dtype=bool)
        #: per joint: its encoder is homed (its position is the joint's absolute angle) this session
        self.homed = np.zeros(self.n, dtype=bool)
        self.last_dac_volts = np.zeros(self.n)
        #: the current (A) the drivers last commanded per joint (what the current monitor should read)
        self.last_current_a = np.zeros(self.n)
        #: bumped whenever a calibration changes how readings convert (pot tables, encoder
        #: counts): the watchdog then re-references its cross-checks
        self.calibration_generation = 0
        # Fault lines as (joint, PIO board, port, bit): read() fetches each port once per tick.
        self._fault_lines = []
        for j in rig.joints:
            if "amp_fault" in j.wiring:
                board = j.wiring["amp_fault"].board
                port, bit = self.pio[board].resolve(j.net("amp_fault"))
                self._fault_lines.append((j.index, board, port, bit))
        # Per-tick plans, resolved once from the wiring (see _build_plans / _scaling_arrays).
        self._build_plans()
        self._scaling_key: tuple[int, int] | None = None
        self.calibration: CalibrationSource | None = None
        #: the lanes of a batch (:meth:`from_lanes`); ``None``: one instance. In lanes ``n`` counts
        #: every lane's joints (lane-major), ``lane_n`` one lane's, ``lane_size`` the lanes
        self.lanes: LaneSet | None = None
        self.lane_n = self.n
        self.lane_size = 1
        self.lane_scaling = [scaling]
        #: in lanes: per calibrated pot (flat joint index, its table); per H-bridge joint (joint, flat
        #: indices, R, Ke, N, supply over the lanes); per lane what the last stop's read-back could not confirm
        self._lane_pot_cal: list[tuple[int, PotCalibration]] = []
        self._lane_pot_tables: list[tuple[np.ndarray, PotCalibration]] = []
        self._lane_hbridge: list[tuple[Any, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self.lane_stop_failures: list[list[str]] = [[]]
        if calibration is not None:
            self.apply_calibration(calibration)

    # --- lanes (batched lockstep) -------------------------------------------------------------
    @classmethod
    def from_lanes(cls, ios: Sequence[JointIO], lanes: LaneSet, *, adc: Mapping[str, Any], dac: Mapping[str, Any],
                   pio: Mapping[str, Any], quad: Mapping[str, Any]) -> JointIO:
        """The joint I/O of B lanes (batched lockstep, :mod:`hal.lanes`): ``ios`` (one per lane, as
        its scalar run built it) over the lane drivers (board name → the stacked driver of that
        board, :meth:`from_lanes` of the driver classes). Per-joint arrays are flat and lane-major,
        B·n joints (joint j of lane b at ``b*n + j``); a driver takes and gives per channel a lane
        value (B,) (an ADC scan (k, B)). :meth:`read` and :meth:`write_torque` are the lane ones,
        selected here once: the same conversions elementwise, so every lane's numbers are its scalar
        run's bit for bit. Where a scalar read makes a bus cycle the others do not (a decoder's
        ILLEGAL flag cleared, a home lost), that lane is ejected. Calibration, homing and source
        changes after stacking are not followed (the arrays are taken now)."""
        first = ios[0]
        size = len(ios)
        n = first.n
        if size != lanes.size:
            raise ValueError(f"{size} joint I/Os for {lanes.size} lanes")
        for io in ios:
            io._scaling_arrays()
            if io.rig.name != first.rig.name or io.n != n or io.position_source != first.position_source \
                    or io.velocity_source != first.velocity_source or io.calibration_generation != \
                    first.calibration_generation or (io._release_pending, io.watchdog_running, io._watchdog_level) != \
                    (first._release_pending, first.watchdog_running, first._watchdog_level):
                raise NotImplementedError("lanes' joint I/Os differ in rig, sources or state: they cannot run as lanes")
            tach = [(b, js.tolist(), chs.tolist()) for b, js, chs in io._tach_read]
            if tach != [(b, js.tolist(), chs.tolist()) for b, js, chs in first._tach_read]:
                raise NotImplementedError("lanes differ in which tachometers are read: they cannot run as lanes")
        for role, have, given in (("ADC", first.adc, adc), ("DAC", first.dac, dac), ("PIO", first.pio, pio),
                                  ("decoder", first.quad, quad)):
            if set(have) != set(given):
                raise ValueError(f"lane {role} drivers for {sorted(given)}, the rig wires {sorted(have)}")

        def cat(name: str) -> np.ndarray:
            return np.concatenate([np.asarray(getattr(io, name)) for io in ios])

        obj = cls.__new__(cls)
        obj.__dict__.update(first.__dict__)  # the wiring and its plans (alike in every lane), then per lane:
        obj.adc, obj.dac, obj.pio, obj.quad = dict(adc), dict(dac), dict(pio), dict(quad)
        obj._watchdog_pio = obj.pio[first.rig.watchdog.line.board] if first.rig.watchdog is not None else None
        obj.n = n * size
        obj.lanes = lanes
        obj.lane_n = n
        obj.lane_size = size
        for name in ("_position_from_pot", "_velocity_from_tach", "_has_pot", "homeable", "homed", "last_dac_volts",
                     "last_current_a", "brake_released", "holding_brake_mask", "last_torque_nm", "_pot_zero_v",
                     "_pot_v_per_rad", "_tach_v_per_rad_s", "_monitor_v_per_a", "_torque_per_a", "_limit_a",
                     "_amp_gain", "_amp_offset"):
            setattr(obj, name, cat(name))
        obj.position_source = list(first.position_source)
        obj.velocity_source = list(first.velocity_source)
        obj._linear_idx = (np.arange(size)[:, None] * n + first._linear_idx[None, :]).reshape(-1)
        obj.lane_scaling = [io.scaling for io in ios]
        obj._lane_pot_cal, obj._lane_pot_tables = [], []
        for i in sorted({i for io in ios for i in io.pot_cal}):
            cals = [io.pot_cal.get(i) for io in ios]
            first_cal = cals[0]
            if first_cal is not None and all(c is not None and np.array_equal(c.volts, first_cal.volts)
                                             and np.array_equal(c.angles, first_cal.angles) for c in cals):
                obj._lane_pot_tables.append((np.arange(size) * n + i, first_cal))  # one table: every lane at once
            else:
                obj._lane_pot_cal += [(b * n + i, c) for b, c in enumerate(cals) if c is not None]
        obj._lane_hbridge = []
        for j in first._hbridge_joints:
            r_ohm, ke, ratio, supply = (np.array([float(getattr(io.scaling[j.index], f)) for io in ios])
                                        for f in ("resistance_ohm", "ke_v_s_per_rad", "ratio", "supply_v"))
            obj._lane_hbridge.append((j, np.arange(size) * n + j.index, r_ohm, ke, ratio, supply))
        obj.lane_stop_failures = [[] for _ in range(size)]
        obj._scaling_key = None
        d = obj.__dict__  # the lane methods, chosen once (the scalar ones are untouched)
        d["read"], d["write_torque"] = obj._read_lanes, obj._write_torque_lanes
        obj._joint_slot = [slice(j, None, n) for j in range(n)]
        d["_stop_outputs"], d["verify_stopped"] = obj._stop_outputs_lanes, obj._verify_stopped_lanes
        for name in ("write_command_volts", "apply_calibration", "home_encoder", "set_sources", "set_pot_calibration"):
            d[name] = partial(_not_in_lanes, name)
        return obj

    def _lane_rows(self, x: np.ndarray) -> np.ndarray:
        """A flat lane-major per-joint array as (B, n) rows (a view)."""
        return x.reshape(self.lane_size, self.lane_n)

    def _read_lanes(self) -> Measurement:
        """:meth:`read` in lanes."""
        B, n = self.lane_size, self.lane_n
        N = B * n
        block = np.full((6, N), np.nan)
        theta_pot, theta_enc, omega_tach, omega_enc, current, pot_v = block
        rows = self._lane_rows
        fault = np.zeros(N, bool)
        volts = {}
        for name, drv in self.adc.items():
            v = np.asarray(drv.scan(self._adc_last[name]), float)
            volts[name] = v if v.ndim == 2 else np.repeat(v[:, None], B, axis=1)  # (k, B)
        readings = {name: drv.update(self.period_s) for name, drv in self.quad.items()}
        for board, js, chs in self._pot_plan:
            rows(pot_v)[:, js] = volts[board][chs].T
        has = self._has_pot
        theta_pot[has] = (pot_v[has] - self._pot_zero_v[has]) / self._pot_v_per_rad[has]
        for idx, cal in self._lane_pot_tables:
            if has[idx[0]]:
                theta_pot[idx] = cal.angles_of(pot_v[idx])
        for i, cal in self._lane_pot_cal:
            if has[i]:
                theta_pot[i] = cal.angle(float(pot_v[i]))
        tach = rows(self._tach_v_per_rad_s)
        for board, js, chs in self._tach_read:
            rows(omega_tach)[:, js] = volts[board][chs].T / tach[:, js]
        mon = rows(self._monitor_v_per_a)
        for board, js, chs in self._imon_plan:
            rows(current)[:, js] = volts[board][chs].T / mon[:, js]
        illegal = np.zeros(N, bool)
        counts = np.full(N, np.nan)
        lanes = self.lanes
        assert lanes is not None
        for board, js, chans in self._enc_plan:
            r = readings[board]
            for i, c in zip(js.tolist(), chans, strict=True):
                x = r[c]
                rows(counts)[:, i] = x.counts
                rows(theta_enc)[:, i] = x.position_rad
                rows(omega_enc)[:, i] = x.velocity_rad_s
                ill = x.status.illegal
                if type(ill) is not np.ndarray and not ill:
                    continue  # no lane flagged it (the usual case)
                flag = np.broadcast_to(np.asarray(ill, bool), (B,))
                if np.count_nonzero(flag):  # its scalar run clears the flag (a bus cycle the other lanes do not make)
                    rows(illegal)[:, i] = flag
                    lanes.eject(flag, f"encoder_illegal ({self.rig.joints[i].name}): the decoder flagged an "
                                "illegal transition (its scalar run clears the flag)")
        for board, port, js, bits in self._fault_plan:
            value = np.asarray(self.pio[board].read_port(port))
            rows(fault)[:, js] = (value[..., None] >> bits) & 1
        m = Measurement(theta_pot, theta_enc, omega_tach, omega_enc, current, pot_v, fault, encoder_illegal=illegal,
                        encoder_counts=counts)
        m.theta = np.where(self._position_from_pot, theta_pot, theta_enc)
        m.omega = np.where(self._velocity_from_tach, omega_tach, omega_enc)
        return m

    def _write_torque_lanes(self, torque_nm: np.ndarray, omega: np.ndarray | None = None) -> np.ndarray:
        """:meth:`write_torque` in lanes: each driver gets per channel the lanes' values (B,)."""
        tau = np.asarray(torque_nm, dtype=float)
        limit = self._limit_a
        amps = tau / self._torque_per_a
        amps = np.where(amps < limit, amps, limit)
        amps = np.where(amps > -limit, amps, -limit)
        current = np.zeros(self.n)
        for j, idx, r_ohm, ke, ratio, supply in self._lane_hbridge:
            a = amps[idx]
            if omega is None:
                w_m = np.zeros(idx.shape)
            else:
                w = np.asarray(omega, float)[idx]
                w_m = np.where(np.isfinite(w), w * ratio, 0.0)
            # hal.amplifiers.duty_for_current, elementwise: max(-1, min(1, (R·i + Ke·ω)/V)) as Python's
            # min/max compare (min(1.0, x) is x only when x < 1.0)
            x = (r_ohm * a + ke * w_m) / supply
            x = np.where(x < 1.0, x, 1.0)
            self._set_hbridge(j, np.where(x > -1.0, x, -1.0))
            current[idx] = a
        lin = self._linear_idx
        if lin.size:
            gain, off = self._amp_gain[lin], self._amp_offset[lin]
            volts = (amps[lin] - off) / gain
            volts = np.where(volts > DAC_V_MIN, volts, DAC_V_MIN)
            volts = np.where(volts < DAC_V_MAX, volts, DAC_V_MAX)
            self.last_dac_volts[lin] = volts
            current[lin] = volts * gain + off
            dv = self._lane_rows(self.last_dac_volts)
            for board, js, chans in self._dac_plan:
                cmds: dict[int, Any] = {ch: dv[:, j].copy() for j, ch in zip(js.tolist(), chans, strict=True)}
                self.dac[board].write_many(cmds, update=True)
        self.last_current_a[:] = current
        self.last_torque_nm[:] = np.where(np.isfinite(tau), tau, 0.0)
        if self._release_pending:
            self.release_brakes()
        if self.watchdog_running:
            self._toggle_watchdog()
        return current

    def _stop_outputs_lanes(self, held: list[BaseException]) -> list[str]:
        """:meth:`_stop_outputs` in lanes: the same writes, every lane alike; the read-back per lane
        (:attr:`lane_stop_failures`; returned: what fails in any live lane)."""
        failures = self._stop_writes(held)
        verified = self._read_back(held)
        self.lane_stop_failures = [failures + [f for f in lane if f not in failures]
                                   for lane in self.lane_stop_failures]
        return failures + [f for f in verified if f not in failures]

    def _verify_stopped_lanes(self) -> list[str]:
        """:meth:`verify_stopped` in lanes: each lane's problems in :attr:`lane_stop_failures`
        (a read that fails is every lane's); returns those of any live lane, each once."""
        B = self.lane_size
        per_lane: list[list[str]] = [[] for _ in range(B)]

        def problem(cond: Any, text: str) -> None:
            for b in np.flatnonzero(np.broadcast_to(np.asarray(cond, bool), (B,))).tolist():
                per_lane[b].append(text)

        for i, board, net in self._holding_brakes:
            pin = self.rig.joints[i].wiring["holding_brake"]
            try:
                pio = self.pio[board]
                port, bit = pio.resolve(net)
                high = np.asarray(pio.get_line(net), bool) | (np.asarray(pio.read_pins(port)) >> bit & 1 != 0)
                problem(high, f"{self.rig.joints[i].name}: holding brake {pin} still reads high (released)")
            except Exception as e:
                problem(True, f"{self.rig.joints[i].name}: holding brake {pin} cannot be read back ({e})")
        for j in self.rig.joints:
            w = j.wiring
            try:
                if "amp_enable" in w:
                    pio = self.pio[w["amp_enable"].board]
                    port, bit = pio.resolve(j.net("amp_enable"))
                    high = np.asarray(pio.get_line(j.net("amp_enable")), bool) | (
                        np.asarray(pio.read_pins(port)) >> bit & 1 != 0)
                    problem(high, f"{j.name}: amplifier enable {w['amp_enable']} still reads high")
            except Exception as e:
                problem(True, f"{j.name}: amplifier enable {w['amp_enable']} cannot be read back ({e})")
            try:
                if "amp_command" in w:
                    pin = w["amp_command"]
                    dac = self.dac[pin.board]
                    zero_code, _ = dac.code_for(pin.index, 0.0)
                    code = np.broadcast_to(np.asarray(dac.read_back_counts(pin.index)), (B,))
                    zero = np.broadcast_to(np.asarray(zero_code), (B,))
                    for b in np.flatnonzero(code != zero).tolist():
                        per_lane[b].append(f"{j.name}: DAC {pin} output code {int(code[b]):#05x}, not the 0 V code "
                                           f"{int(zero[b]):#05x}")
            except Exception as e:
                problem(True, f"{j.name}: DAC {w['amp_command']} cannot be read back ({e})")
            try:
                if "pwm" in w:
                    problem(np.asarray(self.pio[w["pwm"].board].pwm_duty()) != 0.0,
                            f"{j.name}: PWM {w['pwm']} still running")
            except Exception as e:
                problem(True, f"{j.name}: PWM {w['pwm']} cannot be read back ({e})")
        self.lane_stop_failures = per_lane
        alive = self.lanes.alive if self.lanes is not None else np.ones(B, bool)
        out: list[str] = []
        for b in np.flatnonzero(alive).tolist():
            out += [p for p in per_lane[b] if p not in out]
        return out

    # --- per-tick plans -----------------------------------------------------------------------
    def _build_plans(self) -> None:
        """Resolve the wiring once into index arrays, so a tick reads and converts every joint
        with a few array operations instead of looking up each joint's pins."""

        def by_board(sig: str) -> list[tuple[str, np.ndarray, np.ndarray]]:
            groups: dict[str, tuple[list[int], list[int]]] = {}
            for j in self.rig.joints:
                if sig in j.wiring:
                    pin = j.wiring[sig]
                    js, chs = groups.setdefault(pin.board, ([], []))
                    js.append(j.index)
                    chs.append(pin.index)
            return [(b, np.array(js, dtype=np.intp), np.array(chs, dtype=np.intp)) for b, (js, chs) in groups.items()]

        self._pot_plan = by_board("pot")
        self._tach_plan = by_board("tach")
        self._imon_plan = by_board("imon")
        self._has_pot = np.array(["pot" in j.wiring for j in self.rig.joints], dtype=bool)
        self._enc_plan = [(b, js, [int(c) for c in chs]) for b, js, chs in by_board("encoder")]
        # fault lines: each port read once per tick, in the order the joints first name it
        ports: dict[tuple[str, int], tuple[list[int], list[int]]] = {}
        for i, board, port, bit in self._fault_lines:
            js, bits = ports.setdefault((board, port), ([], []))
            js.append(i)
            bits.append(bit)
        self._fault_plan = [(board, port, np.array(js, dtype=np.intp), np.array(bits, dtype=np.int64))
                            for (board, port), (js, bits) in ports.items()]
        # actuators: linear amplifiers grouped per DAC board (joint order within a board, boards in
        # the order of their first joint), H-bridges in joint order
        linear = [j for j in self.rig.joints if j.amplifier == "linear"]
        dac_groups: dict[str, tuple[list[int], list[int]]] = {}
        for j in linear:
            pin = j.wiring["amp_command"]
            js, chs = dac_groups.setdefault(pin.board, ([], []))
            js.append(j.index)
            chs.append(pin.index)
        self._dac_plan = [(b, np.array(js, dtype=np.intp), [int(c) for c in chs])
                          for b, (js, chs) in dac_groups.items()]
        self._linear_idx = np.array([j.index for j in linear], dtype=np.intp)
        self._hbridge_joints = [j for j in self.rig.joints if j.amplifier != "linear"]

    def _scaling_arrays(self) -> None:
        """(Re)build the per-joint scaling arrays when a :class:`SensorScaling` changed."""
        key = (SensorScaling.generation, id(self.scaling))
        if key == self._scaling_key:
            return
        sc = self.scaling

        def col(name: str) -> np.ndarray:
            return np.array([float(getattr(s, name)) for s in sc], dtype=float)

        self._pot_zero_v = col("pot_zero_v")
        self._pot_v_per_rad = col("pot_v_per_rad")
        self._tach_v_per_rad_s = col("tach_v_per_rad_s")
        self._monitor_v_per_a = col("monitor_v_per_a")
        self._torque_per_a = np.array([s.ratio * s.kt_nm_per_a for s in sc], dtype=float)
        self._limit_a = col("current_limit_a")
        self._amp_gain = col("amp_gain_a_per_v")
        self._amp_offset = col("amp_offset_a")
        # a tach with a zero gradient is not read (as before: NaN)
        self._tach_read = [(b, js[self._tach_v_per_rad_s[js] != 0.0], chs[self._tach_v_per_rad_s[js] != 0.0])
                           for b, js, chs in self._tach_plan]
        self._scaling_key = key

    def set_sources(self, joint: int, position: str, velocity: str) -> None:
        """Choose where joint ``joint`` (0-based) takes its position (``"pot"``/``"encoder"``) and
        velocity (``"tach"``/``"encoder"``) from, e.g. for a procedure that needs the encoder."""
        if position not in ("pot", "encoder") or velocity not in ("tach", "encoder"):
            raise ValueError(f"position {position!r} / velocity {velocity!r}: expected pot|encoder and tach|encoder")
        self.position_source[joint], self.velocity_source[joint] = position, velocity
        self._position_from_pot[joint] = position == "pot"
        self._velocity_from_tach[joint] = velocity == "tach"

    # --- calibration ------------------------------------------------------------------------
    def apply_calibration(self, store: CalibrationSource) -> None:
        """Put a calibration in force: ADC/DAC per-channel offset and gain in the board drivers,
        pot tables, encoder counts per revolution, amplifier gain and offset. Entries the store
        lacks keep their nominal values."""
        drivers: list[tuple[str, AdcDriver | DacDriver]] = [*self.adc.items(), *self.dac.items()]
        for name, drv in drivers:
            cal = store.board_calibration(name)
            if cal is not None:
                drv.calibration = cal
        for j in self.rig.joints:
            s = self.scaling[j.index]
            pot = store.joint_entry(j.name, "pot")
            if pot is not None:
                self.set_pot_calibration(j.index, PotCalibration(pot.values["volts"], pot.values["angles_rad"]))
            enc = store.joint_entry(j.name, "encoder")
            if enc is not None and "encoder" in j.wiring:
                s.encoder_counts_per_rev = float(enc.values["counts_per_joint_rev"])
                pin = j.wiring["encoder"]
                self.quad[pin.board].counts_per_rev_x4[pin.index] = s.encoder_counts_per_rev
            amp = store.joint_entry(j.name, "amplifier")
            if amp is not None:
                s.amp_gain_a_per_v = float(amp.values["gain_a_per_v"])
                s.amp_offset_a = float(amp.values["offset_a"])
        self.calibration = store
        self.calibration_generation += 1

    # --- homing ----------------------------------------------------------------------------
    def encoder_channel(self, joint: int) -> tuple[QuadratureDriver, int]:
        """The decoder driver the loop reads joint ``joint``'s encoder with, and its channel."""
        j = self.rig.joints[joint]
        if "encoder" not in j.wiring:
            raise ValueError(f"{j.name} has no encoder wired")
        pin = j.wiring["encoder"]
        return self.quad[pin.board], pin.index

    def home_encoder(self, joint: int, index_angle_rad: float) -> int:
        """Home joint ``joint``'s encoder: the index its decoder captured (armed with
        ``arm_index``) is at joint angle ``index_angle_rad``, so its position reads the joint's
        absolute angle from now on (:attr:`homed`). Returns the index count. The watchdog's
        encoder/pot cross-check then compares the two absolutely (it re-references on the
        generation bump)."""
        drv, ch = self.encoder_channel(joint)
        idx = drv.home_at_index(ch, index_angle_rad)
        self.homed[joint] = True
        self.calibration_generation += 1
        return idx

    def _lose_home(self, board: str, channel: int) -> None:
        """The joint on decoder ``board``'s ``channel`` loses its home (its count is wrong)."""
        for j in self.rig.joints:
            pin = j.wiring.get("encoder")
            if pin is not None and pin.board == board and pin.index == channel:
                self.clear_home(j.index)

    def clear_home(self, joint: int) -> None:
        """Forget joint ``joint``'s home (its encoder reads relative again)."""
        if self.homed[joint]:
            self.homed[joint] = False
            self.calibration_generation += 1

    def set_pot_calibration(self, joint: int, cal: PotCalibration | None) -> None:
        if cal is None:
            self.pot_cal.pop(joint, None)
        else:
            self.pot_cal[joint] = cal
        self.calibration_generation += 1

    def resolution(self) -> SensorResolution:
        """One step of every wired sensor and of the amplifier commands (see :class:`SensorResolution`)."""
        nan = np.full(self.n, np.nan)
        pot, enc, tach, mon, cmd = nan.copy(), nan.copy(), nan.copy(), nan.copy(), nan.copy()
        limit = np.array([s.current_limit_a for s in self.scaling], float)
        linear = np.array([j.amplifier == "linear" for j in self.rig.joints])

        def lsb_v(pin) -> float:
            return self.adc[pin.board].lsb_v  # the driver's named conversion (its board's range)

        for j in self.rig.joints:
            i, s, w = j.index, self.scaling[j.index], j.wiring
            if "pot" in w:
                pot[i] = lsb_v(w["pot"]) / s.pot_v_per_rad
            if "encoder" in w and s.encoder_counts_per_rev:
                enc[i] = 2.0 * np.pi / s.encoder_counts_per_rev
            if "tach" in w and s.tach_v_per_rad_s:
                tach[i] = lsb_v(w["tach"]) / abs(s.tach_v_per_rad_s)
            if "imon" in w:
                mon[i] = lsb_v(w["imon"]) / s.monitor_v_per_a
            if linear[i]:
                cmd[i] = DAC_LSB_V * s.amp_gain_a_per_v
        return SensorResolution(pot, enc, tach, mon, cmd, limit, linear)

    def pot_angle(self, joint: int, volts: float) -> float:
        cal = self.pot_cal.get(joint)
        if cal is not None:
            return cal.angle(volts)
        s = self.scaling[joint]
        return (volts - s.pot_zero_v) / s.pot_v_per_rad

    # --- per tick ---------------------------------------------------------------------------
    def read(self) -> Measurement:
        """Read every wired sensor once (one scan per ADC, one latch per decoder)."""
        self._scaling_arrays()
        n = self.n
        block = np.full((6, n), np.nan)  # one allocation for the six per-joint readings
        theta_pot, theta_enc, omega_tach, omega_enc, current, pot_v = block
        fault = np.zeros(n, bool)
        volts = {name: drv.scan(self._adc_last[name]) for name, drv in self.adc.items()}
        readings = {}
        for name, drv in self.quad.items():
            try:
                readings[name] = drv.update(self.period_s)
            except QuadratureError as e:  # lost track or jumped: the count, and so any home, is wrong
                self._lose_home(name, e.channel)
                raise
        for board, js, chs in self._pot_plan:
            pot_v[js] = volts[board][chs]
        theta_pot[self._has_pot] = (pot_v[self._has_pot] - self._pot_zero_v[self._has_pot]) / \
            self._pot_v_per_rad[self._has_pot]
        for i, cal in self.pot_cal.items():  # calibrated joints: their piecewise-linear table
            if self._has_pot[i]:
                theta_pot[i] = cal.angle(float(pot_v[i]))
        for board, js, chs in self._tach_read:
            omega_tach[js] = volts[board][chs] / self._tach_v_per_rad_s[js]
        for board, js, chs in self._imon_plan:
            current[js] = volts[board][chs] / self._monitor_v_per_a[js]
        illegal = np.zeros(n, bool)
        counts = np.full(n, np.nan)
        for board, js, chans in self._enc_plan:
            r = readings[board]
            got = [r[c] for c in chans]
            counts[js] = [x.counts for x in got]
            theta_enc[js] = [x.position_rad for x in got]
            omega_enc[js] = [x.velocity_rad_s for x in got]
            for i, x in zip(js, got, strict=True):
                if x.status.illegal:  # sticky in the decoder: cleared, so that each read tells anew
                    illegal[i] = True
                    self.quad[board].clear_illegal(x.channel)
                    if self.homed[i]:  # counts were lost: the home no longer holds
                        self.clear_home(int(i))
        for board, port, js, bits in self._fault_plan:
            value = self.pio[board].read_port(port)  # DATA_x, as get_line reads
            fault[js] = (value >> bits) & 1
        m = Measurement(theta_pot, theta_enc, omega_tach, omega_enc, current, pot_v, fault, encoder_illegal=illegal,
                        encoder_counts=counts)
        m.theta = np.where(self._position_from_pot, theta_pot, theta_enc)
        m.omega = np.where(self._velocity_from_tach, omega_tach, omega_enc)
        return m

    def write_torque(self, torque_nm: np.ndarray, omega: np.ndarray | None = None) -> np.ndarray:
        """Command joint torques (N·m). Linear amps: DAC volts = τ/(N·Kt·gain), one strobe per
        DAC board. H-bridges: V = R·i + Ke·ω_motor as PWM duty. Returns the commanded current (A).

        The one torque-to-command conversion (the controller's output is torque; the drivers take
        amperes and volts), with the calibrated scaling. It runs over all joints as arrays and gives
        the same numbers, bit for bit, as i = τ/(N·Kt), :func:`~hal.amplifiers.clamp_current` and
        :func:`~hal.amplifiers.command_volts` joint by joint (the clamps are written as the same
        comparisons, so a NaN clamps to the limit as ``min``/``max`` do)."""
        self._scaling_arrays()
        tau = np.asarray(torque_nm, dtype=float)
        limit = self._limit_a
        amps = tau / self._torque_per_a
        amps = np.where(amps < limit, amps, limit)  # min(limit, amps)
        amps = np.where(amps > -limit, amps, -limit)  # max(-limit, ·)
        current = np.zeros(self.n)
        for j in self._hbridge_joints:
            i, s = j.index, self.scaling[j.index]
            w_m = 0.0 if omega is None or not np.isfinite(omega[i]) else float(omega[i]) * s.ratio
            duty = duty_for_current(float(amps[i]), s.resistance_ohm, s.ke_v_s_per_rad, w_m, s.supply_v)
            self._set_hbridge(j, duty)
            current[i] = amps[i]
        lin = self._linear_idx
        if lin.size:
            gain, off = self._amp_gain[lin], self._amp_offset[lin]
            volts = (amps[lin] - off) / gain
            volts = np.where(volts > DAC_V_MIN, volts, DAC_V_MIN)  # max(DAC_V_MIN, v)
            volts = np.where(volts < DAC_V_MAX, volts, DAC_V_MAX)  # min(DAC_V_MAX, ·)
            self.last_dac_volts[lin] = volts
            current[lin] = volts * gain + off
            dv = self.last_dac_volts
            for board, js, chans in self._dac_plan:
                self.dac[board].write_many(dict(zip(chans, dv[js].tolist(), strict=True)), update=True)
        self.last_current_a[:] = current
        self.last_torque_nm[:] = np.where(np.isfinite(tau), tau, 0.0)
        if self._release_pending:
            self.release_brakes()
        if self.watchdog_running:
            self._toggle_watchdog()
        return current

    def write_command_volts(self, volts: Mapping[int, float]) -> None:
        """Command linear amplifiers directly in DAC volts (joint index → V; one strobe per DAC
        board), bypassing the torque conversion — calibration pulses. The current this commands
        is recorded like :meth:`write_torque`'s, so the watchdog's current check follows it."""
        per_dac: dict[str, dict[int, float]] = {}
        for i, v in volts.items():
            j, s = self.rig.joints[i], self.scaling[i]
            pin = j.wiring["amp_command"]
            per_dac.setdefault(pin.board, {})[pin.index] = v
            self.last_dac_volts[i] = v
            self.last_current_a[i] = v * s.amp_gain_a_per_v + s.amp_offset_a
        for board, cmds in per_dac.items():
            self.dac[board].write_many(cmds, update=True)

    def _toggle_watchdog(self) -> None:
        # Last write of the tick, after the commands: the pump is fed only by a tick that got
        # as far as commanding the amplifiers. No read-back: the amplifiers watch the line.
        pio = self._watchdog_pio
        if pio is not None:
            self._watchdog_level = not self._watchdog_level
            pio.set_line(WATCHDOG_NET, self._watchdog_level, verify=False)

    def _stop_watchdog(self) -> None:
        """Stop toggling and leave the line low (the amplifiers then drop their enables)."""
        self.watchdog_running = False
        if self._watchdog_pio is not None:
            self._watchdog_level = False
            # Not read back: a line stuck at either level gives no edges, which is what counts.
            self._watchdog_pio.set_line(WATCHDOG_NET, False, verify=False)

    def _set_hbridge(self, j, duty: float | np.ndarray) -> None:
        pwm = j.wiring.get("pwm")
        if pwm is None:
            return
        drv: Any = self.pio[pwm.board]  # (in lanes a lane driver, which takes a duty per lane)
        direction = j.net("direction") if "direction" in j.wiring else None
        drv.set_pwm(duty, direction_line=direction)

    @property
    def torque_at_stop_nm(self) -> np.ndarray:
        """Per braked joint the torque last commanded (0 for joints without a brake): after a stop,
        what held each joint its brake then kept in place — a resume starts its law there."""
        return np.where(self.holding_brake_mask, self.last_torque_nm, 0.0)

    def release_brakes(self) -> None:
        """Raise every holding brake's line (energised: the brake releases after its release
        delay). Called by the first torque write after :meth:`enable` — after the DAC strobe, so
        the amplifiers already carry the command that holds the joints."""
        self._release_pending = False
        for i, board, net in self._holding_brakes:
            self.pio[board].set_line(net, True)
            self.brake_released[self._joint_slot[i]] = True

    def engage_brakes(self) -> None:
        """Drop every holding brake's line (the brake holds after its engage delay)."""
        self._release_pending = False
        for i, board, net in self._holding_brakes:
            self.pio[board].set_line(net, False)
            self.brake_released[self._joint_slot[i]] = False

    def enable(self, on: bool = True) -> None:
        """Drive every amplifier enable line (and the PWM timers). Enabling starts the watchdog
        line: its first edge comes with the tick's torque write, so the amplifiers see it
        together with the rising enables (which re-arms one the watchdog tripped) — and never a
        second edge in the same tick, which would cancel the first. Disabling stops it, low.

        Holding brakes: enabling leaves them holding and releases them with the next torque
        write (:meth:`release_brakes`); disabling drops their lines first."""
        if on:
            self.watchdog_running = self._watchdog_pio is not None
            self._release_pending = self.has_holding_brakes
        else:
            self.engage_brakes()
            self._stop_watchdog()
        for j in self.rig.joints:
            if "amp_enable" in j.wiring:
                self.pio[j.wiring["amp_enable"].board].set_line(j.net("amp_enable"), on)
            if "pwm" in j.wiring:
                self.pio[j.wiring["pwm"].board].pwm_enable(on)

    def clear_faults(self) -> None:
        for j in self.rig.joints:
            if "amp_reset" in j.wiring:
                drv = self.pio[j.wiring["amp_reset"].board]
                drv.set_line(j.net("amp_reset"), True)
                drv.set_line(j.net("amp_reset"), False)

    def safe_stop(self, interruptions: list[BaseException] | None = None) -> list[str]:
        """Amplifiers disabled, holding-brake lines low (the brakes hold), DAC outputs to 0 V, PWM
        off, the watchdog line no longer toggled (left low) — then read back that it happened.

        Keeps going past driver errors (a safe stop must do as much as it can) and returns what
        failed or could not be confirmed (:meth:`verify_stopped`): an empty list means every
        enable line reads low, every amplifier command's DAC output holds the 0 V code and every
        PWM timer is off.

        A signal-safe critical section (:class:`servo.interrupts.SignalsDeferred`): a SIGINT,
        SIGTERM or SIGHUP arriving during the stop, or a ``KeyboardInterrupt``/``Terminated``
        raised inside one of its steps, does not cut it short. Each is appended to
        ``interruptions`` when given (the caller records them and decides); without it the first
        is raised once the stop and its read-back are done."""
        held: list[BaseException] = []
        with SignalsDeferred(held):
            failures = self._stop_outputs(held)
        if interruptions is not None:
            interruptions.extend(held)
        elif held:
            raise held[0]
        return failures

    def _stop_outputs(self, held: list[BaseException]) -> list[str]:
        failures = self._stop_writes(held)
        verified = self._read_back(held)
        return failures + [f for f in verified if f not in failures]

    def _stop_writes(self, held: list[BaseException]) -> list[str]:
        """The stop's writes (brakes, DACs at 0 V, PWM off, enables low, the watchdog line low), each
        made whatever the others do; what failed, one line each."""
        failures: list[str] = []

        def step(what: str, action: Callable[[], object]) -> None:
            # An interrupt raised inside a write is held, not raised, and the write (idempotent)
            # made again: the interrupted one may not have reached the board.
            for _ in range(self.STOP_STEP_ATTEMPTS):
                try:
                    action()
                    return
                except INTERRUPTS as e:
                    held.append(e)
                except Exception as e:
                    failures.append(f"{what}: {e}")
                    return
            failures.append(f"{what}: interrupted {self.STOP_STEP_ATTEMPTS} times")

        def dac_zero(drv: DacDriver) -> None:
            drv.write_many({ch: 0.0 for ch in range(drv.CHANNELS)}, update=True)

        def pwm_off(j: Any) -> None:
            self._set_hbridge(j, 0.0)
            self.pio[j.wiring["pwm"].board].pwm_enable(False)

        def enable_low(j: Any) -> None:
            self.pio[j.wiring["amp_enable"].board].set_line(j.net("amp_enable"), False)

        def brake_low(i: int, board: str, net: str) -> None:
            self.pio[board].set_line(net, False)
            self.brake_released[self._joint_slot[i]] = False

        self._release_pending = False
        for i, board, net in self._holding_brakes:  # first: the brakes start engaging at once
            step(f"{self.rig.joints[i].name}: holding brake", partial(brake_low, i, board, net))
        for name, drv in self.dac.items():
            step(name, partial(dac_zero, drv))
        for j in self.rig.joints:
            if "pwm" in j.wiring:
                step(j.name, partial(pwm_off, j))
            if "amp_enable" in j.wiring:
                step(j.name, partial(enable_low, j))
        step("watchdog line", self._stop_watchdog)
        self.last_dac_volts[:] = 0.0
        self.last_current_a[:] = 0.0
        return failures

    def _read_back(self, held: list[BaseException]) -> list[str]:
        """:meth:`verify_stopped`, read again when a signal interrupts it."""
        for _ in range(self.STOP_STEP_ATTEMPTS):
            try:
                return self.verify_stopped()
            except INTERRUPTS as e:
                held.append(e)
        return ["the read-back was interrupted"]

    def verify_stopped(self) -> list[str]:
        """Read back every actuator output: what is not provably safe, one line each.

        An enable line is read from its PIO latch and pin; an amplifier command from its DAC
        output register (``OUTn``) against the 0 V code; a PWM timer from its control register.
        A board that does not answer cannot be confirmed and is reported as such. A holding
        brake's line is read like an enable: it must read low (the brake holding)."""
        problems: list[str] = []
        for i, board, net in self._holding_brakes:
            pin = self.rig.joints[i].wiring["holding_brake"]
            try:
                pio = self.pio[board]
                port, bit = pio.resolve(net)
                if pio.get_line(net) or pio.read_pins(port) >> bit & 1:
                    problems.append(f"{self.rig.joints[i].name}: holding brake {pin} still reads high (released)")
            except Exception as e:
                problems.append(f"{self.rig.joints[i].name}: holding brake {pin} cannot be read back ({e})")
        for j in self.rig.joints:
            w = j.wiring
            try:
                if "amp_enable" in w:
                    pio = self.pio[w["amp_enable"].board]
                    port, bit = pio.resolve(j.net("amp_enable"))
                    if pio.get_line(j.net("amp_enable")) or pio.read_pins(port) >> bit & 1:
                        problems.append(f"{j.name}: amplifier enable {w['amp_enable']} still reads high")
            except Exception as e:
                problems.append(f"{j.name}: amplifier enable {w['amp_enable']} cannot be read back ({e})")
            try:
                if "amp_command" in w:
                    pin = w["amp_command"]
                    dac = self.dac[pin.board]
                    zero, _ = dac.code_for(pin.index, 0.0)
                    code = dac.read_back_counts(pin.index)
                    if code != zero:
                        problems.append(f"{j.name}: DAC {pin} output code {code:#05x}, not the 0 V code {zero:#05x}")
            except Exception as e:
                problems.append(f"{j.name}: DAC {w['amp_command']} cannot be read back ({e})")
            try:
                if "pwm" in w and self.pio[w["pwm"].board].pwm_duty() != 0.0:
                    problems.append(f"{j.name}: PWM {w['pwm']} still running")
            except Exception as e:
                problems.append(f"{j.name}: PWM {w['pwm']} cannot be read back ({e})")
        return problems
