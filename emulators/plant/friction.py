"""Harmonic Drive friction at the input shaft and the exact stick/slip step.

Friction model (per joint, motor-shaft quantities, SI)::

    r(θm)      = 1 + m·sin(2·θm + φ)                 ripple: twice per wave-generator turn, 0 ≤ m < 1
    T_brk(θm)  = T_s·r(θm)                           breakout (static) level
    T_k(ω, θm) = (T_c + (T_s − T_c)·exp(−(ω/ω_s)²))·r(θm)   Coulomb + Stribeck magnitude
    slipping:    T_f = sign(ω)·T_k + b·r(θm)·ω         (always opposes ω: friction never adds energy)
    stuck:       |T_f| ≤ T_brk, T_f = T_drive          (holds exactly)

Integration of ``J·dω/dt = T_drive − T_f`` over one fixed step ``h`` (Karnopp stick/slip with
zero-crossing capture). ``T_drive`` (motor torque minus reflected load), the Coulomb/Stribeck
magnitude and the ripple factor are frozen over the step; the viscous term is integrated
exactly (exponential), so the step is unconditionally stable for any ``b·h/J``:

* stuck (ω = 0) and ``|T_drive| ≤ T_brk`` → stays exactly at ω = 0;
* stuck and ``|T_drive| > T_brk`` → breaks away in the direction of ``T_drive``;
* slipping: ``ω(t) = ω0·e^{−at} + α0·t·φ1(at)`` with ``a = b·r/J``, ``α0 = (T_drive − s·T_k)/J``.
  If ω would cross zero inside the step, the crossing time ``t_c`` is solved in closed form; at
  ``t_c`` the joint sticks exactly (``|T_drive| ≤ T_brk(θ_c)``) or reverses and slips for the
  rest of the step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def phi1(x: np.ndarray) -> np.ndarray:
    """(1 − e^{−x})/x, → 1 at x = 0 (x ≥ 0)."""
    x = np.asarray(x, dtype=float)
    small = x < 1e-8
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0 - 0.5 * x, -np.expm1(-xs) / xs)


def phi2(x: np.ndarray) -> np.ndarray:
    """(x − 1 + e^{−x})/x², → ½ at x = 0 (x ≥ 0)."""
    x = np.asarray(x, dtype=float)
    small = x < 1e-3
    xs = np.where(small, 1.0, x)
    return np.where(small, 0.5 - x / 6.0 + x * x / 24.0, (xs + np.expm1(-xs)) / (xs * xs))


def _log1p_over(y: np.ndarray) -> np.ndarray:
    """log(1 + y)/y, → 1 at y = 0 (y ≥ 0)."""
    small = y < 1e-8
    ys = np.where(small, 1.0, y)
    return np.where(small, 1.0 - 0.5 * y, np.log1p(ys) / ys)


@dataclass
class FrictionArrays:
    """Per-joint friction parameters as arrays (motor-shaft SI)."""

    breakout: np.ndarray  #: T_s (N·m)
    coulomb: np.ndarray  #: T_c (N·m)
    stribeck_w: np.ndarray  #: ω_s (rad/s)
    viscous: np.ndarray  #: b (N·m·s/rad)
    ripple: np.ndarray  #: m
    ripple_phase: np.ndarray  #: φ (rad)

    def ripple_factor(self, theta_m: np.ndarray) -> np.ndarray:
        """r(θm) = 1 + m·sin(2θm + φ) (dimensionless, in (0, 2))."""
        return 1.0 + self.ripple * np.sin(2.0 * theta_m + self.ripple_phase)

    def kinetic(self, omega: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Coulomb + Stribeck magnitude T_k(ω)·r (N·m, ≥ 0), without the viscous term."""
        q = omega / self.stribeck_w
        return (self.coulomb + (self.breakout - self.coulomb) * np.exp(-q * q)) * r

    def slipping_torque(self, omega: np.ndarray, theta_m: np.ndarray) -> np.ndarray:
        """Signed friction torque while slipping at speed ω (N·m; opposes ω; 0 at ω = 0)."""
        r = self.ripple_factor(theta_m)
        return np.sign(omega) * self.kinetic(omega, r) + self.viscous * r * omega


def stick_slip_step(
    omega: np.ndarray,
    theta_m: np.ndarray,
    t_drive: np.ndarray,
    inertia: np.ndarray,
    fr: FrictionArrays,
    h: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Advance ``J·dω/dt = T_drive − T_f`` by ``h`` seconds for every joint.

    Args:
        omega: motor speed at the start (rad/s); exactly 0 means stuck.
        theta_m: motor angle at the start (rad), for the ripple phase.
        t_drive: applied torque at the motor shaft, frozen over the step (N·m).
        inertia: inertia at the motor shaft (kg·m²).
        fr: friction parameters.
        h: step (s).

    Returns:
        ``(omega_new, dtheta, t_friction)``: speed at the end (exactly 0 when stuck), angle
        increment (rad) and the friction torque acting at the end of the step (N·m, sign
        convention ``J·dω/dt = T_drive − T_f``).
    """
    r = fr.ripple_factor(theta_m)
    brk = fr.breakout * r
    stuck0 = omega == 0.0
    hold = stuck0 & (np.abs(t_drive) <= brk)
    s = np.where(stuck0, np.sign(t_drive), np.sign(omega))
    tk = fr.kinetic(omega, r)
    a = fr.viscous * r / inertia
    acc0 = (t_drive - s * tk) / inertia
    x = a * h
    p1 = phi1(x)
    w1 = omega * np.exp(-x) + acc0 * h * p1
    dth = omega * h * p1 + acc0 * (h * h) * phi2(x)
    t_f = s * tk + fr.viscous * r * w1
    cross = (~hold) & (w1 * s <= 0.0) & (omega != 0.0)
    if cross.any():
        om = omega[cross]
        ac = acc0[cross]
        ac = np.where(ac == 0.0, -np.sign(om) * 1e-300, ac)
        ai = a[cross]
        y = -ai * om / ac
        tc = np.clip((-om / ac) * _log1p_over(np.maximum(y, 0.0)), 0.0, h)
        xc = ai * tc
        dth_c = om * tc * phi1(xc) + ac * tc * tc * phi2(xc)
        th_c = theta_m[cross] + dth_c
        td = t_drive[cross]
        inn = inertia[cross]
        rc = 1.0 + fr.ripple[cross] * np.sin(2.0 * th_c + fr.ripple_phase[cross])
        brk_c = fr.breakout[cross] * rc
        rev = np.abs(td) > brk_c
        rem = h - tc
        s2 = np.sign(td)
        acc2 = (td - s2 * brk_c) / inn
        a2 = fr.viscous[cross] * rc / inn
        x2 = a2 * rem
        w2 = np.where(rev, acc2 * rem * phi1(x2), 0.0)
        d2 = np.where(rev, acc2 * rem * rem * phi2(x2), 0.0)
        # a reversal that itself would cross zero again within the remainder cannot happen
        # (breakaway means net torque along s2 at ω = 0), but guard against round-off:
        bad = rev & (w2 * s2 < 0.0)
        w2 = np.where(bad, 0.0, w2)
        d2 = np.where(bad, 0.0, d2)
        w1 = w1.copy()
        dth = dth.copy()
        t_f = t_f.copy()
        w1[cross] = w2
        dth[cross] = dth_c + d2
        t_f[cross] = np.where(rev & ~bad, s2 * brk_c + fr.viscous[cross] * rc * w2, td)
    w1 = np.where(hold, 0.0, w1)
    dth = np.where(hold, 0.0, dth)
    t_f = np.where(hold, t_drive, t_f)
    return w1, dth, t_f
