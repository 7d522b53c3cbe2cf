"""The digital filter alternative to KvI: one definition, used by the servo law and the tuning model.

The JPL paper: "as Kp was increased, noise in the position feedback loop required either a
digital filter or integration of the velocity error signal. Since the velocity error was
directly available, it was used to provide the large noise-free position error signal needed."
The law's KvI·∫ė dt term is that integration (∫ė dt = e, from the tach). The alternative feeds
the same gain KvI with the position error through a first-order digital low-pass filter::

    ef_k = ef_{k−1} + α·(e_k − ef_{k−1}),   α = 1 − exp(−2π·f_c·T)        (rad)
    a_k  = Kp_eff·e_k + Kpi·Ie_k + Kv·ė_k + KvI·ef_k + αd_k                 (rad/s²)

so the static stiffness is Kp + KvI either way (the filter's DC gain is 1), the pot noise
above f_c is attenuated, and the filter adds phase lag where the integration does not (∫ė
follows e at every frequency). The filter is a pole at z = 1 − α (the exact discretisation of
ωc/(s + ωc) for a held input); it is not an integrator, so the integrator switch-off does not
freeze it and the "auto" boost adds nothing for it (the stiffness KvI is not lost when off).

:class:`VelocityFilter` is the definition: :class:`servo.control.law.PidLaw` steps it, the
gain guard's sampled loop (:func:`servo.control.linear.sampled_loop_ss`) and the tuning model
(:mod:`vmehil.analysis.loop_model`) take its coefficients from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["NO_FILTER", "VelocityFilter", "filter_alpha"]

#: per-joint marker of "no filter: the KvI channel integrates the velocity error" (NaN cutoff)
NO_FILTER = math.nan


def filter_alpha(cutoff_hz: float | np.ndarray, period_s: float) -> float | np.ndarray:
    """α = 1 − exp(−2π·f_c·T) per joint (NaN where ``cutoff_hz`` is NaN: no filter)."""
    return -np.expm1(-2.0 * math.pi * np.asarray(cutoff_hz, float) * float(period_s))[()]


@dataclass(frozen=True)
class VelocityFilter:
    """A first-order low-pass of the position error in the KvI channel, corner ``cutoff_hz``."""

    cutoff_hz: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cutoff_hz) and self.cutoff_hz > 0):
            raise ValueError(f"velocity filter cutoff {self.cutoff_hz!r} Hz: expected a positive number of Hz")

    @property
    def omega_c_rad_s(self) -> float:
        """The corner in rad/s (the continuous ideal ωc/(s + ωc))."""
        return 2.0 * math.pi * self.cutoff_hz

    def alpha(self, period_s: float) -> float:
        """The update coefficient α at servo period ``period_s``."""
        return float(filter_alpha(self.cutoff_hz, period_s))

    def discrete(self, period_s: float) -> tuple[float, float]:
        """(pole, input gain) = (1 − α, α): ef_k = pole·ef_{k−1} + α·e_k."""
        a = self.alpha(period_s)
        return 1.0 - a, a

    def continuous(self) -> tuple[float, float]:
        """(A, B) of the continuous ideal ef' = −ωc·ef + ωc·e."""
        w = self.omega_c_rad_s
        return -w, w

    @staticmethod
    def step(ef_prev: np.ndarray, e: np.ndarray, alpha: np.ndarray) -> np.ndarray:
        """One tick of the filter (per joint): ef_prev + α·(e − ef_prev)."""
        return ef_prev + alpha * (e - ef_prev)
