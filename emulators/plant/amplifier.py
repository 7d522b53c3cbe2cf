"""Amplifier power stages, vectorised over joints (each joint has exactly one type).

Linear transconductance amplifier (``amplifier = "linear"``)
    Reference ``i_ref = clip(gain·v_cmd, ±I_lim)``. Its internal current loop gives a first-order
    response ``di/dt = 2π·bw·(i_ref − i)`` as long as the output voltage it needs stays within
    the supply (compliance); the voltage it needs is ``R·i + L·di/dt + Ke·ω``. Over one step the
    current is the first-order solution clipped between the two rail solutions (``V = ±supply``,
    exact RL solutions), which is exact whenever one mode holds for the whole step.
    Disabled (or faulted): the output stage opens and the winding current decays through the
    clamp diodes to zero (then stays zero).
    Latched faults: over-temperature (first-order I²t: ``x' = (i²/I_cont² − x)/τ_th``, trips at
    ``x > 1``) and compliance saturation held for ``saturation_fault_s`` (a stalled or overspeed
    output stage). A latched fault disables the output until a rising edge of ``fault_reset``
    (the thermal state is physical and re-trips at once if still above 1). Over-temperature and
    held saturation are checked once per servo period (their time scales are ≥ 0.1 s).

H-bridge (``amplifier = "hbridge"``), sign-magnitude PWM averaged over the PWM period
    drive (enabled, not braking, duty > 0): ``V = ±supply·max(d − t_dead·f_pwm, 0)`` by the
    direction line, with cycle-by-cycle chopping holding ``|i| ≤ I_lim`` in the drive direction;
    brake: both low-side switches on, winding shorted (``V = 0``); coast (disabled, duty 0 or
    faulted): all switches off, current decays through the diodes to zero.
    Latched faults: overcurrent (``|i| > overcurrent_trip_a``, e.g. braking at speed is not
    chopped) and over-temperature (I²t as above); reset as for the linear amplifier.

Current monitor: ``imon_v = i·monitor_v_per_a + offset`` (+ noise added at sampling).

Enable watchdog (:class:`EnableWatchdog`, rig-level ``[rig.watchdog]``): a retriggerable
charge pump on one line that feeds the enable chain of every amplifier. It arms at the line's
first edge; from then on each edge keeps the chain closed for ``timeout_s``, and when the edges
stop, every amplifier whose enable is high is latched off (an open output stage, like disabled)
until its enable line rises again while the pump runs. The plant node's wall-clock command
timeout latches the same way (:meth:`EnableWatchdog.hold_off`). A latch is not a fault: the
fault line stays low and ``fault_reset`` does not clear it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

FAULT_THERMAL = 1  #: I²t over-temperature
FAULT_COMPLIANCE = 2  #: compliance (voltage) saturation held too long (linear amplifier)
FAULT_OVERCURRENT = 4  #: current above the trip level (H-bridge)

WATCHDOG_EXPIRED = 1  #: the charge-pump line stopped toggling for ``timeout_s`` (simulated time)
WATCHDOG_COMMAND_TIMEOUT = 2  #: the plant node heard no CONTROL/SYNC for its command timeout (wall clock)
WATCHDOG_CAUSES = {WATCHDOG_EXPIRED: "watchdog", WATCHDOG_COMMAND_TIMEOUT: "command_timeout"}


@dataclass
class AmpArrays:
    """Per-joint amplifier parameters (both types stacked; ``is_lin`` selects)."""

    is_lin: np.ndarray
    gain: np.ndarray
    bw_rad_s: np.ndarray
    lin_limit: np.ndarray
    lin_supply: np.ndarray
    lin_monitor: np.ndarray
    lin_monitor_offset: np.ndarray
    lin_monitor_noise: np.ndarray
    sat_fault_s: np.ndarray
    hb_supply: np.ndarray
    hb_deadtime_duty: np.ndarray  #: t_dead·f_pwm
    hb_limit: np.ndarray
    hb_trip: np.ndarray
    hb_monitor: np.ndarray
    hb_monitor_offset: np.ndarray
    hb_monitor_noise: np.ndarray
    i_cont: np.ndarray
    tau_th: np.ndarray

    @property
    def supply(self) -> np.ndarray:
        return np.where(self.is_lin, self.lin_supply, self.hb_supply)

    def monitor_volts(self, i: np.ndarray) -> np.ndarray:
        """Noise-free current-monitor output (V)."""
        return np.where(
            self.is_lin,
            i * self.lin_monitor + self.lin_monitor_offset,
            i * self.hb_monitor + self.hb_monitor_offset,
        )

    @property
    def monitor_noise(self) -> np.ndarray:
        return np.where(self.is_lin, self.lin_monitor_noise, self.hb_monitor_noise)


@dataclass
class AmpDrive:
    """A command turned into per-joint drive quantities (constant over a command segment)."""

    lin_on: np.ndarray  #: linear amp enabled by command
    i_ref: np.ndarray  #: linear amp current reference (A)
    hb_brake: np.ndarray
    hb_drive: np.ndarray  #: H-bridge driving (enabled, not braking, effective duty > 0)
    hb_v: np.ndarray  #: H-bridge average drive voltage (V)
    hb_sign: np.ndarray  #: ±1 drive direction


def prepare_drive(
    amp: AmpArrays,
    amp_command_v: np.ndarray,
    amp_enable: np.ndarray,
    pwm_duty: np.ndarray,
    pwm_direction: np.ndarray,
    brake: np.ndarray,
) -> AmpDrive:
    """Evaluate the command-only parts of both amplifier models."""
    enable = np.asarray(amp_enable, dtype=bool)
    i_ref = np.clip(amp.gain * np.asarray(amp_command_v, dtype=float), -amp.lin_limit, amp.lin_limit)
    duty = np.clip(np.nan_to_num(np.asarray(pwm_duty, dtype=float)), 0.0, 1.0)
    d_eff = np.maximum(duty - amp.hb_deadtime_duty, 0.0)
    sign = np.where(np.asarray(pwm_direction, dtype=bool), 1.0, -1.0)
    is_hb = ~amp.is_lin
    brk = is_hb & np.asarray(brake, dtype=bool)
    drive = is_hb & enable & ~brk & (d_eff > 0.0)
    return AmpDrive(
        lin_on=amp.is_lin & enable,
        i_ref=np.where(amp.is_lin, i_ref, 0.0),
        hb_brake=brk,
        hb_drive=drive,
        hb_v=np.where(drive, sign * d_eff * amp.hb_supply, 0.0),
        hb_sign=sign,
    )


class AmpConsts:
    """Step-dependent factors for one step length ``h``, computed once."""

    def __init__(self, amp: AmpArrays, resistance: np.ndarray, inductance: np.ndarray, ke: np.ndarray, h: float):
        self.h = float(h)
        self.rl = np.exp(-h * resistance / inductance)  #: exp(−h·R/L)
        self.rl_gain = (1.0 - self.rl) / resistance  #: (1 − e)/R: volts → end-of-step current
        self.emf_gain = ke * self.rl_gain  #: back-emf per rad/s → current
        self.rail_gain = amp.supply * self.rl_gain  #: supply rail → current
        self.loop = np.exp(-h * amp.bw_rad_s)  #: exp(−h·2π·bw)
        self.thermal = np.exp(-h / amp.tau_th)  #: exp(−h/τ_th)
        self.thermal_gain = (1.0 - self.thermal) / (amp.i_cont * amp.i_cont)


class AmpState:
    """Fault latches, thermal state and compliance-saturation timers (per joint)."""

    def __init__(self, n: int) -> None:
        self.fault = np.zeros(n, dtype=bool)
        self.cause = np.zeros(n, dtype=np.int64)
        self.thermal = np.zeros(n)
        self.sat_time = np.zeros(n)
        self.saturated = np.zeros(n, dtype=bool)

    def reset_latches(self, mask: np.ndarray) -> None:
        """Clear latched faults where ``mask`` (a rising edge of the reset line)."""
        self.fault = self.fault & ~mask
        self.cause = np.where(mask, 0, self.cause)
        self.sat_time = np.where(mask, 0.0, self.sat_time)

    def latch(self, trip: np.ndarray, cause: int) -> None:
        new = trip & ~self.fault
        self.cause = np.where(new, self.cause | cause, self.cause)
        self.fault = self.fault | trip


def check_slow_faults(amp: AmpArrays, st: AmpState) -> None:
    """Latch over-temperature and held compliance saturation (evaluated once per period)."""
    trip_th = st.thermal > 1.0
    trip_sat = amp.is_lin & (amp.sat_fault_s > 0.0) & (st.sat_time >= amp.sat_fault_s)
    if trip_th.any():
        st.latch(trip_th, FAULT_THERMAL)
    if trip_sat.any():
        st.latch(trip_sat, FAULT_COMPLIANCE)


def current_step_linear(
    st: AmpState, i_ref_term: np.ndarray, i0: np.ndarray, omega: np.ndarray, k: AmpConsts
) -> np.ndarray:
    """Fast path when every joint is an enabled, unfaulted linear amplifier (returns A).

    ``i_ref_term`` is ``i_ref·(1 − loop)``.
    """
    i0d = i0 * k.rl
    g = omega * k.emf_gain
    i_up = i0d + k.rail_gain - g
    i_dn = i0d - k.rail_gain - g
    i_loop = i0 * k.loop + i_ref_term
    i1 = np.minimum(np.maximum(i_loop, i_dn), i_up)
    sat = i1 != i_loop
    st.saturated = sat
    st.sat_time = (st.sat_time + k.h) * sat
    st.thermal = st.thermal * k.thermal + (i1 * i1) * k.thermal_gain
    return i1


def current_step(
    amp: AmpArrays,
    st: AmpState,
    drv: AmpDrive,
    i0: np.ndarray,
    omega: np.ndarray,
    k: AmpConsts,
) -> np.ndarray:
    """Advance the winding current one step, any mix of amplifier states (returns A).

    Updates the thermal state and saturation timers and latches H-bridge overcurrent at once;
    over-temperature and held saturation latch in :func:`check_slow_faults`.
    """
    lin_active = drv.lin_on & ~st.fault
    hb_ok = ~st.fault
    brake = drv.hb_brake & hb_ok
    drive = drv.hb_drive & hb_ok
    i0d = i0 * k.rl
    g = omega * k.emf_gain
    # linear amplifier: first-order loop clipped by the rail solutions (V = ±supply)
    i_loop = drv.i_ref + (i0 - drv.i_ref) * k.loop
    i_up = i0d + k.rail_gain - g
    i_dn = i0d - k.rail_gain - g
    i_lin = np.minimum(np.maximum(i_loop, i_dn), i_up)
    sat = lin_active & (i_lin != i_loop)
    # H-bridge drive / brake (brake: V = 0)
    i_hb = i0d + drv.hb_v * k.rl_gain - g
    chop = drive & (drv.hb_sign * i_hb > amp.hb_limit)
    i_hb = np.where(chop, drv.hb_sign * amp.hb_limit, i_hb)
    # off: the current commutates into the diodes against the rail and stops at zero
    i_off = i0d - np.sign(i0) * k.rail_gain - g
    i_off = np.where(i_off * i0 > 0.0, i_off, 0.0)
    i1 = np.where(lin_active, i_lin, np.where(brake | drive, i_hb, i_off))
    st.saturated = sat
    st.sat_time = np.where(sat, st.sat_time + k.h, 0.0)
    st.thermal = st.thermal * k.thermal + (i1 * i1) * k.thermal_gain
    trip_oc = ~amp.is_lin & (np.abs(i1) > amp.hb_trip)
    if trip_oc.any():
        st.latch(trip_oc, FAULT_OVERCURRENT)
    return i1


def cause_names(cause: int) -> list[str]:
    """The names of the bits of a watchdog cause (``WATCHDOG_CAUSES``), lowest bit first."""
    return [name for bit, name in WATCHDOG_CAUSES.items() if cause & bit]


class EnableWatchdog:
    """The amplifiers' enable watchdog: a retriggerable charge pump shared by every amplifier.

    The plant sees the line once per servo period, when the period's command takes effect, so an
    edge is dated at that instant; the pump then runs out ``timeout_s`` later, on the substep
    grid (:meth:`expiry_substep`). ``timeout_s = None``: no watchdog wired — the pump never runs
    out (old rig files), but :meth:`hold_off` and the re-arm rule still apply.

    It arms at the first edge after a reset, like a watchdog timer started by its first kick:
    until then it holds nothing off, so a plant stepped without a controller (tests, benchmarks,
    ``load_plant`` users) behaves as it did without a watchdog. The drivers
    (:class:`servo.io.JointIO`) give the first edge in the tick the enables rise.

    Per joint ``cause`` holds why the amplifier is latched off (``WATCHDOG_*`` bits, 0 = not
    latched). Only amplifiers whose enable line is high are latched: a controller that disabled
    its amplifiers before it stopped the pump (a safe stop) leaves nothing tripped. Re-arm: a
    rising edge of the enable line while the pump runs.
    """

    def __init__(self, n: int, timeout_s: float | None) -> None:
        if timeout_s is not None and not timeout_s > 0:
            raise ValueError(f"watchdog timeout_s must be > 0, got {timeout_s}")
        self.timeout_s = timeout_s
        self.level = False  #: the line's level in the last command
        self.last_edge_s = -math.inf  #: plant time of the last edge (never: the pump has not run)
        self.cause = np.zeros(n, dtype=np.int64)
        self.trips = 0  #: amplifiers latched off so far (each latching counts once)

    @property
    def latched(self) -> np.ndarray:
        return self.cause != 0

    @property
    def armed(self) -> bool:
        """A pump wired and started (its line has had an edge since the reset)."""
        return self.timeout_s is not None and self.last_edge_s > -math.inf

    def alive(self, t_s: float) -> bool:
        """Whether the pump keeps the enable chain closed at plant time ``t_s``."""
        if self.timeout_s is None or not self.armed:
            return True
        return t_s < self.last_edge_s + self.timeout_s

    def effective(self, enable: np.ndarray) -> np.ndarray:
        """The enables the output stages obey: the enable lines less the latched amplifiers."""
        return np.asarray(enable, dtype=bool) & (self.cause == 0)

    def _latch(self, enable: np.ndarray, cause: int) -> bool:
        new = np.asarray(enable, dtype=bool) & (self.cause == 0)
        if not new.any():
            return False
        self.cause = np.where(new, cause, self.cause)
        self.trips += int(np.count_nonzero(new))
        return True

    def command(self, line: bool, enable: np.ndarray, prev_enable: np.ndarray, t_s: float) -> None:
        """A period's command takes effect at ``t_s``: an edge of the line retriggers the pump
        (first, so an enable raised together with the first toggle is accepted), a rising enable
        re-arms its amplifier while the pump runs, an enable high into a dead pump latches."""
        line = bool(line)
        if line != self.level:
            self.level = line
            self.last_edge_s = t_s
        if self.alive(t_s):
            rising = np.asarray(enable, dtype=bool) & ~np.asarray(prev_enable, dtype=bool)
            if rising.any():
                self.cause = np.where(rising, 0, self.cause)
        else:
            self._latch(enable, WATCHDOG_EXPIRED)

    def expiry_substep(self, t0_s: float, h: float, n_sub: int) -> int:
        """The first substep of the period starting at ``t0_s`` during which the pump is out
        (``-1``: it runs through the whole period). An already dead pump gives 0."""
        if self.timeout_s is None or not self.armed:
            return -1
        k = math.ceil((self.last_edge_s + self.timeout_s - t0_s) / h - 1e-9)
        return max(0, k) if k < n_sub else -1

    def expire(self, enable: np.ndarray) -> bool:
        """The pump ran out: latch every enabled amplifier (True when one was latched)."""
        return self._latch(enable, WATCHDOG_EXPIRED)

    def hold_off(self, enable: np.ndarray, cause: int = WATCHDOG_COMMAND_TIMEOUT) -> np.ndarray:
        """Latch every enabled amplifier off now for ``cause`` (the plant node's command
        timeout); returns the amplifiers this latched."""
        before = self.cause.copy()
        self._latch(enable, cause)
        return (self.cause != 0) & (before == 0)


class LaneEnableWatchdog:
    """The enable watchdogs of B stacked plants (lane mode, :meth:`emulators.plant.Plant.from_lanes`):
    per lane its pump (line level, last edge, timeout), per amplifier its latch, amplifier ``j`` of
    lane ``b`` at ``b*n + j``. Every method does for each lane what :class:`EnableWatchdog` does for
    that lane's plant, with the same float operations; where the scalar one answers one bool or
    substep, this one answers one per lane ((B,) arrays)."""

    def __init__(self, dogs: Sequence[EnableWatchdog]) -> None:
        self.n_lanes = len(dogs)
        self.n = int(dogs[0].cause.size)
        if any(d.cause.size != self.n for d in dogs):
            raise ValueError("stacked watchdogs must have the same number of amplifiers")
        #: lanes with a pump wired (``timeout_s`` not ``None``); the others never run out
        self.wired = np.array([d.timeout_s is not None for d in dogs], dtype=bool)
        self.timeout_s = np.array([math.inf if d.timeout_s is None else d.timeout_s for d in dogs], dtype=float)
        self.level = np.array([d.level for d in dogs], dtype=bool)
        self.last_edge_s = np.array([d.last_edge_s for d in dogs], dtype=float)
        self.cause = np.concatenate([d.cause for d in dogs]).astype(np.int64)
        self.trips = np.array([d.trips for d in dogs], dtype=np.int64)  #: per lane

    @property
    def latched(self) -> np.ndarray:
        return self.cause != 0

    @property
    def armed(self) -> np.ndarray:
        """Per lane: a pump wired and started."""
        return self.wired & (self.last_edge_s > -math.inf)

    def alive(self, t_s: float) -> np.ndarray:
        """Per lane: the pump keeps the enable chain closed at ``t_s``."""
        with np.errstate(invalid="ignore"):  # -inf + inf of an unarmed, unwired lane: masked
            return ~self.armed | (t_s < self.last_edge_s + self.timeout_s)

    def effective(self, enable: np.ndarray) -> np.ndarray:
        return np.asarray(enable, dtype=bool) & (self.cause == 0)

    def _latch(self, new: np.ndarray, cause: int) -> np.ndarray:
        """Latch the amplifiers ``new`` (enabled, not latched yet) for ``cause``; per lane whether
        one was latched."""
        per_lane = new.reshape(self.n_lanes, self.n)
        self.cause = np.where(new, cause, self.cause)
        self.trips = self.trips + np.count_nonzero(per_lane, axis=1)
        return np.asarray(per_lane.any(axis=1), dtype=bool)

    def command(self, line: Any, enable: np.ndarray, prev_enable: np.ndarray, t_s: float) -> None:
        """:meth:`EnableWatchdog.command` per lane; ``line``: the lines' levels (a bool for every
        lane, or (B,))."""
        line = np.asarray(line, dtype=bool)
        edge = line != self.level
        self.level = np.where(edge, line, self.level)
        self.last_edge_s = np.where(edge, t_s, self.last_edge_s)
        alive = np.repeat(self.alive(t_s), self.n)
        enable = np.asarray(enable, dtype=bool)
        rising = enable & ~np.asarray(prev_enable, dtype=bool)
        self.cause = np.where(alive & rising, 0, self.cause)
        dead = ~alive
        if dead.any():
            self._latch(enable & dead & (self.cause == 0), WATCHDOG_EXPIRED)

    def expiry_substep(self, t0_s: float, h: float, n_sub: int) -> np.ndarray:
        """:meth:`EnableWatchdog.expiry_substep` per lane (int64 (B,), -1: runs through)."""
        armed = self.armed
        with np.errstate(invalid="ignore"):
            k = np.ceil((self.last_edge_s + self.timeout_s - t0_s) / h - 1e-9)
        k = np.where(armed, k, -1.0).astype(np.int64)
        return np.where(armed & (k < n_sub), np.maximum(k, 0), -1)

    def expire(self, enable: np.ndarray, lanes: np.ndarray) -> np.ndarray:
        """The pumps of ``lanes`` ((B,) bool) ran out: latch their enabled amplifiers; per lane
        whether one was latched."""
        new = np.asarray(enable, dtype=bool) & (self.cause == 0) & np.repeat(lanes, self.n)
        return self._latch(new, WATCHDOG_EXPIRED)

    def hold_off(self, enable: np.ndarray, cause: int = WATCHDOG_COMMAND_TIMEOUT) -> np.ndarray:
        before = self.cause.copy()
        self._latch(np.asarray(enable, dtype=bool) & (self.cause == 0), cause)
        return (self.cause != 0) & (before == 0)

    def lane(self, b: int) -> EnableWatchdog:
        """Lane ``b``'s watchdog as a scalar :class:`EnableWatchdog` (a copy; for tests and
        reports)."""
        d = EnableWatchdog(self.n, None if not self.wired[b] else float(self.timeout_s[b]))
        d.level = bool(self.level[b])
        d.last_edge_s = float(self.last_edge_s[b])
        d.cause = self.cause[b * self.n:(b + 1) * self.n].copy()
        d.trips = int(self.trips[b])
        return d
