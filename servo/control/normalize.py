"""The normalizing chain: normalized acceleration → joint torque → motor current → amplifier volts.

The JPL loop puts constant gains in the forward path (the paper's G1, G4, G6: buffer amplifier,
converter, motor, inertia) so that every joint looks like a unit double integrator 1/s² to the
servo law. With the sensors already converted to SI by the calibrated drivers (rad, rad/s — the
"converter" part of the normalization lives in the calibration files), the forward chain per joint
is::

    a   [rad/s²]   normalized acceleration, the output of the law
    τ   = J_eff · a                    [N·m at the joint]     J_eff: total inertia at the joint, kg·m²
    i   = τ / (N · Kt)                 [A motor current]      N: reduction ratio, Kt: N·m/A
    u   = i / g_amp                    [V amplifier command]  g_amp: transconductance, A/V
    c   = u / (V per DAC count)        [DAC counts]           optional, when the DAC's LSB is given

so the overall forward gain is ``J_eff / (N·Kt·g_amp)`` volts per rad/s². Multiplying the
law's output by it and having the plant divide by the same numbers leaves θ'' = a: the loop is
1/s² for every joint and one gain set (Kp, Kpi, Kv, KvI) gives every joint the same response.
Friction, gravity and any error in J_eff are what make joints differ.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from servo.control.errors import GainError


def per_joint(name: str, value: float | np.ndarray | list[float], n: int, *, positive: bool = False,
              allow_nan: bool = False) -> np.ndarray:
    """Broadcast a scalar or length-``n`` sequence to a float64 array of length ``n`` and validate it.

    Raises :class:`GainError` naming the parameter (and joint) when a value is not finite, negative
    (or zero with ``positive=True``), or the shape is wrong. ``allow_nan`` lets NaN through (used
    as "not given").
    """
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise GainError(name, value, "a number or a list of numbers") from None
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise GainError(name, value, f"a number or a list of {n} numbers (one per joint)")
    for j, x in enumerate(arr):
        if np.isnan(x) and allow_nan:
            continue
        if not np.isfinite(x):
            raise GainError(name, float(x), "a finite number", j)
        if x < 0 or (positive and x == 0):
            raise GainError(name, float(x), "a positive number" if positive else "a non-negative number", j)
    return arr


@dataclass(frozen=True)
class NormalizingChain:
    """Per-joint forward gains from normalized acceleration to amplifier command (arrays of length n).

    Attributes (SI): ``j_eff`` kg·m² at the joint (rotor inertia reflected, N²·J_rotor, plus link),
    ``ratio`` N (motor turns per joint turn), ``kt`` N·m/A, ``amp_gain`` A/V (transconductance
    amplifier), ``dac_volts_per_count`` V per DAC LSB (NaN when not used).
    """

    j_eff: np.ndarray
    ratio: np.ndarray
    kt: np.ndarray
    amp_gain: np.ndarray
    dac_volts_per_count: np.ndarray

    @property
    def n(self) -> int:
        return int(self.j_eff.shape[0])

    # --- forward chain -------------------------------------------------------------------------
    def torque_from_accel(self, accel: np.ndarray) -> np.ndarray:
        """τ = J_eff·a: N·m at the joint from rad/s²."""
        return self.j_eff * accel

    # --- inverses (limits given as current or volts → torque) -----------------------------------
    def torque_from_current(self, current: np.ndarray) -> np.ndarray:
        """τ = N·Kt·i: joint torque in N·m for a motor current in A."""
        return self.ratio * self.kt * current

    def torque_from_volts(self, volts: np.ndarray) -> np.ndarray:
        """Joint torque in N·m produced by an amplifier command in V."""
        return self.torque_from_current(volts * self.amp_gain)

    # --- summary ---------------------------------------------------------------------------------
    @property
    def volts_per_accel(self) -> np.ndarray:
        """Overall forward gain J_eff/(N·Kt·g_amp) in V per rad/s²."""
        return self.j_eff / (self.ratio * self.kt * self.amp_gain)

    def describe(self) -> list[dict[str, float]]:
        """Per-joint numbers of the chain, for reports (SI, keys carry the units)."""
        out = []
        for j in range(self.n):
            out.append({
                "j_eff_kg_m2": float(self.j_eff[j]),
                "ratio": float(self.ratio[j]),
                "kt_nm_per_a": float(self.kt[j]),
                "amp_gain_a_per_v": float(self.amp_gain[j]),
                "dac_volts_per_count": float(self.dac_volts_per_count[j]),
                "nm_per_accel": float(self.j_eff[j]),
                "amps_per_nm": float(1.0 / (self.ratio[j] * self.kt[j])),
                "volts_per_amp": float(1.0 / self.amp_gain[j]),
                "volts_per_accel": float(self.volts_per_accel[j]),
            })
        return out


def normalizing_chain(
    j_eff: float | np.ndarray | list[float],
    ratio: float | np.ndarray | list[float],
    kt: float | np.ndarray | list[float],
    amp_gain: float | np.ndarray | list[float],
    dac_volts_per_count: float | np.ndarray | list[float] | None = None,
    n: int | None = None,
) -> NormalizingChain:
    """Build the :class:`NormalizingChain` from rig numbers (scalars broadcast to ``n`` joints).

    ``j_eff`` kg·m² at the joint, ``ratio`` N, ``kt`` N·m/A, ``amp_gain`` A/V, ``dac_volts_per_count``
    V/count (optional). ``n`` defaults to the length of the first sequence argument (1 if all are
    scalars). Raises :class:`GainError` for non-positive or non-finite values.
    """
    if n is None:
        n = 1
        for v in (j_eff, ratio, kt, amp_gain, dac_volts_per_count):
            if v is not None and np.ndim(v) == 1:
                n = len(v)  # type: ignore[arg-type]
                break
    dac = np.nan if dac_volts_per_count is None else dac_volts_per_count
    return NormalizingChain(
        j_eff=per_joint("j_eff", j_eff, n, positive=True),
        ratio=per_joint("ratio", ratio, n, positive=True),
        kt=per_joint("kt", kt, n, positive=True),
        amp_gain=per_joint("amp_gain", amp_gain, n, positive=True),
        dac_volts_per_count=per_joint("dac_volts_per_count", dac, n, positive=True, allow_nan=True),
    )


def unit_chain(n: int) -> NormalizingChain:
    """A chain with every gain 1 (torque = accel = current = volts): for tests and pure 1/s² plants."""
    return normalizing_chain(1.0, 1.0, 1.0, 1.0, n=n)
