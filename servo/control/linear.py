"""Linear models of the normalized loop (for tests and the tuning tools).

Continuous ideal (plant 1/s², law a = Kp·e + Kpi·∫e + Kv·ė + KvI·∫ė)::

    θ/θd characteristic polynomial  s³ + Kv·s² + (Kp + KvI)·s + Kpi

Sampled loop: the same law as :class:`servo.control.law.PidLaw` (backward-Euler integrators fed
with the current sample) driving a zero-order-hold double integrator, exact discretisation, with
a computation delay of ``delay`` periods (0 ≤ delay ≤ 1: the new command reaches the plant
``delay·T`` after the sampling instant; before that the previous command is held).
"""

from __future__ import annotations

import numpy as np


def closed_loop_poly(kp: float, kpi: float, kv: float, kvi: float) -> np.ndarray:
    """Coefficients (highest power first) of the continuous closed-loop characteristic polynomial."""
    return np.array([1.0, kv, kp + kvi, kpi])


def continuous_poles(kp: float, kpi: float, kv: float, kvi: float) -> np.ndarray:
    """Roots of :func:`closed_loop_poly` (rad/s). The paper's gains give ≈ −6.0 and −22.0 ± 18.8j."""
    return np.roots(closed_loop_poly(kp, kpi, kv, kvi))


def sampled_loop_matrix(kp: float, kpi: float, kv: float, kvi: float, period: float,
                        delay: float = 0.0) -> np.ndarray:
    """Closed-loop state matrix A (x_{k+1} = A·x_k, reference 0) of the sampled loop.

    State ``x_k = [θ_k, ω_k, Ie_{k−1}, Iv_{k−1}]`` (plus ``a_{k−1}`` when ``delay > 0``). The
    eigenvalues are the sampled loop's poles (compare with exp(s·T) of :func:`continuous_poles`).
    """
    if not 0.0 <= delay <= 1.0:
        raise ValueError(f"delay must be within 0..1 periods, got {delay!r}")
    T = float(period)
    # a_k = -(Kp + Kpi·T)·θ - (Kv + KvI·T)·ω + Kpi·Ie_{k-1} + KvI·Iv_{k-1}   (Ie, Iv integrate e = -θ, ė = -ω)
    a_row = np.array([-(kp + kpi * T), -(kv + kvi * T), kpi, kvi])
    t1, t2 = (1.0 - delay) * T, delay * T  # time the new / the previous command acts
    # effect of a command held over an interval on (θ, ω): the new one acts last
    new_th, new_w = t1 * t1 / 2.0, t1
    old_th, old_w = t2 * t2 / 2.0 + t2 * t1, t2
    base = np.array([
        [1.0, T, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [-T, 0.0, 1.0, 0.0],
        [0.0, -T, 0.0, 1.0],
    ])
    A = base.copy()
    A[0] += new_th * a_row
    A[1] += new_w * a_row
    if delay == 0.0:
        return A
    A5 = np.zeros((5, 5))
    A5[:4, :4] = A
    A5[0, 4] = old_th
    A5[1, 4] = old_w
    A5[4, :4] = a_row
    return A5
