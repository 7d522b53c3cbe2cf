"""Describing-function (harmonic-balance) prediction of limit cycles in the servo loop.

A single static odd nonlinearity ``v = N(x)`` sits somewhere in the otherwise linear loop. The
loop is opened there (:func:`vmehil.analysis.loop_model.build_loop` with ``break_at``) and the linear
part it sees is written in Lur'e form, x = −G·v. A sinusoid x = A·sin ωt is a candidate limit
cycle when the first harmonic closes the loop::

    1 + G(jω)·N(A) = 0    ⇔    G(jω) = −1/N(A)

For the odd single-valued nonlinearities here N(A) is real and positive, so ω is where G is real
and negative, and A solves N(A) = −1/G(jω). For the **sampled** loop, G is evaluated on the unit
circle, G(e^{jωT}) — python-control's ``describing_function_response`` assumes a continuous
system and mis-scales the frequency of a discrete one (docs/jpl-figures.md), so it is not used.

Where the nonlinearity acts in the loop:

* ``velocity_sensor`` (tach dead band): x is the true joint velocity at the sampling instant, v is
  what the controller reads. On the continuous ideal with P = 1/s² this gives
  G(s) = s·(Kv·s + KvI)/(s³ + Kp·s + Kpi) — the velocity loop closed around the position loop.
* ``position_sensor`` (quantization): x is the sampled angle, v the quantized reading (also the
  encoder velocity's input).
* ``actuator`` (saturation): x is the controller output a_k, v the applied command; G = L.
* ``friction`` (Coulomb relay): x is the true (continuous) joint velocity, v the friction
  acceleration acting as −v. Friction is a continuous-time element inside a sampled loop, so
  G(jω) is evaluated with the sampled controller reduced to its fundamental harmonic,
  K(e^{jωT})·(1 − e^{−jωT})/(jωT)·e^{−jωdT} (sampler, zero-order hold and delay, aliases ignored —
  accurate well below the Nyquist frequency).

Stability of each predicted cycle (Loeb's criterion in its equivalent-gain form): replace N by its
value just above and just below the predicted amplitude and look at the closed-loop poles. The
cycle is stable (an attractor) when the loop is stable for amplitudes slightly above A (they decay
back) and unstable slightly below (they grow back).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import control as ct
import numpy as np
from scipy.optimize import brentq

from vmehil.analysis.loop_model import (
    LoopConfig,
    _eval_ss,
    build_loop,
    closed_loop_poles,
    continuous_plant,
    controllable_poles,
    sampled_controller,
)

# ---------------------------------------------------------------------- nonlinearities


class Nonlinearity(ABC):
    """A static odd nonlinearity with a real describing function N(A) (output fundamental / A)."""

    name: str = "nonlinearity"
    location: str = "actuator"
    x_unit: str = ""

    @abstractmethod
    def df(self, a: float) -> float:
        """Describing function N(A) for an input amplitude A > 0 (dimensionless gain)."""

    @abstractmethod
    def __call__(self, x: np.ndarray) -> np.ndarray:
        """The static map v = N(x) (for time-domain checks)."""

    def amplitude_range(self) -> tuple[float, float]:
        """Interval of input amplitudes searched for N(A) = k."""
        return (1e-9, 1e9)

    def amplitudes_for_gain(self, k: float) -> list[float]:
        """All amplitudes A with N(A) = k (found on a log grid, refined by Brent's method)."""
        lo, hi = self.amplitude_range()
        a = np.logspace(math.log10(lo), math.log10(hi), 4000)
        r = self.df_array(a) - k
        out = []
        for i in range(len(a) - 1):
            if r[i] == 0:
                out.append(float(a[i]))
            elif r[i] * r[i + 1] < 0:
                out.append(float(brentq(lambda x: self.df(x) - k, a[i], a[i + 1], xtol=1e-14, rtol=1e-12)))
        return out

    def df_array(self, a: np.ndarray) -> np.ndarray:
        """:meth:`df` at every amplitude of ``a`` (a subclass may compute them at once)."""
        return np.array([self.df(x) for x in a])

    def describe(self) -> dict:
        return {"type": self.name, "location": self.location}


@dataclass
class DeadZone(Nonlinearity):
    """Dead zone of half-width δ with unit slope outside: v = x − δ·sign(x) for |x| > δ, else 0.

    A tach whose brush drop hides speeds below δ = V_brush / (V per rad/s). N(A) = 1 − (2/π)
    (asin r + r·√(1 − r²)), r = δ/A, for A > δ; 0 otherwise. N rises from 0 to 1.
    """

    half_width: float
    location: str = "velocity_sensor"
    x_unit: str = "rad/s"
    name: str = "dead zone"

    def df(self, a: float) -> float:
        if a <= self.half_width:
            return 0.0
        r = self.half_width / a
        return 1.0 - (2.0 / math.pi) * (math.asin(r) + r * math.sqrt(1.0 - r * r))

    def __call__(self, x):
        x = np.asarray(x, dtype=float)
        return np.where(np.abs(x) > self.half_width, x - self.half_width * np.sign(x), 0.0)

    def amplitudes_for_gain(self, k: float) -> list[float]:
        if not (0.0 < k < 1.0):
            return []
        r = brentq(lambda r: (1.0 - (2 / math.pi) * (math.asin(r) + r * math.sqrt(1 - r * r))) - k,
                   0.0, 1.0, xtol=1e-15, rtol=1e-14)
        return [self.half_width / r]

    def describe(self) -> dict:
        return {**super().describe(), "half_width": self.half_width, "unit": self.x_unit}


@dataclass
class Saturation(Nonlinearity):
    """Unit-slope saturation at ±limit. N(A) = 1 for A ≤ limit, else (2/π)(asin r + r√(1 − r²)), r = limit/A."""

    limit: float
    location: str = "actuator"
    x_unit: str = "rad/s²"
    name: str = "saturation"

    def df(self, a: float) -> float:
        if a <= self.limit:
            return 1.0
        r = self.limit / a
        return (2.0 / math.pi) * (math.asin(r) + r * math.sqrt(1.0 - r * r))

    def __call__(self, x):
        return np.clip(np.asarray(x, dtype=float), -self.limit, self.limit)

    def amplitudes_for_gain(self, k: float) -> list[float]:
        if not (0.0 < k < 1.0):
            return []
        r = brentq(lambda r: (2 / math.pi) * (math.asin(r) + r * math.sqrt(1 - r * r)) - k,
                   0.0, 1.0, xtol=1e-15, rtol=1e-14)
        return [self.limit / r]

    def describe(self) -> dict:
        return {**super().describe(), "limit": self.limit, "unit": self.x_unit}


@dataclass
class Relay(Nonlinearity):
    """Ideal relay v = M·sign(x): Coulomb friction (M = F_c/J in rad/s² on the normalized loop).
    N(A) = 4M/(πA)."""

    level: float
    location: str = "friction"
    x_unit: str = "rad/s"
    name: str = "relay"

    def df(self, a: float) -> float:
        return 4.0 * self.level / (math.pi * a)

    def __call__(self, x):
        return self.level * np.sign(np.asarray(x, dtype=float))

    def amplitudes_for_gain(self, k: float) -> list[float]:
        return [4.0 * self.level / (math.pi * k)] if k > 0 else []

    def describe(self) -> dict:
        return {**super().describe(), "level": self.level}


@dataclass
class Quantizer(Nonlinearity):
    """Mid-tread rounding quantizer of step q: v = q·round(x/q).

    N(A) = 0 for A < q/2, else (4q/(πA))·Σ_{i=1..n} √(1 − ((2i − 1)q/(2A))²) over the n levels
    the sinusoid crosses. N is not monotonic (peak ≈ 1.27 just above A = q/2, ripples toward 1),
    so several cycles may be predicted.
    """

    step: float
    location: str = "position_sensor"
    x_unit: str = "rad"
    name: str = "quantizer"

    def df(self, a: float) -> float:
        q = self.step
        if a < q / 2:
            return 0.0
        n = math.floor(a / q + 0.5)
        i = np.arange(1, n + 1)
        t = (2 * i - 1) * q / (2 * a)
        t = t[t < 1.0]
        return float(4 * q / (math.pi * a) * np.sum(np.sqrt(1.0 - t * t)))

    def df_array(self, a: np.ndarray) -> np.ndarray:
        """:meth:`df` at every amplitude at once: level i counts where (2i − 1)q/(2A) < 1."""
        q = self.step
        a = np.asarray(a, dtype=float)
        out = np.zeros(a.shape)
        ok = a >= q / 2
        if not ok.any():
            return out
        aa = a[ok]
        n_max = math.floor(float(aa.max()) / q + 0.5)
        i = np.arange(1, n_max + 1)
        t = (2 * i[None, :] - 1) * q / (2 * aa[:, None])
        n = np.floor(aa / q + 0.5)
        terms = np.where((i[None, :] <= n[:, None]) & (t < 1.0), np.sqrt(np.clip(1.0 - t * t, 0.0, None)), 0.0)
        out[ok] = 4 * q / (math.pi * aa) * terms.sum(axis=1)
        return out

    def __call__(self, x):
        return self.step * np.round(np.asarray(x, dtype=float) / self.step)

    def amplitude_range(self) -> tuple[float, float]:
        return (0.5 * self.step * (1 + 1e-12), 200 * self.step)

    def describe(self) -> dict:
        return {**super().describe(), "step": self.step, "unit": self.x_unit}


# ------------------------------------------------------------------------- solutions


@dataclass
class Cycle:
    """One predicted limit cycle. amplitude_x is at the nonlinearity's input (its units);
    amplitude_rad / amplitude_deg is the joint-angle amplitude (half peak-to-peak), when known."""

    nonlinearity: str
    location: str
    frequency_hz: float
    amplitude_x: float
    equivalent_gain: float
    g_real: float
    stable: bool
    amplitude_rad: float | None = None

    @property
    def amplitude_deg(self) -> float | None:
        return None if self.amplitude_rad is None else math.degrees(self.amplitude_rad)

    def as_dict(self) -> dict:
        def num(v: float | None) -> float | None:
            return None if v is None or not math.isfinite(v) else float(v)

        return {
            "nonlinearity": self.nonlinearity, "location": self.location,
            "frequency_hz": num(self.frequency_hz), "amplitude_x": num(self.amplitude_x),
            "amplitude_rad": num(self.amplitude_rad), "amplitude_deg": num(self.amplitude_deg),
            "equivalent_gain": num(self.equivalent_gain), "g_at_crossing": num(self.g_real),
            "stable": bool(self.stable),
        }


def real_axis_crossings(G: Callable[[np.ndarray], np.ndarray], f_max_hz: float, f_min_hz: float = 1e-2,
                        n: int = 4000, include_f_max: bool = False) -> list[tuple[float, float]]:
    """Frequencies (Hz) where G(f) crosses the negative real axis, with the real value there.

    ``include_f_max``: also test the end point (the Nyquist frequency of a sampled G, where G is real).
    """
    top = f_max_hz * (1 - 1e-9) if include_f_max else f_max_hz
    f = np.logspace(math.log10(f_min_hz), math.log10(top), n)
    g = G(f)
    ok = np.isfinite(g) & (np.abs(g) < 1e12)
    out = []
    for i in range(n - 1):
        if not (ok[i] and ok[i + 1]):
            continue
        if g[i].imag * g[i + 1].imag < 0 or g[i].imag == 0:
            try:
                f0 = brentq(lambda x: G(np.array([x]))[0].imag, f[i], f[i + 1], xtol=1e-13, rtol=1e-13)
            except ValueError:
                continue
            g0 = complex(G(np.array([f0]))[0])
            if g0.real < 0 and abs(g0.imag) <= 1e-6 * abs(g0) and abs(g0) < 1e12:
                out.append((float(f0), g0.real))
    if include_f_max:
        g0 = complex(G(np.array([f_max_hz]))[0])
        if np.isfinite(g0) and g0.real < 0:
            out.append((float(f_max_hz), g0.real))
    return out


def solve_cycles(G: Callable[[np.ndarray], np.ndarray], nl: Nonlinearity, n_unstable: Callable[[float], int],
                 f_max_hz: float, include_f_max: bool = False, eps: float = 0.02,
                 theta_per_v: Callable[[float], complex] | None = None) -> list[Cycle]:
    """Harmonic balance for x = −G·N(x): every (f, A) with G(f) = −1/N(A), and its stability.

    ``n_unstable(k)``: number of unstable closed-loop poles with N replaced by the gain k.
    ``theta_per_v(f)``: joint angle per unit of the nonlinearity's output at f (for amplitude_rad).
    """
    cycles = []
    for f0, g0 in real_axis_crossings(G, f_max_hz, include_f_max=include_f_max):
        k = -1.0 / g0
        for a in nl.amplitudes_for_gain(k):
            above, below = nl.df(a * (1 + eps)), nl.df(a * (1 - eps))
            stable = n_unstable(above) == 0 and n_unstable(below) > 0
            amp_rad = None
            if theta_per_v is not None:
                amp_rad = abs(theta_per_v(f0)) * k * a
            cycles.append(Cycle(nl.name, nl.location, f0, a, k, g0, stable, amp_rad))
    return cycles


# ------------------------------------------------------------- generic Lur'e systems


def lure_response(G: ct.StateSpace | ct.TransferFunction) -> Callable[[np.ndarray], np.ndarray]:
    """f (Hz) → G on the imaginary axis (continuous) or on the unit circle e^{j2πfT} (discrete)."""
    g = ct.ss(G)

    def fn(f: np.ndarray) -> np.ndarray:
        w = 2 * np.pi * np.asarray(f, dtype=float)
        x = np.exp(1j * w * g.dt) if g.isdtime(strict=True) else 1j * w
        return _eval_ss(g.A, g.B, g.C, g.D, x)[0, 0]

    return fn


def predict_lure(G: ct.StateSpace | ct.TransferFunction, nl: Nonlinearity,
                 f_max_hz: float | None = None) -> list[Cycle]:
    """Limit cycles of the Lur'e loop x = −G·N(x) for a SISO G (continuous or discrete)."""
    g = ct.ss(G)
    sampled = g.isdtime(strict=True)
    if f_max_hz is None:
        f_max_hz = 0.5 / g.dt if sampled else 1e3

    def n_unstable(k: float) -> int:
        d = float(g.D[0, 0])
        Acl = g.A - g.B @ g.C * (k / (1.0 + k * d))
        p = np.linalg.eigvals(Acl)
        return int(np.sum(np.abs(p) >= 1.0) if sampled else np.sum(p.real >= 0))

    return solve_cycles(lure_response(g), nl, n_unstable, f_max_hz, include_f_max=sampled)


# --------------------------------------------------------------- the servo loop itself


def hybrid_response_fn(cfg: LoopConfig, location: str = "friction") -> Callable[[np.ndarray], tuple]:
    """f (Hz) → (G, θ/v) of the sampled loop for a continuous-time nonlinearity, to the
    fundamental harmonic.

    The sampled controller acts through sampler → K(e^{jωT}) → hold·delay, reduced to
    H(jω) = (1 − e^{−jωT})/(jωT)·e^{−jωdT}; the plant is the continuous one. Only ``friction``
    and ``actuator`` are supported (the others act on samples: use :func:`linear_response`).
    """
    if location not in ("friction", "actuator"):
        raise ValueError(f"hybrid_response supports friction and actuator, not {location!r}")
    T, dly = cfg.sample_period_s, cfg.delay_s
    P = continuous_plant(cfg.replace(velocity_source="tach"))
    K = sampled_controller(cfg.gains, T, cfg.velocity_source, cfg.kvi_filter_hz)

    def fn(f_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = 2 * np.pi * np.atleast_1d(np.asarray(f_hz, dtype=float))
        Pj = _eval_ss(P.A, P.B, P.C, P.D, 1j * w)  # (4, 2, n): [ths, ws, th, om] × [u, w]
        Kz = _eval_ss(K.A, K.B, K.C, K.D, np.exp(1j * w * T))[0, 2:4]  # (2, n): ∂a/∂[thin, win]
        with np.errstate(all="ignore"):
            H = np.where(w > 0, (1 - np.exp(-1j * w * T)) / (1j * w * T), 1.0) * np.exp(-1j * w * dly)
            M = H * Kz  # (2, n): gain from the sensor outputs [ths, ws] to u (encoder: ws unused)
            KPu = M[0] * Pj[0, 0] + M[1] * Pj[1, 0]
            if location == "friction":
                KPw = M[0] * Pj[0, 1] + M[1] * Pj[1, 1]
                u_per_w = KPw / (1 - KPu)
                om_per_w = Pj[3, 0] * u_per_w + Pj[3, 1]
                th_per_w = Pj[2, 0] * u_per_w + Pj[2, 1]
                return om_per_w, -th_per_w  # friction acceleration is −v
            return -KPu, Pj[2, 0]  # actuator: x = a = M·y, y = P_u·v, G = −x/v

    return fn


def hybrid_response(cfg: LoopConfig, f_hz: np.ndarray, location: str = "friction") -> tuple[np.ndarray, np.ndarray]:
    """(G, θ/v) at ``f_hz`` — see :func:`hybrid_response_fn`."""
    return hybrid_response_fn(cfg, location)(f_hz)


def linear_response_fn(cfg: LoopConfig, location: str, sampled: bool) -> Callable[[np.ndarray], tuple]:
    """f (Hz) → (G, θ/v) seen by a nonlinearity at ``location`` (the loop is built once)."""
    if sampled and location == "friction":
        return hybrid_response_fn(cfg, location)
    br = build_loop(cfg, sampled, location)
    iv = br.input_labels.index("v")
    ix, ith = br.output_labels.index("x"), br.output_labels.index("th")
    A, B, C, D = br.A, br.B[:, [iv]], br.C[[ix, ith]], br.D[[ix, ith]][:, [iv]]
    T = cfg.sample_period_s

    def fn(f_hz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        w = 2 * np.pi * np.atleast_1d(np.asarray(f_hz, dtype=float))
        H = _eval_ss(A, B, C, D, np.exp(1j * w * T) if sampled else 1j * w)
        return -H[0, 0], H[1, 0]

    return fn


def linear_response(cfg: LoopConfig, location: str, f_hz: np.ndarray, sampled: bool) -> tuple[np.ndarray, np.ndarray]:
    """(G, θ/v) seen by a nonlinearity at ``location`` at the frequencies ``f_hz`` (Hz)."""
    return linear_response_fn(cfg, location, sampled)(f_hz)


def gain_loop_poles(cfg: LoopConfig, location: str, k: float, sampled: bool) -> np.ndarray:
    """Closed-loop poles with the nonlinearity at ``location`` replaced by the linear gain k."""
    if location == "friction" and sampled:
        return closed_loop_poles(cfg.replace(viscous_damping=cfg.viscous_damping + k), True)
    return _gain_poles(build_loop(cfg, sampled, location), k)


def _gain_poles(br: ct.StateSpace, k: float) -> np.ndarray:
    iv = br.input_labels.index("v")
    ix = br.output_labels.index("x")
    d = float(br.D[ix, iv])
    Acl = br.A + np.outer(br.B[:, iv], br.C[ix]) * (k / (1.0 - k * d))
    return controllable_poles(Acl, br.B[:, [0, 2]])


def predict_cycles(cfg: LoopConfig, nl: Nonlinearity, sampled: bool = True,
                   f_max_hz: float | None = None) -> list[Cycle]:
    """Limit cycles the describing function predicts for ``nl`` in the servo loop ``cfg``."""
    if f_max_hz is None:
        f_max_hz = cfg.nyquist_hz if sampled else 200.0
    if sampled and nl.location == "friction":
        f_max_hz = min(f_max_hz, 0.5 * cfg.nyquist_hz)  # the fundamental-harmonic reduction needs ω ≪ π/T
    resp = linear_response_fn(cfg, nl.location, sampled)
    br = None if (sampled and nl.location == "friction") else build_loop(cfg, sampled, nl.location)

    def n_unstable(k: float) -> int:
        p = gain_loop_poles(cfg, nl.location, k, sampled) if br is None else _gain_poles(br, k)
        return int(np.sum(np.abs(p) >= 1.0) if sampled else np.sum(p.real >= 0))

    include_end = sampled and nl.location != "friction"
    return solve_cycles(lambda f: resp(f)[0], nl, n_unstable, f_max_hz, include_f_max=include_end,
                        theta_per_v=lambda f: complex(resp(np.array([f]))[1][0]))


def predict_joint_velocity(cfg: LoopConfig, nls: list[Nonlinearity], sampled: bool = True,
                           a_range: tuple[float, float] = (1e-4, 20.0), n: int = 48) -> list[Cycle]:
    """Cycles with several nonlinearities driven by the joint velocity at once (equivalent gains).

    ``nls``: a tach dead zone (``velocity_sensor``) and/or Coulomb friction (``friction``). For a
    joint-velocity amplitude A each is replaced by its describing-function gain — the dead zone
    scales the sampled tach reading by N₁(A), friction becomes viscous damping N₂(A) in the
    continuous plant (so the sampled model stays exact). A cycle is where the resulting linear
    loop is marginally stable: the dominant closed-loop pole pair is on the unit circle (sampled)
    or the imaginary axis (continuous); its angle gives the frequency and θ = A/ω the joint-angle
    amplitude. Stable when the loop is stable just above A and unstable just below (Loeb). With a
    single nonlinearity this is the same harmonic balance as :func:`predict_cycles`.
    """
    dz = [x for x in nls if x.location == "velocity_sensor"]
    fr = [x for x in nls if x.location == "friction"]
    if len(dz) > 1 or len(fr) > 1 or len(dz) + len(fr) != len(nls) or not nls:
        raise ValueError("predict_joint_velocity takes at most one velocity-sensor and one friction nonlinearity")
    if dz and cfg.velocity_source != "tach":
        raise ValueError("a velocity-sensor nonlinearity needs velocity_source='tach'")
    name = " + ".join(x.name for x in nls)
    location = "+".join(x.location for x in nls)
    T = cfg.sample_period_s

    def dominant(a: float) -> tuple[float, complex]:
        c = sum(x.df(a) for x in fr)
        cfg_a = cfg.replace(viscous_damping=cfg.viscous_damping + c)
        if dz:
            p = _gain_poles(build_loop(cfg_a, sampled, "velocity_sensor"), dz[0].df(a))
        else:
            p = closed_loop_poles(cfg_a, sampled)
        if sampled:
            i = int(np.argmax(np.abs(p)))
            return float(abs(p[i]) - 1.0), complex(p[i])
        i = int(np.argmax(p.real))
        return float(p[i].real), complex(p[i])

    amps = np.logspace(math.log10(a_range[0]), math.log10(a_range[1]), n)
    r = np.array([dominant(a)[0] for a in amps])
    cycles = []
    for i in range(n - 1):
        if not (r[i] * r[i + 1] < 0):
            continue
        a0 = float(brentq(lambda a: dominant(a)[0], amps[i], amps[i + 1], xtol=1e-12, rtol=1e-8))
        _, p = dominant(a0)
        w = abs(np.angle(p)) / T if sampled else abs(p.imag)
        if w < 1e-6:
            continue  # a real pole crossing: drift, not an oscillation
        stable = dominant(a0 * 1.02)[0] < 0 and dominant(a0 * 0.98)[0] > 0
        k = dz[0].df(a0) if dz else 1.0
        cycles.append(Cycle(name, location, float(w / (2 * math.pi)), a0, k, float("nan"), stable, float(a0 / w)))
    return cycles


def headline(cycles: list[Cycle]) -> Cycle | None:
    """The cycle to report first: the largest stable one (None when no stable cycle is predicted)."""
    stable = [(c.amplitude_rad, c) for c in cycles if c.stable and c.amplitude_rad is not None]
    return max(stable, key=lambda ac: ac[0])[1] if stable else None


# ------------------------------------------------------------- time-domain check


def simulate_sampled(cfg: LoopConfig, nl: Nonlinearity, n_steps: int, r0: float = 0.0,
                     x0: np.ndarray | None = None, kick: float = 0.0) -> dict[str, np.ndarray]:
    """Brute-force simulation of the sampled loop with ``nl`` acting on samples.

    Exact for nonlinearities at ``actuator``, ``position_sensor`` and ``velocity_sensor`` (the
    plant discretization is exact and the nonlinearity sees exactly the samples). Starts from rest
    with θd = r0 and an initial joint rate ``kick`` (rad/s), or from the loop state ``x0``.
    Returns t (s), theta (rad), x (nonlinearity input) and v (its output), one entry per sample.
    """
    if nl.location == "friction":
        raise ValueError("friction acts in continuous time; simulate it with the plant emulator")
    br = build_loop(cfg, True, nl.location)
    iv = br.input_labels.index("v")
    ix = br.output_labels.index("x")
    ith = br.output_labels.index("th")
    if abs(br.D[ix, iv]) > 0:
        raise ValueError("algebraic loop through the nonlinearity")
    A, B, C, D = br.A, br.B, br.C, br.D
    xi = np.zeros(A.shape[0]) if x0 is None else np.asarray(x0, dtype=float).copy()
    if kick and x0 is None:
        # an initial rate: the plant state order is [θ, ω, ...] (see loop._plant_matrices)
        xi[1] = kick
    ext = np.array([r0, 0.0, 0.0])
    th = np.empty(n_steps)
    xs = np.empty(n_steps)
    vs = np.empty(n_steps)
    for k in range(n_steps):
        x = C[ix] @ xi + D[ix, :3] @ ext
        v = float(nl(np.array([x]))[0])
        th[k] = C[ith] @ xi + D[ith, :3] @ ext
        xs[k], vs[k] = x, v
        xi = A @ xi + B[:, :3] @ ext + B[:, iv] * v
    return {"t": np.arange(n_steps) * cfg.sample_period_s, "theta": th, "x": xs, "v": vs}


def measure_cycle(t: np.ndarray, y: np.ndarray, settle_fraction: float = 0.5) -> tuple[float | None, float | None]:
    """(amplitude, frequency Hz) of a steady oscillation in the last part of a record.

    Amplitude is half the peak-to-peak; frequency comes from the mean spacing of upward mean
    crossings (linear interpolation). (None, None) when the record does not oscillate.
    """
    n0 = int(len(t) * settle_fraction)
    tt, yy = np.asarray(t[n0:]), np.asarray(y[n0:], dtype=float)
    if yy.size < 4:
        return None, None
    amp = 0.5 * float(np.max(yy) - np.min(yy))
    if amp <= 1e-12 * max(1.0, float(np.max(np.abs(yy)))):
        return None, None
    z = yy - 0.5 * (np.max(yy) + np.min(yy))
    idx = np.nonzero((z[:-1] < 0) & (z[1:] >= 0))[0]
    if idx.size < 3:
        return amp, None
    tc = tt[idx] - z[idx] * (tt[idx + 1] - tt[idx]) / (z[idx + 1] - z[idx])
    return amp, float((idx.size - 1) / (tc[-1] - tc[0]))


def simulate_joint(cfg: LoopConfig, seconds: float, deadband_rad_s: float = 0.0, coulomb_accel: float = 0.0,
                   breakout_accel: float | None = None, kick: float = 1.0, r0: float = 0.0,
                   substeps: int = 32) -> dict[str, np.ndarray]:
    """Reduced nonlinear joint: the sampled servo law driving 1/s² with Coulomb friction and stiction.

    Normalized units: friction as accelerations (torque/J, rad/s²). The tach reading is the joint
    velocity through a dead zone of ``deadband_rad_s``. Friction is Karnopp-style: a stopped joint
    stays stuck while the commanded acceleration is below ``breakout_accel`` (default: the Coulomb
    level); a velocity crossing zero inside a sub-step is captured at zero. The plant is integrated
    with ``substeps`` steps per servo period (the command changes after the computation delay).
    Viscous friction is ``cfg.viscous_damping`` (1/s). This is a check on the describing function,
    not the plant emulator: no motor, gearing, sensor noise or amplifier dynamics (the other ``cfg``
    analog options are ignored).
    """
    T, d = cfg.sample_period_s, cfg.delay_fraction
    K = sampled_controller(cfg.gains, T, cfg.velocity_source, cfg.kvi_filter_hz)
    Ka, Kb, Kc, Kd = K.A, K.B, K.C[0], K.D[0]
    h = T / substeps
    j_switch = round(d * substeps)
    stick = coulomb_accel if breakout_accel is None else breakout_accel
    c_visc = cfg.viscous_damping
    n = round(seconds / T)
    xk = np.zeros(Ka.shape[0])
    th, om, a_prev = 0.0, float(kick), 0.0
    out = np.empty(n)
    for k in range(n):
        w_meas = om - deadband_rad_s * math.copysign(1.0, om) if abs(om) > deadband_rad_s else 0.0
        q = np.array([r0, 0.0, th, w_meas])
        a = float(Kc @ xk + Kd @ q)
        xk = Ka @ xk + Kb @ q
        out[k] = th
        for j in range(substeps):
            acc = a_prev if j < j_switch else a
            if om == 0.0 and abs(acc) <= stick:
                continue  # stuck
            sgn = math.copysign(1.0, om) if om != 0.0 else math.copysign(1.0, acc)
            om_new = om + h * (acc - coulomb_accel * sgn - c_visc * om)
            if om != 0.0 and om_new * om < 0.0:
                om_new = 0.0  # captured at zero velocity; stiction decides on the next sub-step
            elif om == 0.0 and om_new * sgn < 0.0:
                om_new = 0.0
            th += 0.5 * h * (om + om_new)
            om = om_new
        a_prev = a
    return {"t": np.arange(n) * T, "theta": out}
