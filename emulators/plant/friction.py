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


class StickSlipStepper:
    """:func:`stick_slip_step` with the per-step constants precomputed (the plant's hot path).

    Calling it returns ``(omega_new, dtheta)`` and keeps what the friction torque at the end of
    the step needs; :meth:`friction_torque` evaluates it on demand.
    """

    def __init__(self, fr: FrictionArrays, inertia: np.ndarray, h: float) -> None:
        self.fr = fr
        self.h = float(h)
        self.inertia = np.asarray(inertia, float)
        self.inv_j = 1.0 / self.inertia
        self.bjh = fr.viscous * self.inv_j * self.h
        #: direct (1−e^{−x})/x formulas are accurate when every x = b·r·h/J exceeds 1e-4
        self.direct = bool(np.all(self.bjh * (1.0 - fr.ripple) > 1e-4))
        self.inv_ws = 1.0 / fr.stribeck_w
        self.d_ts = fr.breakout - fr.coulomb
        self._last: tuple[np.ndarray, ...] | None = None

    def __call__(self, omega: np.ndarray, theta_m: np.ndarray, t_drive: np.ndarray,
                 brake: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``brake``: an engaged holding brake's torque at the motor shaft (N·m, ≥ 0; 0 where
        released), added to the static and the kinetic level alike (not rippled: it is not the
        Harmonic Drive's); ``None``: no brakes (the arithmetic of a rig without them)."""
        fr = self.fr
        h = self.h
        r = 1.0 + fr.ripple * np.sin(2.0 * theta_m + fr.ripple_phase)
        stuck0 = omega == 0.0
        s = np.sign(omega) + stuck0 * np.sign(t_drive)
        q = omega * self.inv_ws
        tk = (fr.coulomb + self.d_ts * np.exp(-(q * q))) * r
        if brake is not None:
            tk = tk + brake
        x = self.bjh * r
        e = np.exp(-x)
        if self.direct:
            p1 = (1.0 - e) / x
            p2 = (x - 1.0 + e) / (x * x)
        else:
            p1 = phi1(x)
            p2 = phi2(x)
        acc0 = (t_drive - s * tk) * self.inv_j
        w1 = omega * e + acc0 * (h * p1)
        dth = h * (omega * p1 + acc0 * (h * p2))
        brk = fr.breakout * r
        if brake is not None:
            brk = brk + brake
        hold = stuck0 & (np.abs(t_drive) <= brk)
        cross = (w1 * s <= 0.0) & ~stuck0
        moving = ~hold
        w1 = w1 * moving
        dth = dth * moving
        self._last = (hold, t_drive, s, tk, r, w1, cross)
        if cross.any():
            w1, dth = self._crossing(omega, theta_m, t_drive, acc0, x, w1, dth, cross, brake)
        return w1, dth

    def _crossing(self, omega, theta_m, t_drive, acc0, x, w1, dth, cross, brake=None):
        """Zero-crossing capture for the joints whose speed would change sign in the step."""
        fr = self.fr
        h = self.h
        om = omega[cross]
        ac = acc0[cross]
        ac = np.where(ac == 0.0, -np.sign(om) * 1e-300, ac)
        ai = x[cross] / h
        y = -ai * om / ac
        tc = np.clip((-om / ac) * _log1p_over(np.maximum(y, 0.0)), 0.0, h)
        xc = ai * tc
        dth_c = om * tc * phi1(xc) + ac * tc * tc * phi2(xc)
        th_c = theta_m[cross] + dth_c
        td = t_drive[cross]
        rc = 1.0 + fr.ripple[cross] * np.sin(2.0 * th_c + fr.ripple_phase[cross])
        brk_c = fr.breakout[cross] * rc
        if brake is not None:
            brk_c = brk_c + brake[cross]
        rev = np.abs(td) > brk_c
        rem = h - tc
        s2 = np.sign(td)
        acc2 = (td - s2 * brk_c) * self.inv_j[cross]
        x2 = self.bjh[cross] * rc * (rem / h)
        w2 = np.where(rev, acc2 * rem * phi1(x2), 0.0)
        d2 = np.where(rev, acc2 * rem * rem * phi2(x2), 0.0)
        # breakaway means net torque along s2 at ω = 0, so w2 cannot change sign; guard round-off
        bad = rev & (w2 * s2 < 0.0)
        w2 = np.where(bad, 0.0, w2)
        d2 = np.where(bad, 0.0, d2)
        w1 = w1.copy()
        dth = dth.copy()
        w1[cross] = w2
        dth[cross] = dth_c + d2
        hold, _, s, tk, r, _, _ = self._last
        hold = hold.copy()
        s = s.copy()
        tk = tk.copy()
        r = r.copy()
        hold[cross] = ~rev | bad
        s[cross] = s2
        tk[cross] = brk_c
        r[cross] = rc
        self._last = (hold, t_drive, s, tk, r, w1, cross)
        return w1, dth

    def friction_torque(self) -> np.ndarray:
        """Friction torque at the end of the last step (N·m; ``J·dω/dt = T_drive − T_f``)."""
        if self._last is None:
            return np.zeros_like(self.inertia)
        hold, t_drive, s, tk, r, w1, _ = self._last
        return np.where(hold, t_drive, s * tk + self.fr.viscous * r * w1)


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
    st = StickSlipStepper(fr, inertia, h)
    w1, dth = st(np.asarray(omega, float), np.asarray(theta_m, float), np.asarray(t_drive, float))
    return w1, dth, st.friction_torque()
