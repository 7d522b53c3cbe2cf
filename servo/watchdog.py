"""The servo watchdog's limits and its sensor/actuator cross-checks.

:class:`WatchdogConfig` holds every limit (SI units, arrays over joints where per joint).
:class:`CrossChecks` compares, once per tick and vectorised over the joints, what two
independent paths say about the same physical quantity — a single failed sensor or actuator
then shows as a disagreement within a few ticks, long before the following error grows:

* **position** — encoder against pot (joints with both): their travel since the last
  reference must agree within ``position_tolerance_rad + position_tolerance_fraction·travel``
  (the fraction covers an uncalibrated pot's non-linearity; a calibration applied at run time
  re-references). A homed encoder (``io.homed``) reads the absolute angle: it is compared with
  the pot absolutely (its reference is the pot's own at the reference tick).
* **velocity** — tachometer against the position derivative (the encoder where wired, else the
  pot), both integrated over the same window of ``velocity_window_ticks``: the tach's mean may
  differ from the mean speed by at most its dead band (it reads ``ω − dead band·sign ω`` above
  it, zero below) plus ``velocity_tolerance_rad_s`` and ``velocity_tolerance_fraction`` of the
  speed (commutator ripple). Both integrals run over the time the samples were taken at: one
  period per tick, or, where the loop is told each sample's time (a free-running plant, whose
  answers may skip or repeat a period), that time over the last ``velocity_window_ticks`` new
  samples (a repeated sample adds nothing; the window then spans more periods). A fault
  that keeps the tach's reading inside that envelope — a tach stuck at 0 V while the joint
  moves slower than its dead band — is undetectable by construction, and harmless (the loop
  gets no velocity feedback there anyway).
* **current** — the current monitor against the current the drivers commanded one tick
  earlier (the command of tick k takes effect 1 ms after t_k, and the monitor is sampled at
  t_k+1): beyond ``current_tolerance_a + current_tolerance_fraction·|i|`` for
  ``current_mismatch_ticks`` ticks in a row (a dead DAC channel, an amplifier that is not
  enabled, a broken motor lead).
* **stale position while moving** — the position reading stays within ±``stale_band_lsb``
  steps of where it was for at least ``stale_ticks`` while the target moves on by
  ``stale_travel_rad``. A joint held by stiction at the start of a move lags its target by
  less than that; the band (not bit-equality) keeps ADC noise on a frozen signal from hiding it.

* **illegal quadrature transitions** — a decoder flags ILLEGAL when A and B change in one of its
  input samples: counts were lost. Motion alone cannot do that below one x4 count per decoder
  sample; at a joint's top speed a healthy encoder gives far fewer (jpl-arm: 20 °/s · 200 000
  counts/rev = 89 counts per 8 ms period against the decoder's 8 000 samples in it, 1 MHz: 90×
  margin), so a healthy encoder never sets it. A single noise spike (a lost count or two) is
  harmless; the check trips when ILLEGAL is seen in ``encoder_illegal_ticks`` (3) ticks of the
  last ``encoder_illegal_window_ticks`` (125, 1 s) — a noisy or failing encoder within 24 ms.

Defaults (``None`` in the config) are derived per joint from the sensors' nominal resolution
(:meth:`servo.io.JointIO.resolution`) and the tach dead band; docs/faults.md says how.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

#: Position sensor steps of uncertainty in the encoder/pot comparison: the pot's reference sample
#: (noise ≈ ⅓ code, quantization ½ code, taken twice) and its non-linearity between calibration
#: points; the largest disagreement of healthy jpl-arm and melmalec-16 runs is 5 pot codes.
POSITION_TOLERANCE_POT_CODES = 8.0
#: Steps of the reference position over the velocity window (quantization and noise at both ends).
VELOCITY_TOLERANCE_REF_STEPS = 4.0
#: Tach ADC codes of uncertainty in the window mean (offset, noise, filter lag).
VELOCITY_TOLERANCE_TACH_CODES = 4.0
#: Current-monitor codes of uncertainty (ADC and DAC offsets of an uncalibrated crate ≈ 4 codes).
CURRENT_TOLERANCE_MONITOR_CODES = 10.0
#: An H-bridge's current follows its PWM duty only as well as the voltage model (R·i + Ke·ω from
#: the measured speed, no inductance) predicts it: a quarter of the current limit.
HBRIDGE_CURRENT_TOLERANCE_OF_LIMIT = 0.25
#: Largest target travel (rad) during which a healthy joint's reading may stay put: breakaway
#: from stiction at the start of a move lags by < 0.9° on both presets; twice that less a bit.
STALE_TRAVEL_RAD = float(np.radians(1.5))
#: A target speed (rad/s) below which the joint is not "commanded to move".
MOVING_RAD_S = 1e-3


@dataclass
class WatchdogConfig:
    """Limits of the watchdog (SI units; arrays over joints where per joint; ``None`` or NaN:
    derived from the sensors' resolution when the loop is built, see :class:`CrossChecks`)."""

    following_error_rad: np.ndarray
    max_jump_rad: float = 0.2
    pot_rail_v: float = 9.95
    stale_ticks: int = 25
    enabled: bool = True
    #: the position, velocity and current cross-checks (False: off; the stale check stays)
    cross_checks: bool = True
    stale_band_lsb: float = 2.0
    stale_travel_rad: np.ndarray | None = None
    position_tolerance_rad: np.ndarray | None = None
    position_tolerance_fraction: float = 0.02
    tach_dead_band_rad_s: np.ndarray | None = None
    velocity_window_ticks: int = 12
    velocity_tolerance_rad_s: np.ndarray | None = None
    velocity_tolerance_fraction: float = 0.05
    current_tolerance_a: np.ndarray | None = None
    current_tolerance_fraction: np.ndarray | None = None
    current_mismatch_ticks: int = 3
    #: ticks an answer may lag the command behind lockstep timing (0: the current monitor reads
    #: the previous tick's command, as in lockstep; a free-running plant answers 1-2 periods late):
    #: the current check then accepts any command of the last ``1 + command_lag_ticks`` ticks
    command_lag_ticks: int = 0
    #: ticks whose decoder read found ILLEGAL set, within the last ``encoder_illegal_window_ticks``,
    #: that stop the loop (cause ``encoder_illegal``; a healthy encoder never sets it, see above)
    encoder_illegal_ticks: int = 3
    encoder_illegal_window_ticks: int = 125
    #: the soft limits per joint (rad; ±inf or ``None``: none) and the margin a measured position
    #: may pass one by before the loop stops with cause ``soft_limit`` (category 1)
    soft_min_rad: np.ndarray | None = None
    soft_max_rad: np.ndarray | None = None
    soft_limit_margin_rad: float = float(np.radians(0.5))

    @classmethod
    def from_lanes(cls, configs: Sequence[WatchdogConfig]) -> WatchdogConfig:
        """One config for B lanes (batched lockstep, :mod:`hal.lanes`): per-joint limits
        concatenated lane-major; a rig-wide limit must be the same in every lane."""
        first = configs[0]
        values: dict[str, Any] = {}
        for f in fields(cls):
            vs = [getattr(c, f.name) for c in configs]
            if any(isinstance(v, np.ndarray) for v in vs):
                if not all(isinstance(v, np.ndarray) and v.ndim == 1 for v in vs):
                    raise NotImplementedError(f"watchdog {f.name}: set in some lanes only; they cannot run as lanes")
                values[f.name] = np.concatenate([np.asarray(v, float) for v in vs])
            elif all(v == vs[0] or (v != v and vs[0] != vs[0]) for v in vs):
                values[f.name] = vs[0]
            else:
                raise NotImplementedError(f"watchdog {f.name}: lanes differ ({vs[0]!r}, …); they cannot run as lanes")
        del first
        return cls(**values)

    def _soft_bounds(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        lo = np.full(n, -np.inf) if self.soft_min_rad is None else np.asarray(self.soft_min_rad, float)
        hi = np.full(n, np.inf) if self.soft_max_rad is None else np.asarray(self.soft_max_rad, float)
        return lo, hi

    def soft_limits(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The soft limits of ``n`` joints (rad), −inf / +inf where a joint has none."""
        return self._soft_bounds(n)

    def past_soft_limit(self, theta: np.ndarray) -> np.ndarray:
        """Per joint how far past its soft limit ``theta`` is (rad; ≤ 0 inside, −inf: no limit
        or no reading)."""
        th = np.asarray(theta, float)
        lo, hi = self._soft_bounds(th.shape[0])
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(th), np.maximum(lo - th, th - hi), -np.inf)

    def beyond_soft_limit(self, theta: np.ndarray,
                          allow_rad: np.ndarray | None = None) -> tuple[int, float, float, str] | None:
        """The joint furthest past a soft limit by more than the margin (or, per joint, by more
        than ``allow_rad``: a joint a stop left past its limit may come back, not go further):
        ``(joint, position, limit, "min"|"max")`` (rad), or ``None``. Non-finite readings are the
        sensor checks' to judge."""
        if self.soft_min_rad is None and self.soft_max_rad is None:
            return None
        th = np.asarray(theta, float)
        allow = np.full(th.shape, self.soft_limit_margin_rad) if allow_rad is None else np.asarray(allow_rad, float)
        over = self.past_soft_limit(th) - allow
        i = int(np.argmax(over))
        if not over[i] > 0.0:
            return None
        lo, hi = self._soft_bounds(th.shape[0])
        if th[i] < lo[i]:
            return i, float(th[i]), float(lo[i]), "min"
        return i, float(th[i]), float(hi[i]), "max"


@dataclass
class Trip:
    """A cross-check that failed: the stop's cause, the joint and what disagreed."""

    cause: str
    joint: int
    detail: str


def _per_joint(value: Any, default: np.ndarray) -> np.ndarray:
    """``value`` per joint, ``default`` where it is ``None`` or NaN."""
    if value is None:
        return default
    v = np.broadcast_to(np.asarray(value, float), default.shape)
    return np.where(np.isnan(v), default, v)


def _worst(bad: np.ndarray, off: np.ndarray, tol: np.ndarray | float) -> int | None:
    """The joint furthest beyond its limit among ``bad`` (None: no joint is)."""
    if not bad.any():
        return None
    return int(np.argmax(np.where(bad, off - tol, -np.inf)))


def _worst_lanes(bad: np.ndarray, off: np.ndarray, tol: np.ndarray | float,
                 size: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_worst` per lane of a lane-major array of ``size`` lanes: which lanes have a joint
    beyond its limit, and per lane the flat index of the one furthest beyond (as ``_worst`` picks it)."""
    rows = bad.reshape(size, -1)
    hit = np.asarray(rows.any(axis=1))
    n = rows.shape[1]
    worst = np.argmax(np.where(bad, off - tol, -np.inf).reshape(size, n), axis=1) + np.arange(size) * n
    return hit, worst


Verdict = tuple[str, np.ndarray, np.ndarray, "np.ndarray | float", Callable[[int], str]]
"""What one cross-check found this tick: its cause, the joints beyond their limits, how far off
each joint is and its limit, and the detail of a joint's trip."""


def _trip(v: Verdict | None) -> Trip | None:
    """A check's verdict for one instance: the trip of its joint furthest beyond its limit."""
    if v is None:
        return None
    cause, bad, off, tol, detail = v
    i = _worst(bad, off, tol)
    return None if i is None else Trip(cause, i, detail(i))


LaneTrip = tuple[str, np.ndarray, np.ndarray, Callable[[int], str]]
"""A cross-check in lanes: its cause, per lane whether it tripped, per lane the flat index of the
joint, and the scalar trip's detail for a flat joint index."""


def _deg(rad: float) -> str:
    return f"{np.degrees(rad):+.2f}°"


class CrossChecks:
    """The per-tick cross-checks of one loop (state: references, windows, counters).

    ``io``: the loop's drivers; without :meth:`~servo.io.JointIO.resolution` (a test double)
    there is nothing to cross-check and :meth:`check` never trips.
    """

    def __init__(self, io: Any, config: WatchdogConfig) -> None:
        self.io = io
        self.config = config
        self.n = n = io.n
        self.period_s = float(io.period_s)
        res = io.resolution() if hasattr(io, "resolution") else None
        nan = np.full(n, np.nan)
        self.pot_rad = res.pot_rad if res is not None else nan
        self.enc_rad = res.encoder_rad if res is not None else nan
        self.tach_rad_s = res.tach_rad_s if res is not None else nan
        self.has_pot = np.isfinite(self.pot_rad)
        self.has_enc = np.isfinite(self.enc_rad)
        self.has_tach = np.isfinite(self.tach_rad_s)
        self.has_imon = np.isfinite(res.monitor_a) if res is not None else np.zeros(n, bool)
        self.both = self.has_pot & self.has_enc
        self.window = max(1, int(config.velocity_window_ticks))
        window_s = self.window * self.period_s
        #: the position the tach is compared with: the encoder where wired (finer), else the pot
        self.ref_rad = np.where(self.has_enc, self.enc_rad, self.pot_rad)
        #: the reading the stale check watches: the pot where wired, else the encoder (as before)
        self.stale_rad = np.where(self.has_pot, self.pot_rad, self.enc_rad)
        zero = np.zeros(n)
        self.defaults = {
            "position_tolerance_rad": np.nan_to_num(POSITION_TOLERANCE_POT_CODES * self.pot_rad + 2 * self.enc_rad),
            "tach_dead_band_rad_s": zero,
            "velocity_tolerance_rad_s": np.nan_to_num(VELOCITY_TOLERANCE_REF_STEPS * self.ref_rad / window_s
                                                      + VELOCITY_TOLERANCE_TACH_CODES * self.tach_rad_s),
            "stale_travel_rad": np.full(n, STALE_TRAVEL_RAD),
        }
        if res is not None:
            lin = res.linear
            self.defaults["current_tolerance_a"] = np.nan_to_num(np.where(
                lin, CURRENT_TOLERANCE_MONITOR_CODES * res.monitor_a + 2 * np.nan_to_num(res.command_a),
                HBRIDGE_CURRENT_TOLERANCE_OF_LIMIT * res.current_limit_a))
            self.defaults["current_tolerance_fraction"] = np.where(lin, 0.05, 0.2)
        else:
            self.defaults["current_tolerance_a"] = zero
            self.defaults["current_tolerance_fraction"] = zero
        self._limits_key: tuple[int, ...] = ()
        self._limits: dict[str, np.ndarray] = {}
        self._ratio = np.zeros(n)
        #: the lanes these checks serve (batched lockstep, :meth:`from_lanes`); 1: one instance
        self.lane_size = 1
        self.reset()

    @classmethod
    def from_lanes(cls, checks: Sequence[CrossChecks], io: Any, config: WatchdogConfig, size: int) -> CrossChecks:
        """The cross-checks of B lanes (batched lockstep, :mod:`hal.lanes`): every per-joint array
        (resolutions, limits, references, windows, counters) concatenated lane-major (the windows'
        rings along their joint axis); the lanes' times and counts must agree. :meth:`check_lanes`
        checks every lane as its scalar :meth:`check` does."""
        first = checks[0]
        n = first.n
        for c in checks:
            if c.n != n or c.window != first.window or c.period_s != first.period_s or c._slot != first._slot \
                    or c._filled != first._filled or c._tick != first._tick or c._last_t != first._last_t \
                    or c._generation != first._generation or c._illegal_seen \
                    or not np.array_equal(c._ring_t, first._ring_t) \
                    or len(c._cur_history) != len(first._cur_history) \
                    or (c._last_theta_d is None) != (first._last_theta_d is None):
                raise NotImplementedError("lanes' cross-checks are not at the same point: they cannot run as lanes")

        def cat(values: list[Any]) -> np.ndarray:
            return np.concatenate(values, axis=-1)

        obj = cls.__new__(cls)
        obj.io = io
        obj.config = config
        obj.n = n * size
        obj.period_s = first.period_s
        for name in ("pot_rad", "enc_rad", "tach_rad_s", "has_pot", "has_enc", "has_tach", "has_imon", "both",
                     "ref_rad", "stale_rad", "_pot0", "_enc0", "_ring_ref", "_ring_int", "_tach_int", "_last_tach",
                     "_cur_over", "_stale_at", "_stale_count", "_stale_travel"):
            setattr(obj, name, cat([getattr(c, name) for c in checks]))
        obj.window = first.window
        obj.defaults = {k: cat([c.defaults[k] for c in checks]) for k in first.defaults}
        obj._limits_key = ()
        obj._limits = {}
        obj._ratio = np.zeros(obj.n)
        obj._generation = first._generation
        obj._slot, obj._filled, obj._ring_t = first._slot, first._filled, first._ring_t.copy()
        obj._last_t, obj._tick = first._last_t, first._tick
        obj._cur_history = deque((np.concatenate(rows) for rows in zip(*(c._cur_history for c in checks), strict=True)),
                                 maxlen=first._cur_history.maxlen)
        obj._last_theta_d = None if first._last_theta_d is None else cat([c._last_theta_d for c in checks])
        obj._illegal_seen = {}
        obj.peak_ratio = {k: cat([c.peak_ratio[k] for c in checks]) for k in first.peak_ratio}
        obj.lane_size = size
        return obj

    def limit(self, name: str) -> np.ndarray:
        """The limit in force for ``name`` (the config's, else the derived default), per joint."""
        key = (id(self.config), *(id(getattr(self.config, f)) for f in self.defaults))
        if key != self._limits_key:  # resolved once per config (the per-tick path only looks up)
            self._limits = {f: _per_joint(getattr(self.config, f), d) for f, d in self.defaults.items()}
            self._limits_key = key
        return self._limits[name]

    def reset(self) -> None:
        """Forget references and windows (start, resume: the joints may have moved meanwhile)."""
        n, w = self.n, self.window
        self._generation: int | None = None
        self._pot0 = np.full(n, np.nan)
        self._enc0 = np.full(n, np.nan)
        self._ring_ref = np.zeros((w + 1, n))
        self._ring_int = np.zeros((w + 1, n))
        self._slot = 0
        self._filled = 0
        self._ring_t = np.zeros(w + 1)
        self._tach_int = np.zeros(n)
        self._last_tach = np.zeros(n)
        self._last_t = 0.0
        self._cur_over = np.zeros(n, int)
        self._cur_history: deque[np.ndarray] = deque(maxlen=1 + max(0, int(self.config.command_lag_ticks)))
        self._stale_at = np.full(n, np.nan)
        self._stale_count = np.zeros(n, int)
        self._stale_travel = np.zeros(n)
        self._last_theta_d: np.ndarray | None = None
        self._tick = 0
        #: per joint with ILLEGAL seen in the window: the ticks it was seen at
        self._illegal_seen: dict[int, deque[int]] = {}
        #: per check and joint, the largest disagreement seen as a fraction of its limit (1 trips):
        #: how close a healthy run came (reports, tests)
        self.peak_ratio = {name: np.zeros(n) for name in ("position", "velocity", "current")}

    def _over(self, name: str, off: np.ndarray, tol: np.ndarray, wired: np.ndarray) -> np.ndarray:
        """Where ``off`` exceeds ``tol`` (wired joints only); keeps :attr:`peak_ratio` up to date."""
        ratio = self._ratio
        ratio[:] = 0.0
        np.divide(off, tol, out=ratio, where=wired & (tol > 0.0))
        np.fmax(self.peak_ratio[name], ratio, out=self.peak_ratio[name])
        return wired & (off > tol)

    # --- per tick ---------------------------------------------------------------------------
    def check(self, m: Any, theta_d: np.ndarray, omega_d: np.ndarray,
              sample_time_s: float | None = None) -> Trip | None:
        """Update every check with this tick's measurement and target; the first that fails.

        ``sample_time_s``: when the measurement was taken (s, the plant's time): given by a
        free-running plant, whose answers may skip or repeat periods; ``None``: one period per
        tick (lockstep, a real rig's sampled loop)."""
        self._begin_tick(m)
        stale = _trip(self._stale(m, np.asarray(theta_d, float), np.asarray(omega_d, float)))
        illegal = self._illegal(m)
        if not self.config.cross_checks:
            return illegal or stale
        return (illegal or _trip(self._current(m)) or _trip(self._velocity(m, sample_time_s))
                or _trip(self._position(m)) or stale)

    def _begin_tick(self, m: Any) -> None:
        generation = getattr(self.io, "calibration_generation", 0)
        if generation != self._generation:  # a new calibration: readings convert differently now
            self._generation = generation
            self._pot0 = np.where(self.both, m.theta_pot, np.nan)
            # a homed encoder reads the joint's absolute angle: its reference is the pot's, so
            # the two are compared absolutely (docs/motion-safety.md, "Homing")
            homed = getattr(self.io, "homed", None)
            enc0 = m.theta_enc if homed is None else np.where(homed, m.theta_pot, m.theta_enc)
            self._enc0 = np.where(self.both, enc0, np.nan)
            self._filled = 0
        self.limit("stale_travel_rad")  # the limits in force, resolved once for this tick's checks

    def _illegal(self, m: Any) -> Trip | None:
        """ILLEGAL seen in ``encoder_illegal_ticks`` of the last ``encoder_illegal_window_ticks``."""
        self._tick += 1
        flags = getattr(m, "encoder_illegal", None)
        seen = self._illegal_seen
        if flags is None or len(flags) != self.n or (not seen and not flags.any()):
            return None  # the healthy path: nothing flagged now or in the window
        window = max(1, int(self.config.encoder_illegal_window_ticks))
        for flagged in np.flatnonzero(flags):
            seen.setdefault(int(flagged), deque()).append(self._tick)
        worst: int | None = None
        most = 0
        for joint, ticks in list(seen.items()):
            while ticks and ticks[0] <= self._tick - window:
                ticks.popleft()
            if not ticks:
                del seen[joint]
            elif len(ticks) > most:
                worst, most = joint, len(ticks)
        if worst is None or most < max(1, int(self.config.encoder_illegal_ticks)):
            return None
        return Trip("encoder_illegal", worst,
                    f"the quadrature decoder flagged illegal transitions (A and B changed in one sample: counts "
                    f"lost) in {most} of the last {window} ticks (limit {self.config.encoder_illegal_ticks}): "
                    "a noisy or failing encoder, or a shaft faster than the decoder samples")

    # Each cross-check below updates its state with the tick's readings and gives its verdict (the
    # joints beyond their limits, how far off, the limits, the text of a joint's trip); one joint's
    # worst in a scalar loop (_trip), each lane's in a loop of lanes (_lane_trips).
    def _position(self, m: Any) -> Verdict | None:
        if not self.both.any():
            return None
        d_pot = m.theta_pot - self._pot0
        d_enc = m.theta_enc - self._enc0
        travel = np.fmax(np.abs(d_pot), np.abs(d_enc))
        tol = self._limits["position_tolerance_rad"] + self.config.position_tolerance_fraction * travel
        off = np.abs(d_enc - d_pot)

        def detail(i: int) -> str:
            return (f"pot and encoder disagree by {np.degrees(off[i]):.2f}° (limit {np.degrees(tol[i]):.2f}°): "
                    f"since the reference the pot moved {_deg(d_pot[i])}, the encoder {_deg(d_enc[i])}")
        return "position_mismatch", self._over("position", off, tol, self.both), off, tol, detail

    def _velocity(self, m: Any, t_s: float | None = None) -> Verdict | None:
        if not self.has_tach.any():
            return None
        tach = np.where(self.has_tach, m.omega_tach, 0.0)
        ref = np.where(self.has_enc, m.theta_enc, m.theta_pot)
        w = self.window
        dt = self.period_s if t_s is None else t_s - self._last_t
        if t_s is not None and self._filled and dt <= 0.0:
            return None  # the same sample again (a free-running plant did not step): nothing new
        if self._filled == 0:
            self._tach_int[:] = 0.0
        else:  # trapezoid: the tach is integrated over exactly the interval the positions span
            self._tach_int += 0.5 * dt * (tach + self._last_tach)
        self._last_tach = tach
        self._slot = (self._slot + 1) % (w + 1)
        self._ring_ref[self._slot] = ref
        self._ring_int[self._slot] = self._tach_int
        if t_s is not None:  # (untimed, the window is w periods: no times to keep)
            self._last_t = self._ring_t[self._slot] = t_s
        self._filled = min(self._filled + 1, w + 1)
        if self._filled <= w:
            return None
        old = (self._slot + 1) % (w + 1)
        # timed: the window is the last w new samples, at least w periods of the plant's time
        window_s = w * self.period_s if t_s is None else t_s - self._ring_t[old]
        v_ref = (ref - self._ring_ref[old]) / window_s
        v_tach = (self._tach_int - self._ring_int[old]) / window_s
        off = np.abs(v_tach - v_ref)
        tol = (self._limits["tach_dead_band_rad_s"] + self._limits["velocity_tolerance_rad_s"]
               + self.config.velocity_tolerance_fraction * np.fmax(np.abs(v_ref), np.abs(v_tach)))

        def detail(i: int) -> str:
            src = "encoder" if self.has_enc[i] else "pot"
            return (f"tachometer and {src} disagree: over the last {window_s * 1e3:.0f} ms the tach averaged "
                    f"{v_tach[i]:+.3f} rad/s, the {src} moved at {v_ref[i]:+.3f} rad/s "
                    f"(limit ±{tol[i]:.3f} rad/s, dead band included)")
        return "velocity_mismatch", self._over("velocity", off, tol, self.has_tach), off, tol, detail

    def _current(self, m: Any) -> Verdict | None:
        if not self.has_imon.any():
            return None
        commanded = np.asarray(self.io.last_current_a, float)
        if self._cur_history.maxlen == 1:  # lockstep: the previous tick's command
            off = np.abs(m.current - commanded)
            largest = np.abs(commanded)
        else:  # a lagging answer: how far the monitor is from every command it may be answering
            self._cur_history.append(commanded.copy())
            lo, hi = np.min(self._cur_history, axis=0), np.max(self._cur_history, axis=0)
            off = np.maximum(np.maximum(lo - m.current, m.current - hi), 0.0)
            largest = np.maximum(np.abs(lo), np.abs(hi))
        tol = self._limits["current_tolerance_a"] + self._limits["current_tolerance_fraction"] * largest
        cur_over = self._cur_over = np.where(self._over("current", off, tol, self.has_imon), self._cur_over + 1, 0)

        def detail(i: int) -> str:
            return (f"current monitor reads {m.current[i]:+.3f} A, {commanded[i]:+.3f} A commanded "
                    f"(limit ±{tol[i]:.3f} A) for {cur_over[i]} ticks: no current reaches the motor?")
        return "current_mismatch", cur_over >= max(1, int(self.config.current_mismatch_ticks)), off, tol, detail

    def _stale(self, m: Any, theta_d: np.ndarray, omega_d: np.ndarray) -> Verdict:
        cfg = self.config
        reading = np.where(self.has_pot, m.theta_pot, m.theta_enc)
        band = cfg.stale_band_lsb * self.stale_rad
        step = np.zeros(self.n) if self._last_theta_d is None else np.abs(theta_d - self._last_theta_d)
        self._last_theta_d = theta_d.copy()
        keep = (np.abs(reading - self._stale_at) <= band) & (np.abs(omega_d) > MOVING_RAD_S)
        count = self._stale_count = np.where(keep, self._stale_count + 1, 0)
        travel = self._stale_travel = np.where(keep, self._stale_travel + step, 0.0)
        self._stale_at = np.where(keep, self._stale_at, reading)
        bad = (count >= cfg.stale_ticks) & (travel >= self._limits["stale_travel_rad"])

        def detail(i: int) -> str:
            src = "pot" if self.has_pot[i] else "encoder"
            return (f"{src} reading within ±{cfg.stale_band_lsb:g} steps for {count[i]} ticks while the "
                    f"target moved {np.degrees(travel[i]):.2f}°")
        return "stale_sensor", bad, travel, 0.0, detail

    # --- per tick, in lanes (batched lockstep) -------------------------------------------------
    def check_lanes(self, m: Any, theta_d: np.ndarray, omega_d: np.ndarray,
                    sample_time_s: float | None = None) -> list[LaneTrip]:
        """:meth:`check` for every lane of a lane-major stack (:meth:`from_lanes`): the same state
        updates, elementwise, then per lane the checks that failed, in :meth:`check`'s order (the
        first is the lane's cause; its scalar run stops there). A lane that trips no longer counts:
        the caller ejects it, so it does not matter that its later checks still updated its state."""
        self._begin_tick(m)
        stale = self._lane_trips(self._stale(m, np.asarray(theta_d, float), np.asarray(omega_d, float)))
        trips = self._illegal_lanes(m)
        if self.config.cross_checks:
            trips += (self._lane_trips(self._current(m)) + self._lane_trips(self._velocity(m, sample_time_s))
                      + self._lane_trips(self._position(m)))
        return trips + stale

    def _lane_trips(self, v: Verdict | None) -> list[LaneTrip]:
        """A check's verdict per lane: the lanes it trips and each one's worst joint."""
        if v is None or not v[1].any():
            return []
        cause, bad, off, tol, detail = v
        hit, worst = _worst_lanes(bad, off, tol, self.lane_size)
        return [(cause, hit, worst, detail)]

    def _illegal_lanes(self, m: Any) -> list[LaneTrip]:
        """In lanes a decoder's ILLEGAL flag already ejected its lane (its scalar run clears the flag:
        a bus cycle the others do not make, :meth:`servo.io.JointIO.read`): one flag is one trip here."""
        self._tick += 1
        flags = getattr(m, "encoder_illegal", None)
        if flags is None or len(flags) != self.n or not flags.any():
            return []
        hit = np.asarray(flags, bool).reshape(self.lane_size, -1)
        worst = np.argmax(hit, axis=1) + np.arange(self.lane_size) * hit.shape[1]
        return [("encoder_illegal", np.asarray(hit.any(axis=1)), worst,
                 lambda i: "the quadrature decoder flagged an illegal transition")]

    def write_lane(self, lane: int, checks: CrossChecks) -> None:
        """Put lane ``lane``'s state of these lane cross-checks into ``checks`` (its scalar ones)."""
        n = checks.n
        sl = slice(lane * n, (lane + 1) * n)
        for name in ("_pot0", "_enc0", "_tach_int", "_last_tach", "_cur_over", "_stale_at", "_stale_count",
                     "_stale_travel"):
            setattr(checks, name, getattr(self, name)[sl].copy())
        checks._ring_ref, checks._ring_int = self._ring_ref[:, sl].copy(), self._ring_int[:, sl].copy()
        checks._ring_t = self._ring_t.copy()
        checks._generation, checks._slot, checks._filled = self._generation, self._slot, self._filled
        checks._last_t, checks._tick = self._last_t, self._tick
        checks._cur_history = deque((h[sl].copy() for h in self._cur_history), maxlen=checks._cur_history.maxlen)
        checks._last_theta_d = None if self._last_theta_d is None else self._last_theta_d[sl].copy()
        checks.peak_ratio = {k: v[sl].copy() for k, v in self.peak_ratio.items()}
