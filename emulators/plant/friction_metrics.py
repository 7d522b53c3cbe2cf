"""The running-friction measurement definition shared by the plant tests and the friction CLI.

The JPL test drives joint 1 through ``θd = A·sin(2π·f·t)`` (A = 0.4 rad, f = 0.06 Hz) under a
position loop and records, once per servo period, the motor current ``i`` (amplifier current
monitor) and the motor angle ``θm`` (encoder). From these uniformly sampled records:

* **motor speed and acceleration** ``ωm``, ``αm``: central differences of ``θm``;
* **friction torque estimate** ``τ_f = Kt·i − J_m·αm`` (``J_m``: the joint inertia referred to
  the motor shaft; the inertia term matters for the ripple, not for the mean);
* **fast part**: the samples where the *commanded* joint speed is at least half its peak,
  ``|ωd| ≥ ½·max|ωd|`` (the middle third of every stroke);
* **running torque mean**: ``mean(|τ_f|)`` over the fast part;
* **ripple amplitude**: least squares over the fast part of
  ``τ_f·sign(ωm) ≈ a + b·|ωm| + A·cos(2θm) + B·sin(2θm)`` (the ripple is locked to twice the
  wave-generator angle; regressing on the *measured* speed absorbs the viscous friction's
  response to the speed ripple, so the figure does not depend on the loop's stiffness at the
  ripple frequency); amplitude ``√(A² + B²)``;
* **ripple frequency**: in each stroke's near-peak window (``|ωd| ≥ 0.9·max|ωd|``) the
  frequency of the largest peak of the (Hann-windowed, zero-padded) spectrum of
  ``τ_f·sign(ωm) − a − b·|ωm|``, averaged over the strokes;
* **breakout** (from a slow torque ramp): the torque at which the joint first moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class RunningTorque:
    """Running-friction figures at the motor shaft (N·m, Hz)."""

    mean_nm: float
    ripple_amplitude_nm: float
    ripple_frequency_hz: float
    fast_samples: int
    strokes: int


def running_torque_metrics(
    t: np.ndarray,
    torque_nm: np.ndarray,
    theta_motor: np.ndarray,
    omega_cmd: np.ndarray,
    inertia_motor_kg_m2: float = 0.0,
) -> RunningTorque:
    """Running torque mean, ripple amplitude and ripple frequency (see the module docstring).

    Args:
        t: sample times (s), uniform.
        torque_nm: motor torque ``Kt·i`` (N·m).
        theta_motor: motor angle (rad) at the same instants (encoder).
        omega_cmd: commanded joint speed (rad/s).
        inertia_motor_kg_m2: ``J_m`` for the inertia correction (0: none).
    """
    t = np.asarray(t, float)
    thm = np.asarray(theta_motor, float)
    w = np.asarray(omega_cmd, float)
    dt = float(np.median(np.diff(t)))
    wm = np.gradient(thm, dt)
    am = np.zeros_like(thm)
    am[1:-1] = (thm[2:] - 2.0 * thm[1:-1] + thm[:-2]) / (dt * dt)
    tau = np.asarray(torque_nm, float) - inertia_motor_kg_m2 * am
    wmax = float(np.max(np.abs(w)))
    if wmax <= 0:
        raise ValueError("the commanded speed is zero everywhere; nothing to measure")
    fast = np.abs(w) >= 0.5 * wmax
    if np.count_nonzero(fast) < 16:
        raise ValueError("too few samples in the fast part of the strokes")
    s = np.sign(wm[fast])
    y = tau[fast] * s
    aw = np.abs(wm[fast])
    mean = float(np.mean(np.abs(tau[fast])))
    X = np.column_stack([np.ones_like(aw), aw, np.cos(2.0 * thm[fast]), np.sin(2.0 * thm[fast])])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    amp = float(np.hypot(coef[2], coef[3]))
    resid = np.zeros_like(tau)
    resid[fast] = y - X[:, :2] @ coef[:2]
    # ripple frequency in each near-peak window
    peak = np.abs(w) >= 0.9 * wmax
    edges = np.flatnonzero(np.diff(np.concatenate(([0], peak.astype(np.int8), [0]))))
    freqs = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        seg = resid[a:b]
        if len(seg) < 32:
            continue
        seg = (seg - seg.mean()) * np.hanning(len(seg))
        nfft = 1 << int(np.ceil(np.log2(len(seg) * 16)))
        spec = np.abs(np.fft.rfft(seg, nfft))
        f = np.fft.rfftfreq(nfft, dt)
        spec[f < 0.5] = 0.0
        freqs.append(float(f[int(np.argmax(spec))]))
    strokes = len(freqs)
    return RunningTorque(
        mean_nm=mean,
        ripple_amplitude_nm=amp,
        ripple_frequency_hz=float(np.mean(freqs)) if freqs else float("nan"),
        fast_samples=int(np.count_nonzero(fast)),
        strokes=strokes,
    )


def breakout_from_ramp(torque_nm: np.ndarray, moved: np.ndarray) -> float:
    """The torque (N·m) at the first sample where ``moved`` is true during a slow ramp."""
    moved = np.asarray(moved, bool)
    if not moved.any():
        raise ValueError("the joint never moved during the ramp; raise the ramp's end torque")
    return float(np.abs(np.asarray(torque_nm, float)[int(np.argmax(moved))]))


@dataclass
class DeadbandCycle:
    """Describing-function prediction of the velocity-dead-band limit cycle."""

    amplitude_rad: float  #: joint position amplitude (half peak-to-peak)
    frequency_hz: float
    speed_amplitude_rad_s: float  #: joint speed amplitude V (just above the dead band)
    deadzone_gain: float  #: N(V), the dead zone's describing function at V


def deadzone_df(v: float, d: float) -> float:
    """Describing function of a unit-slope dead zone of half-width ``d`` at amplitude ``v``."""
    if v <= d:
        return 0.0
    r = d / v
    return 1.0 - (2.0 / np.pi) * (np.arcsin(r) + r * np.sqrt(1.0 - r * r))


def deadband_limit_cycle(
    *,
    kp: float,
    kpi: float,
    kv: float,
    kvi: float,
    inertia_kg_m2: float,
    ratio: float,
    viscous_input: float,
    coulomb_input: float,
    deadband_rad_s: float,
) -> DeadbandCycle | None:
    """Harmonic balance of the normalized JPL loop with a velocity-sensor dead band and friction.

    The velocity terms see ``N(V)·ω`` (dead zone DF at speed amplitude ``V``); the joint friction
    acts as damping ``c = b·N²/J + 4·N·T_c/(π·V·J)`` (viscous + Coulomb first harmonic, input-shaft
    parameters referred to the joint). The loop ``s³ + (Kv·N + c)s² + (Kp + KvI·N)s + Kpi`` has a
    sustained oscillation where ``(Kv·N + c)(Kp + KvI·N) = Kpi``, at ``ω² = Kp + KvI·N``; the
    position amplitude is ``V/ω``. Sampling, quantization and stiction are ignored. Returns
    ``None`` when friction alone keeps the blind loop stable (no crossing).
    """
    d = deadband_rad_s
    j = inertia_kg_m2

    def balance(v: float) -> float:
        n = deadzone_df(v, d)
        c = kv * n + viscous_input * ratio**2 / j + 4.0 * ratio * coulomb_input / (np.pi * v * j)
        return c * (kp + kvi * n) - kpi

    vs = d * (1.0 + np.geomspace(1e-7, 10.0, 4000))
    vals = np.array([balance(v) for v in vs])
    idx = np.flatnonzero((vals[:-1] < 0.0) & (vals[1:] >= 0.0))
    if len(idx) == 0:
        return None
    from scipy.optimize import brentq  # scipy is an extra (tune): imported only where it is needed

    v = float(brentq(balance, vs[idx[0]], vs[idx[0] + 1]))
    n = deadzone_df(v, d)
    w = float(np.sqrt(kp + kvi * n))
    return DeadbandCycle(amplitude_rad=v / w, frequency_hz=w / (2.0 * np.pi), speed_amplitude_rad_s=v, deadzone_gain=n)
