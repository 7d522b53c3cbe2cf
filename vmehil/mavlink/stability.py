"""Is the sampled loop stable with a candidate gain set? (the check behind refusing a PARAM_SET)

Uses the same linear model as the tuning tools, :func:`servo.control.linear.sampled_loop_matrix`
(the JPL law with backward-Euler integrators on a zero-order-hold 1/s² plant, with the rig's
computation delay). The stability margin reported here is ``1 − ρ(A)`` (ρ the spectral radius of
the closed-loop state matrix): > 0 means every sampled pole lies inside the unit circle.

Note for later: when ``vmehil.analysis`` (gain/phase margins of the tuning issue) lands, the
refusal rule can use its margins instead of (or on top of) the spectral radius; the model is the
same, so :func:`check_gains` is the one place to change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from servo.control.linear import sampled_loop_matrix


def _reduced(A: np.ndarray, kpi: float, kvi: float) -> np.ndarray:
    """The loop matrix without its unobservable modes.

    The integrators enter the law only as ``Kpi·Ie + KvI·Iv``; the other combination (and an
    integrator with a zero gain) is fed but never read back, which adds an eigenvalue exactly 1
    that does not belong to the loop (see tests/test_control_law.py). With
    ``P = [θ, ω, Kpi·Ie + KvI·Iv, (a_prev)]`` the kernel of P is A-invariant, so the reduced
    matrix is ``P·A·P⁺`` and its eigenvalues are the loop's poles.
    """
    n = A.shape[0]
    rows = [np.eye(n)[0], np.eye(n)[1]]
    if kpi != 0.0 or kvi != 0.0:
        z = np.zeros(n)
        z[2], z[3] = kpi, kvi
        rows.append(z)
    if n == 5:
        rows.append(np.eye(n)[4])
    P = np.array(rows)
    return P @ A @ np.linalg.pinv(P)


def sampled_margin(kp: float, kpi: float, kv: float, kvi: float, period_s: float, delay: float = 0.0) -> float:
    """``1 − spectral radius`` of the sampled closed loop (dimensionless; ≤ 0: unstable or marginal).

    ``delay`` is the computation delay in periods (0..1).
    """
    values = (kp, kpi, kv, kvi, period_s, delay)
    if not all(math.isfinite(v) for v in values):
        return -math.inf
    A = sampled_loop_matrix(kp, kpi, kv, kvi, period_s, delay)
    rho = float(np.max(np.abs(np.linalg.eigvals(_reduced(A, kpi, kvi)))))
    return 1.0 - rho


@dataclass(frozen=True)
class StabilityVerdict:
    """Result of :func:`check_gains`: ``ok``, the margins (1 − ρ) of the integrating and the
    switched-off loop (NaN when the switch-off is disabled) and a human-readable ``reason``."""

    ok: bool
    margin_integrating: float
    margin_switched_off: float
    reason: str


def check_gains(kp: float, kpi: float, kv: float, kvi: float, period_s: float, *, delay: float = 0.0,
                kp_off: float | None = None, min_margin: float = 0.0) -> StabilityVerdict:
    """Check one joint's gain set for the integrating loop and, when ``kp_off`` is given, for the
    switched-off loop (integrators frozen: Kp_off·e + Kv·ė). Stable means margin > ``min_margin``."""
    m_int = sampled_margin(kp, kpi, kv, kvi, period_s, delay)
    m_off = math.nan if kp_off is None else sampled_margin(kp_off, 0.0, kv, 0.0, period_s, delay)
    if not m_int > min_margin:
        return StabilityVerdict(False, m_int, m_off,
                                f"the sampled loop would be unstable (margin 1-rho = {m_int:.4g}, "
                                f"need > {min_margin:g})")
    if kp_off is not None and not m_off > min_margin:
        return StabilityVerdict(False, m_int, m_off,
                                f"the loop with integrators switched off (Kp_off = {kp_off:.4g}) would be "
                                f"unstable (margin 1-rho = {m_off:.4g}, need > {min_margin:g})")
    return StabilityVerdict(True, m_int, m_off, "stable")
