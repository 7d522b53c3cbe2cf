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


def delay_periods(delay_s: float, period_s: float) -> float:
    """A computation delay of ``delay_s`` seconds in servo periods, within the models' 0..1."""
    return min(max(float(delay_s) / float(period_s), 0.0), 1.0)


def closed_loop_poly(kp: float, kpi: float, kv: float, kvi: float) -> np.ndarray:
    """Coefficients (highest power first) of the continuous closed-loop characteristic polynomial."""
    return np.array([1.0, kv, kp + kvi, kpi])


def continuous_poles(kp: float, kpi: float, kv: float, kvi: float) -> np.ndarray:
    """Roots of :func:`closed_loop_poly` (rad/s). The paper's gains give ≈ −6.0 and −22.0 ± 18.8j."""
    return np.roots(closed_loop_poly(kp, kpi, kv, kvi))


def sampled_loop_matrix(kp: float, kpi: float, kv: float, kvi: float, period: float,
                        delay: float = 0.0, filter_alpha: float | None = None) -> np.ndarray:
    """Closed-loop state matrix A (x_{k+1} = A·x_k, reference 0) of the sampled loop.

    State ``x_k = [θ_k, ω_k, Ie_{k−1}, Iv_{k−1}]`` (plus ``a_{k−1}`` when ``delay > 0``). The
    eigenvalues are the sampled loop's poles (compare with exp(s·T) of :func:`continuous_poles`).
    ``filter_alpha``: the KvI channel is the velocity filter (:mod:`servo.control.velocity_filter`,
    its coefficient α) instead of ∫ė; the fourth state is then ef_{k−1}.
    """
    return sampled_loop_ss(kp, kpi, kv, kvi, period, delay, filter_alpha)[0]


def sampled_loop_ss(kp: float, kpi: float, kv: float, kvi: float, period: float,
                    delay: float = 0.0, filter_alpha: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the sampled closed loop, x_{k+1} = A·x_k + B·u_k with u_k = [θd_k, ωd_k, αd_k].

    State as in :func:`sampled_loop_matrix`; θ_k = x_k[0], ω_k = x_k[1].
    """
    if not 0.0 <= delay <= 1.0:
        raise ValueError(f"delay must be within 0..1 periods, got {delay!r}")
    T = float(period)
    if filter_alpha is None:
        # a_k = (Kp + Kpi·T)·(θd − θ) + (Kv + KvI·T)·(ωd − ω) + Kpi·Ie_{k−1} + KvI·Iv_{k−1} + αd
        a_x = np.array([-(kp + kpi * T), -(kv + kvi * T), kpi, kvi])
        a_u = np.array([kp + kpi * T, kv + kvi * T, 1.0])
    else:
        # ef_k = (1 − α)·ef_{k−1} + α·e_k: a_k = (Kp + Kpi·T + KvI·α)·e + Kv·ė + Kpi·Ie + KvI·(1 − α)·ef
        al = float(filter_alpha)
        a_x = np.array([-(kp + kpi * T + kvi * al), -kv, kpi, kvi * (1.0 - al)])
        a_u = np.array([kp + kpi * T + kvi * al, kv, 1.0])
    t1, t2 = (1.0 - delay) * T, delay * T  # time the new / the previous command acts in the period
    new_th, new_w = t1 * t1 / 2.0, t1
    old_th, old_w = t2 * t2 / 2.0 + t2 * t1, t2
    A = np.array([
        [1.0, T, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [-T, 0.0, 1.0, 0.0],
        [0.0, -T, 0.0, 1.0],
    ])
    B = np.zeros((4, 3))
    B[2, 0] = T
    B[3, 1] = T
    if filter_alpha is not None:
        al = float(filter_alpha)
        A[3] = [-al, 0.0, 0.0, 1.0 - al]
        B[3] = [al, 0.0, 0.0]
    A[0] += new_th * a_x
    A[1] += new_w * a_x
    B[0] += new_th * a_u
    B[1] += new_w * a_u
    if delay == 0.0:
        return A, B
    A5 = np.zeros((5, 5))
    A5[:4, :4] = A
    A5[0, 4] = old_th
    A5[1, 4] = old_w
    A5[4, :4] = a_x
    B5 = np.zeros((5, 3))
    B5[:4] = B
    B5[4] = a_u
    return A5, B5


def simulate_sampled_loop(kp: float, kpi: float, kv: float, kvi: float, period: float,
                          theta_d: np.ndarray, omega_d: np.ndarray, alpha_d: np.ndarray | None = None,
                          delay: float = 0.0) -> np.ndarray:
    """θ_k (rad) of the linear sampled loop from rest for reference sequences (one value per tick)."""
    A, B = sampled_loop_ss(kp, kpi, kv, kvi, period, delay)
    th_d = np.asarray(theta_d, float)
    w_d = np.asarray(omega_d, float)
    al_d = np.zeros_like(th_d) if alpha_d is None else np.asarray(alpha_d, float)
    x = np.zeros(A.shape[0])
    out = np.empty(th_d.shape[0])
    for k in range(th_d.shape[0]):
        out[k] = x[0]
        x = A @ x + B @ np.array([th_d[k], w_d[k], al_d[k]])
    return out
