"""Stability margins, crossover and bandwidth of the servo loop, continuous and sampled.

The margins are computed from the frequency response on a dense logarithmic grid with each
crossing refined by Brent's method, on the open loop broken at the plant input
(:func:`vmehil.analysis.loop_model.open_loop`). Definitions (L = loop transfer, closed loop 1 + L):

* **phase margin** (deg): 180° + ∠L at the gain crossover |L| = 1; the smallest over all
  crossovers is reported, with its frequency as ``crossover_hz``;
* **gain margin** (dB): how much the loop gain may *rise* before instability, −20·log10|L| at a
  phase crossover (∠L = −180°) where |L| < 1; ``None`` (JSON null) when there is none (infinite);
* **gain-reduction margin** (dB, negative): how much the gain may *fall* — the JPL loop has three
  integrators (1/s² plant and the position integral), so it is conditionally stable: the phase
  is below −180° at low frequency where |L| ≫ 1 and too little gain destabilizes it;
* **bandwidth** (Hz): first frequency where |θ/θd| falls 3 dB below its low-frequency value.

Sampled responses are evaluated on the unit circle up to the Nyquist frequency (the response
is symmetric beyond it); a phase crossover exactly at Nyquist (L(−1) < 0) counts.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import control as ct
import numpy as np
from scipy.optimize import brentq

from vmehil.analysis.loop_model import LoopConfig, closed_loop, closed_loop_poles, freqresp, open_loop, poles_stable

F_MIN_HZ = 1e-3
F_MAX_CONTINUOUS_HZ = 1e3


@dataclass
class Margins:
    """Margins and bandwidth of one loop model (see the module docstring for definitions)."""

    stable: bool
    gain_margin_db: float | None
    gain_margin_hz: float | None
    gain_reduction_margin_db: float | None
    gain_reduction_hz: float | None
    phase_margin_deg: float | None
    crossover_hz: float | None
    delay_margin_s: float | None
    bandwidth_hz: float | None
    peak_db: float | None  #: closed-loop resonance peak above the low-frequency gain (dB)
    peak_hz: float | None  #: its frequency (None when the magnitude never rises above DC)
    sensitivity_peak_db: float | None
    poles: list[complex]

    def as_dict(self) -> dict:
        d = asdict(self)
        d["poles"] = [{"re": float(p.real), "im": float(p.imag)} for p in self.poles]
        return {k: (_clean(v) if k != "poles" else v) for k, v in d.items()}


def _clean(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def frequency_grid(f_max_hz: float, f_min_hz: float = F_MIN_HZ, n: int = 3000) -> np.ndarray:
    return np.logspace(math.log10(f_min_hz), math.log10(f_max_hz), n)


def _refine(fun, a: float, b: float) -> float:
    try:
        return float(brentq(fun, a, b, xtol=1e-12, rtol=1e-12, maxiter=200))
    except ValueError:
        return 0.5 * (a + b)


def _at(sys: ct.StateSpace, f: float) -> complex:
    return complex(freqresp(sys, np.array([f]))[0])


def crossings(L: ct.StateSpace, f_max_hz: float, f_min_hz: float = F_MIN_HZ, *,
              grid: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, list[tuple[float, complex]]]:
    """Gain crossovers (|L| = 1) and phase crossovers (L real negative) as (f Hz, L(f)) lists.
    ``grid``: (f, L(f)) on this function's own grid, when the caller has it already."""
    sampled = L.isdtime(strict=True)
    f_top = f_max_hz * (1 - 1e-9) if sampled else f_max_hz
    if grid is None:
        f = frequency_grid(f_top, f_min_hz)
        H = freqresp(L, f)
    else:
        f, H = grid
    finite = np.isfinite(H) & (np.abs(H) < 1e12)
    gain: list[tuple[float, complex]] = []
    phase: list[tuple[float, complex]] = []
    lg = np.log(np.abs(H))
    for i in range(len(f) - 1):
        if not (finite[i] and finite[i + 1]):
            continue
        if lg[i] == 0 or lg[i] * lg[i + 1] < 0:
            fc = _refine(lambda x: math.log(abs(_at(L, x))), f[i], f[i + 1])
            gain.append((fc, _at(L, fc)))
        if H[i].imag == 0 or H[i].imag * H[i + 1].imag < 0:
            fp = _refine(lambda x: _at(L, x).imag, f[i], f[i + 1])
            h = _at(L, fp)
            if h.real < 0 and abs(h.imag) <= 1e-6 * abs(h) + 1e-12:
                phase.append((fp, h))
    if sampled:
        h = _at(L, f_max_hz)
        if h.real < 0 and np.isfinite(h):
            phase.append((f_max_hz, complex(h.real, 0.0)))
    return {"gain": gain, "phase": phase}


def bandwidth_hz(T: ct.StateSpace, f_max_hz: float, f_min_hz: float = F_MIN_HZ, drop_db: float = -3.0, *,
                 grid: tuple[np.ndarray, np.ndarray] | None = None) -> float | None:
    """First frequency (Hz) where |T| falls ``drop_db`` below |T(f_min)|; None if it never does.
    ``grid``: (f, T(f)) on this function's own grid, when the caller has it already."""
    if grid is None:
        f = frequency_grid(f_max_hz, f_min_hz)
        HT = freqresp(T, f)
    else:
        f, HT = grid
    mag = np.abs(HT)
    ref = mag[0] * 10 ** (drop_db / 20)
    below = np.nonzero(mag < ref)[0]
    if below.size == 0:
        return None
    i = int(below[0])
    if i == 0:
        return float(f[0])
    return _refine(lambda x: abs(_at(T, x)) - ref, f[i - 1], f[i])


def compute_margins(cfg: LoopConfig, sampled: bool, f_max_hz: float | None = None) -> Margins:
    """All margins of the continuous ideal (``sampled=False``) or the sampled loop."""
    L = open_loop(cfg, sampled)
    T = closed_loop(cfg, sampled)
    if f_max_hz is None:
        f_max_hz = cfg.nyquist_hz if sampled else F_MAX_CONTINUOUS_HZ
    # one grid for every figure below (the crossings', the peak's, the bandwidth's: the same
    # frequencies), each response evaluated once on it
    f_top = f_max_hz * (1 - 1e-9) if sampled else f_max_hz
    f = frequency_grid(f_top)
    HL, HT = freqresp(L, f), freqresp(T, f)
    cr = crossings(L, f_max_hz, grid=(f, HL))
    up = [(f, -20 * math.log10(abs(h))) for f, h in cr["phase"] if abs(h) < 1]
    down = [(f, -20 * math.log10(abs(h))) for f, h in cr["phase"] if abs(h) > 1]
    gm = min(up, key=lambda t: t[1]) if up else (None, None)
    gr = max(down, key=lambda t: t[1]) if down else (None, None)
    pms = [(f, _wrap180(180.0 + math.degrees(np.angle(h)))) for f, h in cr["gain"]]
    pm = min(pms, key=lambda t: t[1]) if pms else (None, None)
    delay = None
    if pm[0] is not None and pm[1] is not None and pm[1] > 0:
        delay = math.radians(pm[1]) / (2 * math.pi * pm[0])
    Tm = np.abs(HT)
    k = int(np.argmax(Tm))
    S = np.abs(1.0 / (1.0 + HL))
    poles = closed_loop_poles(cfg, sampled)
    return Margins(
        stable=poles_stable(poles, sampled),
        gain_margin_db=gm[1], gain_margin_hz=gm[0],
        gain_reduction_margin_db=gr[1], gain_reduction_hz=gr[0],
        phase_margin_deg=pm[1], crossover_hz=pm[0], delay_margin_s=delay,
        bandwidth_hz=bandwidth_hz(T, f_top, grid=(f, HT)),
        peak_db=20 * math.log10(Tm[k] / Tm[0]) if k > 0 else 0.0, peak_hz=float(f[k]) if k > 0 else None,
        sensitivity_peak_db=20 * math.log10(float(np.max(S))),
        poles=sorted((complex(p) for p in poles), key=lambda p: (p.real, p.imag)),
    )


def _wrap180(deg: float) -> float:
    """Wrap an angle to (−180, 180]."""
    w = (deg + 180.0) % 360.0 - 180.0
    return 180.0 if w == -180.0 else w


def equivalent_s_poles(z_poles: list[complex], sample_period_s: float) -> list[complex]:
    """s = ln(z)/T for sampled poles (z = 0 maps to −inf and is left out)."""
    return [complex(np.log(complex(p)) / sample_period_s) for p in z_poles if abs(p) > 1e-12]
