"""Is the sampled loop stable with a candidate gain set? (the check behind refusing a PARAM_SET)

Uses the same linear model as the tuning tools, :func:`servo.control.linear.sampled_loop_matrix`
(the JPL law with backward-Euler integrators on a zero-order-hold 1/s² plant, with the rig's
computation delay). The stability margin reported here is ``1 − ρ(A)`` (ρ the spectral radius of
the closed-loop state matrix): > 0 means every sampled pole lies inside the unit circle.

Note for later: when ``servo.analysis`` (gain/phase margins of the tuning issue) lands, the
refusal rule can use its margins instead of (or on top of) the spectral radius; the model is the
same, so :func:`check_gains` is the one place to change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from servo.control.linear import sampled_loop_matrix


def _kept_states(kpi: float, kvi: float, delay: float) -> list[int]:
    """States that feed back. An integrator with a zero gain is only fed (never read): it adds an
    eigenvalue 1 that does not belong to the loop, so it is left out (the matrix is block
    triangular in that state)."""
    keep = [0, 1]
    if kpi != 0.0:
        keep.append(2)
    if kvi != 0.0:
        keep.append(3)
    if delay > 0.0:
        keep.append(4)
    return keep


def sampled_margin(kp: float, kpi: float, kv: float, kvi: float, period_s: float, delay: float = 0.0) -> float:
    """``1 − spectral radius`` of the sampled closed loop (dimensionless; ≤ 0: unstable or marginal).

    ``delay`` is the computation delay in periods (0..1).
    """
    values = (kp, kpi, kv, kvi, period_s, delay)
    if not all(math.isfinite(v) for v in values):
        return -math.inf
    A = sampled_loop_matrix(kp, kpi, kv, kvi, period_s, delay)
    keep = _kept_states(kpi, kvi, delay)
    sub = A[np.ix_(keep, keep)]
    rho = float(np.max(np.abs(np.linalg.eigvals(sub))))
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
