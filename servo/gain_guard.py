"""The gain guard: may this gain set be used on the servo? One rule for every entry point.

The console (``gains``), MAVLink (``PARAM_SET`` of ``J<n>_K*`` and of the switch-off boost),
``vmehil run --gains`` / ``vmehil console --gains``, ``vmehil tune`` and the sweeps all ask
:func:`judge` (through :func:`check_gain_change` where a live :class:`~servo.control.law.PidLaw`
is involved), so the same gain set gets the same verdict and the same reason everywhere. Sweeps
classify a refused point (``stable = false``) instead of refusing the sweep.

**Values** (:func:`value_problem`, verdict kind ``"invalid"``): a gain is one of ``kp``, ``kpi``,
``kv``, ``kvi``; a finite number ≥ 0 (:func:`servo.control.gains.gain_value_problem`); not
subnormal (a non-zero value below 2.2e-308 has lost its precision, and the pole it sets sits
within rounding of z = 1 anyway: use 0); at most :data:`GAIN_MAX` (the ranges MAVLink
advertises; at 125 Hz every limit is far beyond a stable loop, so 1e30 is a typo, not a tuning).

**Stability** (verdict kind ``"unstable"``) of the sampled closed loop of the normalized joint — the
ideal plant θ'' = a, whose continuous loop is s³ + Kv·s² + (Kp+KvI)·s + Kpi — as the servo runs
it: :func:`servo.control.linear.sampled_loop_matrix` (the PidLaw's backward-Euler integrators,
zero-order hold, exact discretisation at the servo period T, computation delay ``delay``·T):

* not Kpi = 0 with KvI > 0: the polynomial's root s = 0 is a loop pole at exactly z = 1 (the KvI
  integrator holds whatever offset it has, nothing brings the joint back to its target);
* every loop pole strictly inside the unit circle with margin 1 − ρ > ``min_margin`` (and at
  least :data:`MIN_MARGIN_FLOOR`, so rounding never decides);
* where the switch-off is enabled, the same for the switched-off loop (integrators frozen, Kp_eff
  = the boosted Kp, :func:`servo.control.law.switched_off_kp`).

The sampled-loop state ``[θ, ω, Ie, Iv]`` has one structural eigenvalue at exactly z = 1 that is
not a loop pole: only ``S = Kpi·Ie + KvI·Iv`` acts on the plant; ``R = KvI·Ie − Kpi·Iv`` is fed
but never read back. :func:`loop_poles` removes it by that change of coordinates — a scaled
rotation, so exact and perfectly conditioned — before the eigenvalues are taken; a genuine slow
pole near z = 1 (a tiny Kpi) is never mistaken for it.

Why this guard and not the one MAVLink had (the former ``vmehil.mavlink.stability``, merged here): both
removed the structural eigenvalue (it by projecting onto ``[θ, ω, S]`` with a pseudo-inverse, the
same poles to rounding) and tested 1 − ρ, but it decided the marginal Kpi = 0, KvI > 0 loop by
the sign of a ±1e-16 rounding residue, accepted negative gains whenever the eigenvalues happened
to lie inside the circle (a negative gain is positive feedback the law refuses anyway), and had
no upper limits. This one refuses the marginal loop for its physical reason, judges values first,
and keeps a rounding floor under the margin.

Use::

    from servo.gain_guard import GainRejected, check_gain_change, judge
    check_gain_change(loop.law, joint=0, changes={"kp": 120.0}, period_s=loop.period_s, delay=0.125)
    loop.law.set_gains(kp=120.0, joint=0)      # only after the check passed
    judge(Gains(kp=120, kpi=5000, kv=50, kvi=1000), 0.008, 0.125).ok      # a verdict, never raises
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from servo.control.errors import GainRejected
from servo.control.gains import GAIN_NAMES, Gains, gain_value_problem
from servo.control.law import switched_off_kp
from servo.control.linear import sampled_loop_matrix
from servo.control.velocity_filter import VelocityFilter

__all__ = ["GAIN_MAX", "MIN_MARGIN_FLOOR", "GainRejected", "GainVerdict", "check_gain_change", "check_gain_set",
           "check_values",
           "judge", "loop_poles", "spectral_radius", "value_problem"]

# The stability margin 1 − ρ must exceed this at least (strictly inside the unit circle, with a hair
# for rounding: 1e-12 per tick is a time constant of ~250 million years at 125 Hz).
MIN_MARGIN_FLOOR = 1e-12
# A pole this close to the unit circle (either side) is marginal, not unstable: rounding decides its side.
_MARGINAL = 1e-9
#: Upper limits of the gains (the ranges the MAVLink parameters advertise).
GAIN_MAX: dict[str, float] = {"kp": 1e5, "kpi": 1e7, "kv": 1e4, "kvi": 1e6}


@dataclass(frozen=True)
class GainVerdict:
    """What :func:`judge` says about one joint's gain set.

    ``ok``; ``kind`` ``"ok"``, ``"invalid"`` (a value no gain may have) or ``"unstable"`` (unstable or
    marginal sampled loop); ``reason`` (``"stable"`` when ok, else why not and what to do);
    ``margin_integrating`` and ``margin_switched_off`` the stability margins 1 − ρ (dimensionless,
    NaN where not computed: invalid values, or the switch-off not checked).
    """

    ok: bool
    kind: str
    reason: str
    margin_integrating: float = math.nan
    margin_switched_off: float = math.nan

    def raise_if_refused(self, shown: str, joint: int | None = None) -> None:
        """Raise :class:`GainRejected` (``shown``: the gain change as the user wrote it) unless ok."""
        if not self.ok:
            raise GainRejected(shown, None, self.reason, joint, kind=self.kind)


# ---- values -----------------------------------------------------------------------------------------
def value_problem(name: str, value: Any) -> str | None:
    """Why ``value`` may not be gain ``name`` (a sentence naming the gain), or None."""
    if name not in GAIN_NAMES:
        return f"unknown gain {name!r}; use kp, kpi, kv or kvi"
    problem = gain_value_problem(value)
    if problem is not None:
        return f"{name} {problem}; a gain is a finite number >= 0"
    v = float(value)
    if 0.0 < v < sys.float_info.min:
        return f"{name} is subnormal ({v:g} < {sys.float_info.min:.3g}); use 0 or a normal number"
    if v > GAIN_MAX[name]:
        return f"{name} is limited to {GAIN_MAX[name]:g} (far beyond a stable loop at servo rates)"
    return None


def check_values(changes: Mapping[str, Any], joint: int | None = None) -> dict[str, float]:
    """``changes`` (gain name → value) as floats; :class:`GainRejected` (kind invalid) for the first
    value :func:`value_problem` refuses."""
    for name, value in changes.items():
        problem = value_problem(name, value)
        if problem is not None:
            raise GainRejected(name, value, problem, joint)
    return {name: float(value) + 0.0 for name, value in changes.items()}


# ---- the sampled loop ----------------------------------------------------------------------------------
def loop_poles(kp: float, kpi: float, kv: float, kvi: float, period_s: float, delay: float = 0.0,
               filter_alpha: float | None = None) -> np.ndarray:
    """Poles (z-plane) of the sampled closed loop, without the structural eigenvalue at z = 1.

    Coordinates: ``S = Kpi·Ie + KvI·Iv`` (acts on the plant) and ``R = KvI·Ie − Kpi·Iv`` (never
    feeds back); the loop poles are the eigenvalues of the block without R. With Kpi = KvI = 0 both
    integrator states are dropped. ``filter_alpha``: the KvI channel is the velocity filter
    (:mod:`servo.control.velocity_filter`): no structural eigenvalue (the filter state is a real
    pole at 1 − α, dropped only with KvI = 0), and Ie only with Kpi = 0.
    """
    A = sampled_loop_matrix(kp, kpi, kv, kvi, period_s, delay, filter_alpha)
    m = A.shape[0]
    if filter_alpha is not None:
        drop = ({2} if kpi == 0.0 else set()) | ({3} if kvi == 0.0 else set())
        keep = [i for i in range(m) if i not in drop]
        return np.linalg.eigvals(A[np.ix_(keep, keep)])
    if kpi == 0.0 and kvi == 0.0:
        keep = [i for i in range(m) if i not in (2, 3)]
        return np.linalg.eigvals(A[np.ix_(keep, keep)])
    M = np.eye(m)
    M[2, 2:4] = (kpi, kvi)
    M[3, 2:4] = (kvi, -kpi)
    Ap = M @ A @ np.linalg.inv(M)
    keep = [i for i in range(m) if i != 3]
    return np.linalg.eigvals(Ap[np.ix_(keep, keep)])


def spectral_radius(kp: float, kpi: float, kv: float, kvi: float, period_s: float, delay: float = 0.0,
                    filter_alpha: float | None = None) -> float:
    """Largest pole magnitude of the sampled loop (< 1: stable)."""
    return float(np.max(np.abs(loop_poles(kp, kpi, kv, kvi, period_s, delay, filter_alpha))))


def _stability_problem(loop: str, r: float, need: float, where: str, lower: str, stiffer: str) -> str | None:
    """Why ``loop`` with pole radius ``r`` fails the margin ``need``, with what to do, or None.
    ``lower``/``stiffer``: the remedy for too much gain / for a pole on the unit circle."""
    if 1.0 - r > need:
        return None
    if r >= 1.0 + _MARGINAL:
        return f"{loop} would be unstable (pole radius {r:.4f} > 1; {where}); {lower}"
    if r > 1.0 - _MARGINAL:
        return (f"{loop} would be marginal (pole radius {r:.10f}, on the unit circle to rounding: an error would "
                f"never decay; {where}); {stiffer}")
    return (f"{loop} would keep a stability margin 1-rho = {1.0 - r:.4g}, not more than the required {need:g} "
            f"(pole radius {r:.4f}; {where}); {lower}, or require less margin")


def judge(gains: Gains[float], period_s: float, delay: float = 0.0, *, kp_off: float | None = None,
          min_margin: float = 0.0, filter_hz: float | None = None) -> GainVerdict:
    """The verdict on one joint's gain set (see the module docstring); never raises for bad gains.

    ``period_s`` the servo period (s), ``delay`` the computation delay in periods (0..1),
    ``kp_off`` the position gain while the integrators are switched off (1/s²; None: the switch-off
    is disabled, not checked), ``min_margin`` the margin 1 − ρ the set must keep (> it),
    ``filter_hz`` the velocity filter's cutoff when the KvI channel is that filter (None or NaN: ∫ė).
    Raises :class:`GainRejected` only for a bad ``period_s``, ``delay`` or ``kp_off``.
    """
    if not (math.isfinite(period_s) and period_s > 0):
        raise GainRejected("period", period_s, "the servo period must be a positive number of seconds")
    if not 0.0 <= delay <= 1.0:
        raise GainRejected("delay", delay, "the computation delay must be within 0..1 periods")
    if kp_off is not None and gain_value_problem(kp_off) is not None:
        raise GainRejected("kp_off", kp_off, "the switched-off position gain must be a finite number ≥ 0")
    for name in GAIN_NAMES:
        problem = value_problem(name, getattr(gains, name))
        if problem is not None:
            return GainVerdict(False, "invalid", problem)
    need = max(float(min_margin), MIN_MARGIN_FLOOR)
    g = gains
    fa = None if filter_hz is None or math.isnan(filter_hz) else VelocityFilter(filter_hz).alpha(period_s)
    m_int = 1.0 - spectral_radius(g.kp, g.kpi, g.kv, g.kvi, period_s, delay, fa)
    # switched off, the integrators are frozen; a velocity filter keeps running (it is no integrator)
    m_off = math.nan if kp_off is None else 1.0 - spectral_radius(kp_off, 0.0, g.kv, 0.0 if fa is None else g.kvi,
                                                                  period_s, delay, fa)
    if g.kpi == 0.0 and g.kvi > 0.0 and fa is None:
        return GainVerdict(False, "unstable", (
            "Kpi = 0 with KvI > 0 leaves a closed-loop pole at z = 1 (the KvI integrator would hold whatever "
            "offset it has, nothing brings the joint back to its target); set kvi=0 as well, or keep kpi > 0"),
            m_int, m_off)
    where = f"T = {period_s * 1e3:g} ms, delay {delay:g} T"
    problem = _stability_problem("the sampled loop", 1.0 - m_int, need, where, "lower the gains",
                                 "raise kp or kpi (the loop's position stiffness)")
    if problem is not None:
        return GainVerdict(False, "unstable", problem, m_int, m_off)
    if kp_off is not None:
        problem = _stability_problem(f"the loop with its integrators switched off (Kp_eff = {kp_off:g})",
                                     1.0 - m_off, need, where, "lower kp/kvi or the kp_boost",
                                     "raise kp or the kp_boost")
        if problem is not None:
            return GainVerdict(False, "unstable", problem, m_int, m_off)
    return GainVerdict(True, "ok", "stable", m_int, m_off)


# ---- a live law -------------------------------------------------------------------------------------------
def _staged(law: Any, attr: str) -> Any:
    """What the law will use at the next tick: a staged value if any, else the current one."""
    pending = getattr(law, f"_pending_{attr}", None)
    return pending if pending is not None else getattr(law, attr)


def check_gain_change(law: Any, joint: int | None, changes: Mapping[str, Any], period_s: float,
                      delay: float = 0.0, *, min_margin: float = 0.0, switch_off: Any = None) -> None:
    """Raise :class:`GainRejected` unless ``changes`` (gain name → value) may be applied to ``law``.

    ``law`` is a :class:`servo.control.law.PidLaw` (its ``gains``, ``n`` and ``switch_off`` are
    read; staged-but-not-yet-applied values count as current). ``joint`` is a joint index, or None
    for every joint. ``switch_off``: judge with this :class:`~servo.control.law.SwitchOffConfig`
    instead of the law's (a switch-off change being checked; ``changes`` may then be empty).
    ``period_s``, ``delay`` and ``min_margin`` as for :func:`judge`. Never modifies ``law``.
    """
    if not changes and switch_off is None:
        raise GainRejected("gains", {}, "no gain given (use kp=, kpi=, kv=, kvi=)")
    so = switch_off if switch_off is not None else _staged(law, "switch_off")
    check_gain_set(_staged(law, "gains"), so, changes, period_s, delay, joint=joint, min_margin=min_margin,
                   filter_hz=getattr(law, "filter_hz", None))


def check_gain_set(gains: Gains[np.ndarray], switch_off: Any, changes: Mapping[str, Any], period_s: float,
                   delay: float = 0.0, *, joint: int | None = None, min_margin: float = 0.0,
                   filter_hz: Any = None) -> dict[str, float]:
    """Raise :class:`GainRejected` unless ``changes`` (gain name → value) applied to the per-joint
    set ``gains`` (of joint ``joint``, or of every joint for None) pass: values first, then every
    changed joint's sampled loop with ``switch_off`` (a :class:`~servo.control.law.SwitchOffConfig`).
    ``filter_hz``: per joint the velocity filter's cutoff (NaN: none; None: no joint has one).
    Returns ``changes`` as floats (:func:`check_values`).
    :func:`check_gain_change` (a live law) and an override of a rig's settings
    (:meth:`servo.settings.ServoSettings.overridden`) both ask this."""
    n = int(gains.n or 1)
    if joint is not None and not (isinstance(joint, int) and not isinstance(joint, bool) and 0 <= joint < n):
        raise GainRejected("joint", joint, f"a joint index in 0..{n - 1}")
    clean = check_values(changes, joint)
    so = switch_off
    shown = ", ".join(f"{k}={v:g}" for k, v in clean.items()) or "switch-off change"
    for j in range(n) if joint is None else (joint,):
        g = gains.joint(j).replace(**clean)
        f_hz = None if filter_hz is None or math.isnan(float(filter_hz[j])) else float(filter_hz[j])
        kvi_lost = g.kvi if f_hz is None else 0.0  # a filter keeps its stiffness while switched off
        kp_off = float(switched_off_kp(g.kp, kvi_lost, float(so.kp_boost[j]))) if bool(so.enabled[j]) else None
        judge(g, period_s, delay, kp_off=kp_off, min_margin=min_margin, filter_hz=f_hz).raise_if_refused(shown, j)
    return clean
