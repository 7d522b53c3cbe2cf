"""Validation of live gain changes — shared by every live-tuning path (console, MAVLink, API).

A change is accepted only if, for every joint it touches,

* each new gain is one of ``kp``, ``kpi``, ``kv``, ``kvi``: a finite number ≥ 0 and at most
  :data:`GAIN_MAX` (the ranges the MAVLink parameters advertise);
* the sampled closed loop with the new gains is stable (margin 1 − ρ > ``min_margin``, default 0):
  every pole of
  :func:`servo.control.linear.sampled_loop_matrix` (ZOH double integrator, period ``period_s``,
  computation delay ``delay`` periods) lies strictly inside the unit circle;
* not Kpi = 0 with KvI > 0 (a pole at exactly z = 1: marginal, the KvI integrator keeps an offset);
* where the joint's integrator switch-off is enabled, the switched-off loop (integrators frozen,
  ``Kp_eff`` = the boosted Kp, see :mod:`servo.control.law`) is stable as well.

The sampled-loop state ``[θ, ω, Ie, Iv]`` has one structural eigenvalue at exactly z = 1 that is
not a loop pole: only the combination ``Kpi·Ie + KvI·Iv`` acts on the plant, the complementary
combination never feeds back (see docs/control.md). :func:`loop_poles` removes it with an exact
change of coordinates before the eigenvalues are taken, so a genuine slow pole near z = 1 is never
mistaken for it.

Use::

    from servo.gain_guard import GainRejected, check_gain_change
    check_gain_change(loop.law, joint=0, changes={"kp": 120.0}, period_s=loop.period_s, delay=0.5)
    loop.law.set_gains(kp=120.0, joint=0)      # only after the check passed
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from servo.control.law import GAIN_NAMES
from servo.control.linear import sampled_loop_matrix

# The stability margin 1 − ρ must exceed this at least (strictly inside the unit circle, with a hair
# for rounding: 1e-12 per tick is a time constant of ~250 million years at 125 Hz).
MIN_MARGIN_FLOOR = 1e-12
# Upper limits (the ranges the MAVLink parameters advertise, vmehil.mavlink.params.GAIN_RANGES).
GAIN_MAX = {"kp": 1e5, "kpi": 1e7, "kv": 1e4, "kvi": 1e6}


class GainRejected(ValueError):
    """A live gain change was refused; nothing was changed.

    ``name`` is the gain (or ``"joint"``), ``joint`` the joint index (None: the request as a whole),
    ``value`` the offending value, ``reason`` a short human explanation (what to do instead).
    """

    def __init__(self, name: str, value: Any, reason: str, joint: int | None = None) -> None:
        self.name = name
        self.value = value
        self.joint = joint
        self.reason = reason
        what = name if value is None else f"{name}={value!r}"
        where = f" on joint {joint}" if joint is not None else ""
        super().__init__(f"gain change {what}{where} rejected: {reason}; nothing was changed")


def loop_poles(kp: float, kpi: float, kv: float, kvi: float, period_s: float, delay: float = 0.0) -> np.ndarray:
    """Poles (z-plane) of the sampled closed loop, without the structural eigenvalue at z = 1.

    Coordinates: ``S = Kpi·Ie + KvI·Iv`` (acts on the plant) and ``R = KvI·Ie − Kpi·Iv`` (never
    feeds back); the loop poles are the eigenvalues of the block without R. With Kpi = KvI = 0 both
    integrator states are dropped.
    """
    A = sampled_loop_matrix(kp, kpi, kv, kvi, period_s, delay)
    m = A.shape[0]
    if kpi == 0.0 and kvi == 0.0:
        keep = [i for i in range(m) if i not in (2, 3)]
        return np.linalg.eigvals(A[np.ix_(keep, keep)])
    M = np.eye(m)
    M[2, 2:4] = (kpi, kvi)
    M[3, 2:4] = (kvi, -kpi)
    Ap = M @ A @ np.linalg.inv(M)
    keep = [i for i in range(m) if i != 3]
    return np.linalg.eigvals(Ap[np.ix_(keep, keep)])


def spectral_radius(kp: float, kpi: float, kv: float, kvi: float, period_s: float, delay: float = 0.0) -> float:
    """Largest pole magnitude of the sampled loop (< 1: stable)."""
    return float(np.max(np.abs(loop_poles(kp, kpi, kv, kvi, period_s, delay))))


def _staged(law: Any, attr: str) -> Any:
    """What the law will use at the next tick: a staged value if any, else the current one."""
    pending = getattr(law, f"_pending_{attr}", None)
    return pending if pending is not None else getattr(law, attr)


def check_gain_change(law: Any, joint: int | None, changes: Mapping[str, float], period_s: float,
                      delay: float = 0.0, *, min_margin: float = 0.0) -> None:
    """Raise :class:`GainRejected` unless ``changes`` (gain name → value) may be applied.

    ``law`` is a :class:`servo.control.law.PidLaw` (its ``gains``, ``n`` and ``switch_off`` are
    read; staged-but-not-yet-applied gains count as current). ``joint`` is a joint index, or None
    for every joint. ``period_s`` is the servo period (s), ``delay`` the computation delay in
    periods (0..1), ``min_margin`` the stability margin 1 − ρ the new set must keep (> it).
    Returns None when the change is acceptable; never modifies ``law``.
    """
    need = max(float(min_margin), MIN_MARGIN_FLOOR)
    if not changes:
        raise GainRejected("gains", {}, "no gain given (use kp=, kpi=, kv=, kvi=)")
    n = int(law.n)
    if joint is not None and not (isinstance(joint, int) and not isinstance(joint, bool) and 0 <= joint < n):
        raise GainRejected("joint", joint, f"a joint index in 0..{n - 1}")
    if not (math.isfinite(period_s) and period_s > 0):
        raise GainRejected("period", period_s, "the servo period must be a positive number of seconds")
    if not 0.0 <= delay <= 1.0:
        raise GainRejected("delay", delay, "the computation delay must be within 0..1 periods")
    clean: dict[str, float] = {}
    for name, value in changes.items():
        if name not in GAIN_NAMES:
            raise GainRejected(name, value, "unknown gain; use kp, kpi, kv or kvi", joint)
        if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
            raise GainRejected(name, value, "a number is required", joint)
        v = float(value)
        if not math.isfinite(v):
            raise GainRejected(name, value, "gains must be finite", joint)
        if v < 0.0:
            raise GainRejected(name, value, "gains must be >= 0", joint)
        if v > GAIN_MAX[name]:
            raise GainRejected(name, value, f"{name} is limited to {GAIN_MAX[name]:g}", joint)
        clean[name] = v
    gains = _staged(law, "gains")
    switch_off = _staged(law, "switch_off")
    joints = range(n) if joint is None else (joint,)
    shown = ", ".join(f"{k}={v:g}" for k, v in clean.items())
    for j in joints:
        g = {name: clean.get(name, float(getattr(gains, name)[j])) for name in GAIN_NAMES}
        if g["kpi"] == 0.0 and g["kvi"] > 0.0:
            raise GainRejected(
                shown, None, "Kpi = 0 with KvI > 0 leaves a closed-loop pole at z = 1 (the KvI integrator would "
                "hold whatever offset it has, nothing brings the joint back to its target); set kvi=0 as well, "
                "or keep kpi > 0", j)
        r = spectral_radius(g["kp"], g["kpi"], g["kv"], g["kvi"], period_s, delay)
        if not 1.0 - r > need:
            raise GainRejected(
                shown, None, f"the sampled loop would be unstable (pole radius {r:.4f}, margin 1-rho must exceed "
                f"{need:g}; T = {period_s * 1e3:g} ms, delay {delay:g} T); lower the gains", j)
        if switch_off is not None and bool(switch_off.enabled[j]):
            boost = float(switch_off.kp_boost[j])
            kp_off = g["kp"] + g["kvi"] if math.isnan(boost) else g["kp"] * boost
            r_off = spectral_radius(kp_off, 0.0, g["kv"], 0.0, period_s, delay)
            if not 1.0 - r_off > need:
                raise GainRejected(
                    shown, None, f"the loop would be unstable with its integrators switched off (Kp_eff = "
                    f"{kp_off:g}, pole radius {r_off:.4f}); lower kp/kvi or the kp_boost", j)
