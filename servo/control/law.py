"""The JPL servo law, vectorised over joints, with integrator switch-off and anti-windup hooks.

Per joint, every period T (8 ms at 125 Hz)::

    e_k  = θd_k − θ_k                  rad
    ė_k  = ωd_k − ω_k                  rad/s
    Ie_k = Ie_{k−1} + T·e_k            rad·s     (backward Euler, only while integrating)
    Iv_k = Iv_{k−1} + T·ė_k            rad
    a_k  = Kp_eff·e_k + Kpi·Ie_k + Kv·ė_k + KvI·Iv_k + αd_k      rad/s² (normalized acceleration)

``Kp_eff`` is ``Kp`` while integrating and the boosted gain while the integrators are switched off.
On the ideal plant θ'' = a the continuous closed loop is s³ + Kv·s² + (Kp+KvI)·s + Kpi.

Integrator switch-off (per joint, see :class:`SwitchOffConfig`) — states ``integrating`` and
``switched off``::

    integrating  → off   when the motion is done and |e| ≤ inner band (or e changed sign since the
                         previous tick) for at least settle_time
    off → integrating    when a motion is running (done is false)        reason "new_motion"
                         or |e| > outer band                             reason "error_outside_band"
                         or the switch-off is disabled                   reason "disabled"

While off the integrators keep their values (they are not fed) and Kp is multiplied by the boost.
The default boost (``None`` = "auto") is (Kp+KvI)/Kp: frozen, the KvI·Iv term no longer follows the
position error (∫ė dt = e), so the loop would lose KvI of its position stiffness; the boost puts it
back, as the paper says ("increasing the position gain to compensate for the loss in loop gain").
The static error left by a friction torque T_F is then T_F/(J·Kp_eff).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np

from servo.control.errors import GainError
from servo.control.gains import GAIN_NAMES, Gains, V
from servo.control.normalize import per_joint
from servo.control.velocity_filter import VelocityFilter, filter_alpha

DEFAULT_PERIOD_S = 0.008

DEFAULT_INNER_BAND_RAD = math.radians(0.1)
DEFAULT_OUTER_BAND_RAD = math.radians(1.0)


def switched_off_kp(kp: V, kvi: V, kp_boost: V) -> V:
    """Kp while the integrators are switched off (1/s²): ``kp·kp_boost``, or with ``kp_boost`` NaN
    (auto) ``kp + kvi`` — frozen, the KvI·∫ė term no longer follows e, so the boost puts its
    stiffness back (module docstring). Floats or per-joint arrays."""
    # ``[()]`` gives a numpy scalar for float inputs, an array for arrays: V either way
    return cast(V, np.where(np.isnan(kp_boost), kp + kvi, kp * np.nan_to_num(kp_boost, nan=1.0))[()])


@dataclass(frozen=True)
class SwitchOffConfig:
    """Per-joint integrator switch-off settings (arrays of length n).

    ``enabled`` bool; ``inner_band`` rad (switch off at or below); ``outer_band`` rad (switch back on
    above; must exceed inner_band); ``kp_boost`` factor ≥ 1 applied to Kp while off, NaN = auto
    ((Kp+KvI)/Kp); ``settle_time`` s the error must stay in the inner band before switching off;
    ``zero_crossing`` bool: a sign change of e between two ticks counts as "in the band" (a fast
    limit cycle can step over a narrow band between samples).
    """

    enabled: np.ndarray
    inner_band: np.ndarray
    outer_band: np.ndarray
    kp_boost: np.ndarray
    settle_time: np.ndarray
    zero_crossing: np.ndarray

    @classmethod
    def make(cls, n: int, enabled: bool | list[bool] | np.ndarray = True,
             inner_band: float | list[float] | np.ndarray = DEFAULT_INNER_BAND_RAD,
             outer_band: float | list[float] | np.ndarray = DEFAULT_OUTER_BAND_RAD,
             kp_boost: float | list[float | None] | np.ndarray | None = None,
             settle_time: float | list[float] | np.ndarray = 0.0,
             zero_crossing: bool | list[bool] | np.ndarray = True) -> SwitchOffConfig:
        """Validated settings for ``n`` joints (scalars broadcast); raises :class:`GainError`."""
        en = _bools("switch_off.enabled", enabled, n)
        zc = _bools("switch_off.zero_crossing", zero_crossing, n)
        inner = per_joint("switch_off.inner_band", inner_band, n)
        outer = per_joint("switch_off.outer_band", outer_band, n, positive=True)
        boost_in: float | list[float] | np.ndarray
        if isinstance(kp_boost, list):
            boost_in = [np.nan if b is None else b for b in kp_boost]
        else:
            boost_in = np.nan if kp_boost is None else kp_boost
        boost = per_joint("switch_off.kp_boost", boost_in, n, allow_nan=True)
        settle = per_joint("switch_off.settle_time", settle_time, n)
        for j in range(n):
            if not outer[j] > inner[j]:
                raise GainError("switch_off.outer_band", float(outer[j]),
                                f"a band wider than inner_band ({float(inner[j])!r} rad) for hysteresis", j)
            if not np.isnan(boost[j]) and boost[j] < 1.0:
                raise GainError("switch_off.kp_boost", float(boost[j]), "a factor >= 1 (or auto)", j)
        return cls(en, inner, outer, boost, settle, zc)

    @classmethod
    def disabled(cls, n: int) -> SwitchOffConfig:
        return cls.make(n, enabled=False)


def _bools(name: str, value: bool | list[bool] | np.ndarray, n: int) -> np.ndarray:
    arr = np.array(value)
    if arr.ndim == 0:
        arr = np.full(n, arr.item())
    if arr.shape != (n,) or arr.dtype != np.bool_:
        raise GainError(name, value, f"true/false or a list of {n} of them")
    return arr.astype(bool)


@dataclass(frozen=True)
class SwitchEvent:
    """An integrator switch-off state change: at ``tick`` joint ``joint`` started (``integrating``
    True) or stopped (False) feeding its integrators, for ``reason``."""

    tick: int
    joint: int
    integrating: bool
    reason: str


@dataclass
class LawState:
    """The law's memory (arrays of length n): integrator values and switch-off state."""

    ie: np.ndarray  # ∫e dt, rad·s
    iv: np.ndarray  # ∫ė dt, rad
    integrating: np.ndarray  # bool: integrators fed (switch-off state "on")
    in_band_time: np.ndarray  # s spent settled in the inner band while integrating
    e_prev: np.ndarray  # rad, NaN before the first tick
    events: list[SwitchEvent] = field(default_factory=list)
    #: the velocity filter's output ef (rad) where a joint uses it (servo.control.velocity_filter)
    ef: np.ndarray | None = None

    @classmethod
    def zeros(cls, n: int) -> LawState:
        return cls(np.zeros(n), np.zeros(n), np.ones(n, bool), np.zeros(n), np.full(n, np.nan), ef=np.zeros(n))

    def copy(self) -> LawState:
        return LawState(self.ie.copy(), self.iv.copy(), self.integrating.copy(), self.in_band_time.copy(),
                        self.e_prev.copy(), list(self.events),
                        ef=np.zeros_like(self.ie) if self.ef is None else self.ef.copy())


class PidLaw:
    """The normalized JPL law for ``n`` joints with period ``period`` s.

    Use :meth:`update` for a one-shot step (no anti-windup), or the three-phase :meth:`begin`,
    :meth:`evaluate`, :meth:`commit` (what :class:`servo.control.objects.PidObject` does so that the
    torque limiter can veto integration in the direction of saturation).
    """

    def __init__(self, n: int, period: float = DEFAULT_PERIOD_S, gains: Gains | None = None,
                 switch_off: SwitchOffConfig | None = None, filter_hz: np.ndarray | None = None) -> None:
        if not (isinstance(n, int) and n > 0):
            raise GainError("n_joints", n, "a positive integer")
        if not (math.isfinite(period) and period > 0):
            raise GainError("period", period, "a positive number of seconds")
        self.n = n
        self.period = float(period)
        self.gains = (gains if gains is not None else Gains.paper()).broadcast(n)
        self.switch_off = switch_off if switch_off is not None else SwitchOffConfig.make(n)
        self.state = LawState.zeros(n)
        #: per joint the velocity filter's cutoff in Hz, NaN: the KvI channel integrates ė (the paper's law)
        self.filter_hz = np.full(n, np.nan)
        self._alpha = np.full(n, np.nan)
        self._filtered = np.zeros(n, bool)
        if filter_hz is not None:
            self._set_filter(np.asarray(filter_hz, float))
        #: staged per-joint controller switches: joint → (gains, filter cutoff Hz or NaN)
        self._pending_switch: dict[int, tuple[Gains[float], float]] = {}
        self._pending_gains: Gains[np.ndarray] | None = None
        self._pending_switch_off: SwitchOffConfig | None = None
        self._tick = -1
        self._kp_off_key: tuple[Gains[np.ndarray], SwitchOffConfig] | None = None
        self._kp_off = np.zeros(n)
        # per-tick scratch (set by begin/evaluate)
        self._e = np.zeros(n)
        self._edot = np.zeros(n)
        self._feed = np.zeros(n, bool)
        self._ie_new = np.zeros(n)
        self._iv_new = np.zeros(n)
        self._ef_new = np.zeros(n)
        self.last_accel = np.zeros(n)

    @classmethod
    def from_lanes(cls, laws: Sequence[PidLaw]) -> PidLaw:
        """One law for B lanes of ``laws`` (batched lockstep, :mod:`hal.lanes`): per-joint arrays
        concatenated lane-major (joint j of lane b at ``b*n + j``). Every operation of a tick is
        elementwise, so each lane computes its scalar law's numbers bit for bit. Staged gains
        (:meth:`set_gains` before the first tick) are taken in force now: the first :meth:`begin`
        would, before anything reads them. Switch-off events of the lane law carry the flat joint
        index (:meth:`lane_events`). Staged per-joint controller switches cannot run in lanes."""
        first = laws[0]
        n = first.n
        for law in laws:
            if law.n != n or law.period != first.period or law._tick != first._tick:
                raise NotImplementedError("lanes' laws differ in joints, period or tick: they cannot run as lanes")
            if law._pending_switch:
                raise NotImplementedError("a staged per-joint controller switch cannot run in lanes")

        def cat(arrays: Sequence[np.ndarray]) -> np.ndarray:
            return np.concatenate([np.asarray(a) for a in arrays])

        obj = cls.__new__(cls)
        obj.n = n * len(laws)
        obj.period = first.period
        gains = [law._pending_gains if law._pending_gains is not None else law.gains for law in laws]
        obj.gains = Gains(**{k: cat([getattr(g, k) for g in gains]) for k in GAIN_NAMES})
        offs = [law._pending_switch_off if law._pending_switch_off is not None else law.switch_off for law in laws]
        obj.switch_off = SwitchOffConfig(*(cat([getattr(o, f) for o in offs]) for f in (
            "enabled", "inner_band", "outer_band", "kp_boost", "settle_time", "zero_crossing")))
        states = [law.state for law in laws]
        obj.state = LawState(cat([s.ie for s in states]), cat([s.iv for s in states]),
                             cat([s.integrating for s in states]), cat([s.in_band_time for s in states]),
                             cat([s.e_prev for s in states]), [],
                             ef=cat([np.zeros(n) if s.ef is None else s.ef for s in states]))
        # the filter coefficients as each lane computed them (not recomputed on the longer array)
        obj.filter_hz = cat([law.filter_hz for law in laws])
        obj._alpha = cat([law._alpha for law in laws])
        obj._filtered = cat([law._filtered for law in laws])
        obj._pending_switch = {}
        obj._pending_gains = None
        obj._pending_switch_off = None
        obj._tick = first._tick
        obj._kp_off_key = None
        obj._kp_off = np.zeros(obj.n)
        obj._e = np.zeros(obj.n)
        obj._edot = np.zeros(obj.n)
        obj._feed = np.zeros(obj.n, bool)
        obj._ie_new = np.zeros(obj.n)
        obj._iv_new = np.zeros(obj.n)
        obj._ef_new = np.zeros(obj.n)
        obj.last_accel = np.zeros(obj.n)
        return obj

    def lane_events(self, lane: int, n: int) -> list[SwitchEvent]:
        """Lane ``lane``'s switch-off events of a lane law of ``n`` joints per lane (:meth:`from_lanes`),
        with the lane's own joint indices, in the order its scalar law records them."""
        lo = lane * n
        return [SwitchEvent(e.tick, e.joint - lo, e.integrating, e.reason) for e in self.state.events
                if lo <= e.joint < lo + n]

    def write_lane(self, lane: int, law: PidLaw) -> None:
        """Put lane ``lane``'s state of this lane law into ``law`` (its scalar law): gains, switch-off
        state, integrators, filter and events (appended to its own), as its scalar run ends."""
        n = law.n
        sl = slice(lane * n, (lane + 1) * n)
        law.gains = Gains(**{k: np.array(getattr(self.gains, k)[sl]) for k in GAIN_NAMES})
        law._pending_gains = None
        law._pending_switch_off = None
        law.switch_off = SwitchOffConfig(*(np.array(getattr(self.switch_off, f)[sl]) for f in (
            "enabled", "inner_band", "outer_band", "kp_boost", "settle_time", "zero_crossing")))
        st = self.state
        law.state = LawState(st.ie[sl].copy(), st.iv[sl].copy(), st.integrating[sl].copy(), st.in_band_time[sl].copy(),
                             st.e_prev[sl].copy(), law.state.events + self.lane_events(lane, n),
                             ef=None if st.ef is None else st.ef[sl].copy())
        law._tick = self._tick
        law._kp_off_key = None
        law._e, law._edot, law._feed = self._e[sl].copy(), self._edot[sl].copy(), self._feed[sl].copy()
        law._ie_new, law._iv_new = self._ie_new[sl].copy(), self._iv_new[sl].copy()
        law._ef_new = self._ef_new[sl].copy()
        law.last_accel = self.last_accel[sl].copy()

    def _set_filter(self, filter_hz: np.ndarray) -> None:
        if filter_hz.shape != (self.n,) or np.any(~np.isnan(filter_hz) & ~(filter_hz > 0)):
            raise GainError("velocity_filter.cutoff_hz", filter_hz.tolist(), f"{self.n} positive cutoffs in Hz or NaN")
        self.filter_hz = filter_hz.copy()
        self._alpha = np.asarray(filter_alpha(self.filter_hz, self.period), float).reshape(self.n)
        self._filtered = ~np.isnan(self.filter_hz)
        self._kp_off_key = None

    @property
    def filtered(self) -> np.ndarray:
        """Per joint: True where the KvI channel is the velocity filter, not the integral of ė."""
        return self._filtered.copy()

    def switch_joint(self, joint: int, gains: Gains[float], filter_hz: float = math.nan) -> None:
        """Stage a controller switch of ``joint`` (its gains and velocity filter, NaN: none), done
        at the start of the next tick and bumpless: the position integrator of that joint is set
        so the law's output in that tick is what the old controller would have commanded, but for
        the Kv·ė term (one sample's noise at rest; the new Kv acts on it) — the new gains then act
        on the errors from there on (ros2_control's switch: deactivate and activate in one step)."""
        if not (isinstance(joint, int) and 0 <= joint < self.n):
            raise GainError("joint", joint, f"a joint index in 0..{self.n - 1}")
        f_hz = float(filter_hz)
        if not (math.isnan(f_hz) or (math.isfinite(f_hz) and f_hz > 0.0)):  # refused now, never inside the tick
            raise GainError("velocity_filter.cutoff_hz", filter_hz, "a positive cutoff in Hz, or NaN for none", joint)
        if not isinstance(gains, Gains) or gains.n is not None:
            raise GainError("gains", gains, "one joint's Gains", joint)
        self._pending_switch[joint] = (gains, f_hz)
    # ---- live tuning ---------------------------------------------------------------------------
    def set_gains(self, kp: float | list[float] | np.ndarray | None = None,
                  kpi: float | list[float] | np.ndarray | None = None,
                  kv: float | list[float] | np.ndarray | None = None,
                  kvi: float | list[float] | np.ndarray | None = None,
                  joint: int | None = None) -> Gains[np.ndarray]:
        """Stage new gains; they take effect at the next tick (next :meth:`begin` / :meth:`update`).

        Each argument is a scalar (all joints, or only ``joint`` when given) or a per-joint list;
        ``None`` keeps the current value. Values must be finite and ≥ 0, else :class:`GainError`
        naming the gain and joint is raised and nothing changes. Returns the staged gains.
        """
        base = self._pending_gains or self.gains
        new: dict[str, np.ndarray] = {}
        for name, value in zip(GAIN_NAMES, (kp, kpi, kv, kvi), strict=True):
            cur = getattr(base, name).copy()
            if value is None:
                new[name] = cur
                continue
            if joint is not None:
                if not (isinstance(joint, int) and 0 <= joint < self.n):
                    raise GainError("joint", joint, f"a joint index in 0..{self.n - 1}")
                if np.ndim(value) != 0:
                    raise GainError(name, value, "a single number when a joint is given")
                try:
                    cur[joint] = per_joint(name, [cast(float, value)], 1)[0]  # a scalar: np.ndim checked above
                except GainError as e:
                    raise GainError(name, e.value, "a finite non-negative number", joint) from None
                new[name] = cur
            else:
                new[name] = per_joint(name, value, self.n)
        staged = Gains(**new)
        self._pending_gains = staged
        return staged

    def set_switch_off(self, config: SwitchOffConfig) -> None:
        """Stage a new switch-off configuration (takes effect at the next tick)."""
        if config.enabled.shape != (self.n,):
            raise GainError("switch_off", config.enabled.shape, f"settings for {self.n} joints")
        self._pending_switch_off = config

    # ---- derived quantities ----------------------------------------------------------------------
    def kp_off(self) -> np.ndarray:
        """Kp used while the integrators are switched off (boosted), per joint, 1/s².

        Kept per (gains, switch-off configuration) object: both are replaced, never edited, when
        they change (:meth:`set_gains`, :meth:`set_switch_off`; the gains' arrays are read-only),
        so the per-tick path does not redo the same three numpy calls twice a tick."""
        key = (self.gains, self.switch_off)
        if self._kp_off_key is None or key[0] is not self._kp_off_key[0] or key[1] is not self._kp_off_key[1]:
            # a filtered KvI channel keeps following e while the integrators are off: nothing to make up
            kvi = np.where(self._filtered, 0.0, self.gains.kvi) if self._filtered.any() else self.gains.kvi
            self._kp_off = switched_off_kp(self.gains.kp, kvi, self.switch_off.kp_boost)
            self._kp_off_key = key
        return self._kp_off.copy()

    def kp_eff(self) -> np.ndarray:
        """The position gain in force for each joint now (boosted where switched off)."""
        return np.where(self.state.integrating, self.gains.kp, self.kp_off())

    @property
    def integrating(self) -> np.ndarray:
        """Per joint: True while the integrators are fed (switch-off state "on")."""
        return self.state.integrating.copy()

    @property
    def events(self) -> list[SwitchEvent]:
        """All switch-off events so far (tick, joint, integrating, reason)."""
        return list(self.state.events)

    def reset(self) -> None:
        """Clear integrators and switch-off state (keeps gains and configuration)."""
        self.state = LawState.zeros(self.n)

    def preload(self, accel: np.ndarray) -> None:
        """Set the position integrator so that with zero errors the law's output is ``accel``
        (rad/s² per joint): ``Ie = a/Kpi`` (0 where Kpi is 0), ``Iv`` unchanged. A resume after
        a stop whose brakes held the joints takes up their loads this way (servo.loop)."""
        kpi = np.broadcast_to(np.asarray(self.gains.kpi, float), (self.n,))
        a = np.broadcast_to(np.asarray(accel, float), (self.n,))
        self.state.ie = np.where(a == 0, self.state.ie, np.divide(a, kpi, out=np.zeros(self.n), where=kpi != 0))

    # ---- the three phases of a tick ----------------------------------------------------------------
    def begin(self, tick: int, theta: np.ndarray, omega: np.ndarray, theta_d: np.ndarray,
              omega_d: np.ndarray, motion_done: bool | np.ndarray) -> None:
        """Start tick ``tick``: apply staged gains, compute errors, run the switch-off state machine."""
        if self._pending_gains is not None:
            self.gains, self._pending_gains = self._pending_gains, None
        if self._pending_switch_off is not None:
            self.switch_off, self._pending_switch_off = self._pending_switch_off, None
        self._tick = int(tick)
        e = np.asarray(theta_d, float) - np.asarray(theta, float)
        edot = np.asarray(omega_d, float) - np.asarray(omega, float)
        self._e, self._edot = e, edot
        self._switch_off_step(e, np.broadcast_to(np.asarray(motion_done, bool), (self.n,)))
        self.state.e_prev = e.copy()
        if self._pending_switch:
            self._apply_switches()

    def _accel_of(self, j: int, g: Gains[float], alpha: float, ef_prev: float) -> float:
        """Joint ``j``'s output this tick without the Kv·ė term (integrators fed as the state says)
        with gains ``g`` and a filter coefficient ``alpha`` (NaN: the integral of ė)."""
        st, T = self.state, self.period
        feed = bool(st.integrating[j])
        e, ed = float(self._e[j]), float(self._edot[j])
        ie = float(st.ie[j]) + (T * e if feed else 0.0)
        if math.isnan(alpha):
            kvi_in = float(st.iv[j]) + (T * ed if feed else 0.0)
        else:
            kvi_in = ef_prev + alpha * (e - ef_prev)
        kvi = 0.0 if not math.isnan(alpha) else g.kvi
        kp_eff = g.kp if feed else float(switched_off_kp(g.kp, kvi, float(self.switch_off.kp_boost[j])))
        # the velocity term is left out of the match: at rest ė is one sample's noise (a tach ripple,
        # an encoder count), which the integrator would keep for good; in motion it is small
        return kp_eff * e + g.kpi * ie + g.kvi * kvi_in

    def _apply_switches(self) -> None:
        """The staged per-joint controller switches (:meth:`switch_joint`), bumpless."""
        st = self.state
        if st.ef is None:
            st.ef = np.zeros(self.n)
        new = {k: np.array(getattr(self.gains, k), float) for k in GAIN_NAMES}
        hz = self.filter_hz.copy()
        for j, (g, f_hz) in sorted(self._pending_switch.items()):
            a_old = self._accel_of(j, self.gains.joint(j), float(self._alpha[j]), float(st.ef[j]))
            alpha = math.nan if math.isnan(f_hz) else float(filter_alpha(f_hz, self.period))
            if not math.isnan(alpha) and math.isnan(float(self._alpha[j])):
                st.ef[j] = self._e[j]  # primed: the filter starts where the error is
            a_new = self._accel_of(j, g, alpha, float(st.ef[j]))
            # the difference is taken up by an integrator of the new law (the torque does not step)
            if g.kpi > 0.0:
                st.ie[j] += (a_old - a_new) / g.kpi
            elif g.kvi > 0.0 and math.isnan(alpha):
                st.iv[j] += (a_old - a_new) / g.kvi
            for k in GAIN_NAMES:
                new[k][j] = getattr(g, k)
            hz[j] = f_hz
        self._pending_switch = {}
        self.gains = Gains(**new)
        self._set_filter(hz)

    def _switch_off_step(self, e: np.ndarray, done: np.ndarray) -> None:
        """The switch-off state machine of every joint at once (each joint changes at most once a
        tick; its events are recorded in joint order)."""
        st, so, T = self.state, self.switch_off, self.period
        abs_e = np.abs(e)
        # where e_prev is not finite ``crossed`` is False whatever it is replaced by: np.where is the
        # cheaper np.nan_to_num here (same result)
        finite = np.isfinite(st.e_prev)
        crossed = so.zero_crossing & finite & (e * np.where(finite, st.e_prev, 0.0) < 0)
        enabled = np.asarray(so.enabled, bool)
        integ = st.integrating.copy()  # each joint's state before this tick
        done = np.asarray(done, bool)
        # fed joints: in the inner band (or crossing zero) at the end of a motion, long enough
        feeding = enabled & integ
        near = feeding & done & ((abs_e <= so.inner_band) | crossed)
        settled = near & (st.in_band_time + 1e-12 >= so.settle_time)
        # frozen joints: a new motion, or the error left the outer band
        frozen = enabled & ~integ
        new_motion = frozen & ~done
        outside = frozen & done & (abs_e > so.outer_band)
        disabled = ~enabled & ~integ
        # the band timer runs while settling, restarts otherwise; a frozen joint's stays as it is
        st.in_band_time[:] = np.where(frozen, st.in_band_time, np.where(near & ~settled, st.in_band_time + T, 0.0))
        changed = disabled | settled | new_motion | outside
        if changed.any():
            for j in np.flatnonzero(changed).tolist():
                if disabled[j]:
                    self._event(j, True, "disabled")
                elif settled[j]:
                    self._event(j, False, "settled")
                elif new_motion[j]:
                    self._event(j, True, "new_motion")
                else:
                    self._event(j, True, "error_outside_band")

    def _event(self, j: int, integrating: bool, reason: str) -> None:
        self.state.integrating[j] = integrating
        self.state.events.append(SwitchEvent(self._tick, j, integrating, reason))

    def evaluate(self, alpha_d: np.ndarray | float = 0.0, block: np.ndarray | None = None) -> np.ndarray:
        """The normalized acceleration a_k (rad/s²) for this tick, integrating where fed and not blocked.

        ``block`` (bool per joint) withholds this tick's integration (anti-windup). Pure: may be
        called again with another ``block`` before :meth:`commit`.
        """
        g, st, T = self.gains, self.state, self.period
        feed = st.integrating.copy()
        if block is not None:
            feed &= ~np.asarray(block, bool)
        self._feed = feed
        self._ie_new = st.ie + np.where(feed, T * self._e, 0.0)
        self._iv_new = st.iv + np.where(feed, T * self._edot, 0.0)
        if self._filtered.any():  # the filter alternative to KvI where a joint uses it
            self._iv_new = np.where(self._filtered, st.iv, self._iv_new)  # ∫ė not kept where the filter serves
            ef = st.ef if st.ef is not None else np.zeros(self.n)
            self._ef_new = np.where(self._filtered, VelocityFilter.step(ef, self._e, self._alpha), ef)
            kvi_in = np.where(self._filtered, self._ef_new, self._iv_new)
            a = self.kp_eff() * self._e + g.kpi * self._ie_new + g.kv * self._edot + g.kvi * kvi_in + alpha_d
        else:
            a = self.kp_eff() * self._e + g.kpi * self._ie_new + g.kv * self._edot + g.kvi * self._iv_new + alpha_d
        self.last_accel = a
        return a

    def integration_push(self) -> np.ndarray:
        """The change of a_k (rad/s²) this tick's integration makes for joints being fed (0 elsewhere):
        T·(Kpi·e + KvI·ė). Its sign is the direction integration drives the output."""
        g, T = self.gains, self.period
        kvi = np.where(self._filtered, 0.0, g.kvi) if self._filtered.any() else g.kvi  # a filter is no integrator
        return np.where(self.state.integrating, T * (g.kpi * self._e + kvi * self._edot), 0.0)

    def commit(self) -> None:
        """Store the integrator values of the last :meth:`evaluate`."""
        self.state.ie = self._ie_new.copy()
        self.state.iv = self._iv_new.copy()
        if self._filtered.any():
            self.state.ef = self._ef_new.copy()

    @property
    def fed(self) -> np.ndarray:
        """Per joint: whether the integrators were fed in the last evaluated tick."""
        return self._feed.copy()

    # ---- one-shot ---------------------------------------------------------------------------------
    def update(self, theta: np.ndarray, omega: np.ndarray, theta_d: np.ndarray, omega_d: np.ndarray,
               alpha_d: np.ndarray | float = 0.0, motion_done: bool | np.ndarray = False,
               tick: int | None = None) -> np.ndarray:
        """One whole tick without a limiter: returns a_k in rad/s² (see the module docstring)."""
        self.begin(self._tick + 1 if tick is None else tick, theta, omega, theta_d, omega_d, motion_done)
        a = self.evaluate(alpha_d)
        self.commit()
        return a

    # ---- state transfer (controller swap) -----------------------------------------------------------
    def export_state(self) -> LawState:
        return self.state.copy()

    def import_state(self, state: LawState) -> None:
        if state.ie.shape != (self.n,):
            raise GainError("state", state.ie.shape, f"a law state for {self.n} joints")
        self.state = state.copy()
