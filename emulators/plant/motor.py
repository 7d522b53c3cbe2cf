"""DC motor electrical dynamics, solved exactly over a step.

Armature: ``L·di/dt = V − R·i − Ke·ω``; torque ``T_m = Kt·i``. With the terminal voltage ``V``
and the speed ``ω`` held over a step ``h`` the solution is exact::

    i(h) = i_ss + (i0 − i_ss)·exp(−h·R/L),   i_ss = (V − Ke·ω)/R

so the electrical pole (L/R ≈ 1 ms) never limits the integration step. The amplifier models
(:mod:`emulators.plant.amplifier`) evaluate this same solution with the factors ``e^{−hR/L}`` and
``(1 − e^{−hR/L})/R`` precomputed per step length; :func:`rl_step` is the reference form.
"""

from __future__ import annotations

import numpy as np


def rl_step(i0: np.ndarray, v: np.ndarray, back_emf: np.ndarray, r: np.ndarray, decay: np.ndarray) -> np.ndarray:
    """Armature current after one step at constant terminal voltage ``v`` (A).

    Args:
        i0: current at the start (A).
        v: terminal voltage held over the step (V).
        back_emf: ``Ke·ω`` held over the step (V).
        r: armature resistance (Ω).
        decay: ``exp(−h·R/L)`` for the step (precomputed).
    """
    i_ss = (v - back_emf) / r
    return i_ss + (i0 - i_ss) * decay
