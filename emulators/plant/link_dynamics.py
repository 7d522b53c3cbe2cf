"""Link side: gravity, inelastic hard stops and the flexspline (two-mass) coupling.

Rigid joint (default): the link rides on the motor through the Harmonic Drive,
``θ_joint = θm/N + ε(θm)`` with the kinematic error ``ε = A·sin(2θm + φ)`` (applied to the
output position only; the dynamics use the nominal ratio), and the link inertia is reflected
to the motor shaft as ``J_link/N²``.

Compliant joint (``gear.compliant = true``): the flexspline is a torsional spring/damper at the
output, ``τ_s = K·(θm/N + ε − θ_l) + c·(ωm/N − ω_l)``; the motor side sees ``−τ_s/N``; the link
obeys ``J_l·dω_l/dt = τ_s − T_g(θ_l)`` (semi-implicit Euler; stable for ``h·√(K/J) ≪ 2``).

Gravity: ``T_g(θ) = G·cos(θ + φ_g)`` is the torque the drive must supply to hold the link.
Hard stops are inelastic: crossing a limit puts the link exactly on the limit with zero speed.
"""

from __future__ import annotations

import numpy as np


def gravity_torque(theta_joint: np.ndarray, g_torque: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """Holding torque demanded by gravity at the joint (N·m)."""
    return g_torque * np.cos(theta_joint + phase)


def hard_stop_overshoot(theta_joint: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """How far past a stop the joint is (rad; > 0 above the upper stop, < 0 below the lower, else 0)."""
    return np.where(theta_joint > upper, theta_joint - upper, np.where(theta_joint < lower, theta_joint - lower, 0.0))
