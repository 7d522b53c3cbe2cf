"""Linear models of the normalized JPL joint servo loop, continuous and sampled.

The loop (docs/control.md), per joint, in normalized units (plant 1/s²: the input is an
acceleration in rad/s², i.e. torque/J)::

    e_k  = θd_k − θ_k            ė_k = ωd_k − ω_k                      (rad, rad/s)
    Ie_k = Ie_{k−1} + T·e_k       Iv_k = Iv_{k−1} + T·ė_k               (backward Euler)
    a_k  = Kp·e_k + Kpi·Ie_k + Kv·ė_k + KvI·Iv_k                        (rad/s²)

``a_k`` is applied to the plant through a zero-order hold after a computation delay d·T
(0 ≤ d ≤ 1): the plant sees a_{k−1} on [kT, kT+dT) and a_k on [kT+dT, (k+1)T). The
sampled plant is built exactly (matrix exponentials of the continuous plant, with the held
previous command as an extra state), so no Padé or Tustin approximation is involved.

Velocity path: ``"tach"`` samples the continuous (optionally filtered) joint velocity at t_k;
``"encoder"`` uses the backward difference (θ_k − θ_{k−1})/T of the sampled position.
Optional analog dynamics: a first-order amplifier current-loop lag (bandwidth Hz, between the
command and the applied acceleration), first-order position-sensor and tach filters.

Block signal names (used by :func:`build_loop`):

* plant ``P``: inputs ``u`` (commanded acceleration), ``w`` (disturbance acceleration, torque/J);
  outputs ``ths``, ``ws`` (sensor outputs: position, velocity), ``th``, ``om`` (true angle, rate).
* controller ``K``: inputs ``r`` (θd), ``rv`` (ωd), ``thin``, ``win`` (measured position and
  velocity as the controller sees them); output ``a``.

A disturbance torque enters the sampled model through a zero-order hold without the
computation delay (it is held over each period); that is exact for piecewise-constant
disturbances and accurate below a few Hz for smooth ones.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace
from typing import Literal

import control as ct
import numpy as np
from scipy.linalg import expm

from servo.control.gains import Gains
from servo.control.velocity_filter import VelocityFilter
from vmehil.errors import VmehilError

VelocitySource = Literal["tach", "encoder"]

#: Places where a nonlinearity can sit, i.e. where :func:`build_loop` can break the loop.
#: ``actuator``: between the controller output a_k and the plant command (saturation).
#: ``position_sensor``: between the sampled position and the controller (quantization).
#: ``velocity_sensor``: between the sampled velocity and the controller (tach dead band).
#: ``friction``: a torque acting on the joint driven by its true velocity (Coulomb friction).
BREAK_POINTS = ("actuator", "position_sensor", "velocity_sensor", "friction")


class LoopConfigError(VmehilError, ValueError):
    """A loop model parameter is out of range."""


def _check_bandwidth(name: str, v: float | None) -> None:
    if v is not None and not (math.isfinite(v) and v > 0):
        raise LoopConfigError(f"{name}={v} must be a positive number of Hz (or omitted for none)")


@dataclass(frozen=True)
class LoopConfig:
    """Everything the linear model needs.

    sample_period_s: T (s); delay_fraction: computation delay as a fraction d of T (0..1);
    velocity_source: ``"tach"`` or ``"encoder"``; amplifier_bandwidth_hz: current-loop
    bandwidth (first-order lag) or None; position_filter_hz / velocity_filter_hz: first-order
    analog sensor filters or None; viscous_damping: extra plant damping c (1/s, ω' = u − c·ω),
    used by the describing-function stability test for friction.
    """

    gains: Gains[float] = field(default_factory=Gains.paper)  #: one joint's set (servo.control.gains)
    sample_period_s: float = 0.008
    delay_fraction: float = 0.5
    velocity_source: VelocitySource = "tach"
    amplifier_bandwidth_hz: float | None = None
    position_filter_hz: float | None = None
    velocity_filter_hz: float | None = None
    viscous_damping: float = 0.0
    #: the velocity filter alternative to KvI (servo.control.velocity_filter): the KvI channel low-pass
    #: filters the position error at this corner instead of integrating ė; None: ∫ė (the paper's law)
    kvi_filter_hz: float | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sample_period_s) and self.sample_period_s > 0):
            raise LoopConfigError(f"sample period {self.sample_period_s} s must be > 0")
        if not (0.0 <= self.delay_fraction <= 1.0):
            raise LoopConfigError(
                f"computation delay {self.delay_fraction * self.sample_period_s:g} s is outside 0..T "
                f"(T = {self.sample_period_s:g} s); the model covers a delay of 0 to 1 sample"
            )
        if self.velocity_source not in ("tach", "encoder"):
            raise LoopConfigError(f"velocity source {self.velocity_source!r} must be 'tach' or 'encoder'")
        _check_bandwidth("amplifier_bandwidth_hz", self.amplifier_bandwidth_hz)
        _check_bandwidth("position_filter_hz", self.position_filter_hz)
        _check_bandwidth("velocity_filter_hz", self.velocity_filter_hz)
        _check_bandwidth("kvi_filter_hz", self.kvi_filter_hz)
        if not (math.isfinite(self.viscous_damping) and self.viscous_damping >= 0):
            raise LoopConfigError(f"viscous_damping={self.viscous_damping} must be ≥ 0")

    @property
    def nyquist_hz(self) -> float:
        return 0.5 / self.sample_period_s

    @property
    def delay_s(self) -> float:
        return self.delay_fraction * self.sample_period_s

    def replace(self, **kw) -> LoopConfig:
        return replace(self, **kw)


# --------------------------------------------------------------------------- plant


def _plant_matrices(cfg: LoopConfig, ideal_velocity: bool) -> tuple[np.ndarray, ...]:
    """Continuous plant (A, B, C) with inputs [u, w] and outputs [ths, ws, th, om].

    With ``ideal_velocity`` and an encoder velocity path, ``ws`` is the exact derivative of the
    position sensor output (the continuous ideal of a backward difference).
    """
    names = ["th", "om"]
    if cfg.amplifier_bandwidth_hz:
        names.append("acc")
    if cfg.position_filter_hz:
        names.append("thf")
    if cfg.velocity_filter_hz:
        names.append("omf")
    n = len(names)
    ix = {k: i for i, k in enumerate(names)}
    A = np.zeros((n, n))
    B = np.zeros((n, 2))
    A[ix["th"], ix["om"]] = 1.0
    A[ix["om"], ix["om"]] = -cfg.viscous_damping
    B[ix["om"], 1] = 1.0
    if cfg.amplifier_bandwidth_hz:
        wa = 2 * math.pi * cfg.amplifier_bandwidth_hz
        A[ix["om"], ix["acc"]] = 1.0
        A[ix["acc"], ix["acc"]] = -wa
        B[ix["acc"], 0] = wa
    else:
        B[ix["om"], 0] = 1.0
    if cfg.position_filter_hz:
        wp = 2 * math.pi * cfg.position_filter_hz
        A[ix["thf"], ix["th"]] = wp
        A[ix["thf"], ix["thf"]] = -wp
    if cfg.velocity_filter_hz:
        wv = 2 * math.pi * cfg.velocity_filter_hz
        A[ix["omf"], ix["om"]] = wv
        A[ix["omf"], ix["omf"]] = -wv
    C = np.zeros((4, n))
    C[0, ix["thf" if cfg.position_filter_hz else "th"]] = 1.0
    C[1, ix["omf" if cfg.velocity_filter_hz else "om"]] = 1.0
    C[2, ix["th"]] = 1.0
    C[3, ix["om"]] = 1.0
    if ideal_velocity and cfg.velocity_source == "encoder":
        C[1] = C[0] @ A  # d/dt of the position sensor output (its row has no direct input term)
    return A, B, C


_PLANT_IO = {"inputs": ["u", "w"], "outputs": ["ths", "ws", "th", "om"]}


def continuous_plant(cfg: LoopConfig) -> ct.StateSpace:
    """The continuous plant (1/s² plus the configured analog lags); see the module docstring."""
    A, B, C = _plant_matrices(cfg, ideal_velocity=True)
    return ct.ss(A, B, C, np.zeros((4, 2)), name="P", **_PLANT_IO)


def _zoh_integral(A: np.ndarray, B: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{At}, ∫₀ᵗ e^{As} ds · B) by one block matrix exponential."""
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A
    M[:n, n:] = B
    E = expm(M * t)
    return E[:n, :n], E[:n, n:]


def sampled_plant(cfg: LoopConfig) -> ct.StateSpace:
    """The exact sampled plant with the fractional computation delay (dt = T).

    State [x; a_{k−1}] (the held previous command is dropped when d = 0); inputs [u_k, w_k];
    outputs [ths, ws, th, om] sampled at t_k, before u_k acts (no direct feedthrough)::

        x_{k+1} = Φ x_k + Γ0 u_k + Γ1 u_{k−1} + Γw w_k
        Φ = e^{AT}, Γ0 = ∫₀^{T−dT} e^{As}ds B_u, Γ1 = e^{A(T−dT)} ∫₀^{dT} e^{As}ds B_u,
        Γw = ∫₀^T e^{As}ds B_w
    """
    Ad, Bd, Cd = _sampled_plant_arrays(cfg.replace(gains=Gains.paper(), velocity_source="tach"))
    return ct.ss(Ad, Bd, Cd, np.zeros((4, 2)), cfg.sample_period_s, name="P", **_PLANT_IO)


@functools.lru_cache(maxsize=256)
def _sampled_plant_arrays(cfg: LoopConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    A, B, C = _plant_matrices(cfg, ideal_velocity=False)
    T, d = cfg.sample_period_s, cfg.delay_fraction
    n = A.shape[0]
    Phi, Gam = _zoh_integral(A, B, T)
    Gw = Gam[:, 1:2]
    _, G0 = _zoh_integral(A, B[:, :1], T - d * T)
    Phi_rest = expm(A * (T - d * T))
    _, Gd = _zoh_integral(A, B[:, :1], d * T)
    G1 = Phi_rest @ Gd
    if d > 0:
        Ad = np.block([[Phi, G1], [np.zeros((1, n)), np.zeros((1, 1))]])
        Bd = np.block([[G0, Gw], [np.ones((1, 1)), np.zeros((1, 1))]])
        Cd = np.hstack([C, np.zeros((4, 1))])
    else:
        Ad, Bd, Cd = Phi, np.hstack([G0, Gw]), C
    for arr in (Ad, Bd, Cd):
        arr.setflags(write=False)
    return Ad, Bd, Cd


# ----------------------------------------------------------------------- controller


def _controller_matrices(gains: Gains[float], T: float | None, velocity_source: str,
                         kvi_filter_hz: float | None = None) -> tuple[np.ndarray, ...]:
    """Controller (A, B, C, D); inputs [r, rv, thin, win], output a. T=None: continuous.

    Integrator states exist only for non-zero integral gains (no hidden uncontrollable poles).
    ``kvi_filter_hz``: the KvI channel is the velocity filter (:class:`servo.control.velocity_filter.
    VelocityFilter`, the servo's own definition: pole 1 − α, gain α; continuous ωc/(s + ωc)).
    """
    filt = VelocityFilter(kvi_filter_hz) if kvi_filter_hz else None
    encoder = T is not None and velocity_source == "encoder"
    # error rows over the inputs q = [r, rv, thin, win] (and, for the encoder, the state thprev)
    e_q = np.array([1.0, 0.0, -1.0, 0.0])
    ed_q = np.array([0.0, 1.0, 0.0, -1.0])
    if encoder and T is not None:  # encoder implies T is not None
        ed_q = np.array([0.0, 1.0, -1.0 / T, 0.0])  # + thprev/T, added below
    states: list[str] = []
    if gains.kpi:
        states.append("ie")
    if gains.kvi:
        states.append("iv" if filt is None else "ef")
    if encoder:
        states.append("thprev")
    n = len(states)
    ix = {k: i for i, k in enumerate(states)}
    ed_s = np.zeros(n)
    if encoder and T is not None:
        ed_s[ix["thprev"]] = 1.0 / T
    A = np.zeros((n, n))
    B = np.zeros((n, 4))
    C = np.zeros((1, n))
    D = (gains.kp * e_q + gains.kv * ed_q)[None, :]
    C[0] += gains.kv * ed_s
    for name, gain, rq, rs in (("ie", gains.kpi, e_q, np.zeros(n)), ("iv", gains.kvi, ed_q, ed_s)):
        if name not in ix:
            continue
        i = ix[name]
        if T is None:  # continuous integrator: I' = err
            B[i] += rq
            A[i] += rs
            C[0, i] += gain
        else:  # backward Euler: I_k = s_k + T·err_k with s_{k+1} = I_k, so a uses s_k + T·err_k
            A[i, i] += 1.0
            A[i] += T * rs
            B[i] += T * rq
            C[0, i] += gain
            C[0] += gain * T * rs
            D[0] += gain * T * rq
    if filt is not None and "ef" in ix:
        i = ix["ef"]
        if T is None:  # ef' = −ωc·ef + ωc·e
            a, b = filt.continuous()
            A[i, i] += a
            B[i] += b * e_q
            C[0, i] += gains.kvi
        else:  # ef_k = pole·s_k + α·e_k with s_{k+1} = ef_k, and a uses KvI·ef_k
            pole, alpha = filt.discrete(T)
            A[i, i] += pole
            B[i] += alpha * e_q
            C[0, i] += gains.kvi * pole
            D[0] += gains.kvi * alpha * e_q
    if encoder:
        B[ix["thprev"], 2] = 1.0
    return A, B, C, D


_CTRL_IO = {"inputs": ["r", "rv", "thin", "win"], "outputs": ["a"]}


def sampled_controller(gains: Gains[float], sample_period_s: float,
                       velocity_source: VelocitySource = "tach", kvi_filter_hz: float | None = None) -> ct.StateSpace:
    """The discrete servo law (dt = T) with inputs [r, rv, thin, win] and output a (rad/s²)."""
    A, B, C, D = _controller_matrices(gains, sample_period_s, velocity_source, kvi_filter_hz)
    return ct.ss(A, B, C, D, sample_period_s, name="K", **_CTRL_IO)


def continuous_controller(gains: Gains[float], kvi_filter_hz: float | None = None) -> ct.StateSpace:
    """The continuous ideal of the servo law: Kp·e + Kpi·∫e + Kv·ė + KvI·∫ė (or KvI·ωc/(s + ωc)·e)."""
    A, B, C, D = _controller_matrices(gains, None, "tach", kvi_filter_hz)
    return ct.ss(A, B, C, D, name="K", **_CTRL_IO)


# ------------------------------------------------------------------------- the loop


@functools.lru_cache(maxsize=256)
def build_loop(cfg: LoopConfig, sampled: bool, break_at: str | None = None) -> ct.StateSpace:
    """Close the loop with python-control's ``interconnect``.

    Cached per (frozen) configuration: the margins, poles and responses of one gain set all start
    from the same few loops (``interconnect`` is most of a sweep point's analysis time); callers
    derive new systems from the result (indexing, arithmetic) and never change it.

    Without ``break_at``: inputs [r, rv, d] (θd rad, ωd rad/s, disturbance acceleration rad/s²),
    outputs [th, om, a].

    With ``break_at`` (one of :data:`BREAK_POINTS`) the loop is opened where a nonlinearity sits:
    an extra input ``v`` (the nonlinearity's output) replaces the signal there and an extra output
    ``x`` is the signal feeding the nonlinearity. The linear part seen by the nonlinearity is then
    G = −x/v, so that the loop reads x = −G·N(x). For ``friction`` v is the friction acceleration
    (it acts as −v on the joint) and x is the true joint velocity.
    """
    if break_at is not None and break_at not in BREAK_POINTS:
        raise LoopConfigError(f"unknown break point {break_at!r}; one of {', '.join(BREAK_POINTS)}")
    if break_at == "friction" and sampled:
        raise LoopConfigError("friction acts in continuous time; use describing.hybrid_response for the sampled loop")
    if break_at == "velocity_sensor" and cfg.velocity_source == "encoder":
        raise LoopConfigError("a velocity-sensor nonlinearity needs velocity_source='tach' (the encoder path "
                              "derives velocity from the position; break at position_sensor instead)")
    if sampled:
        Ap, Bp, Cp = _sampled_plant_arrays(cfg.replace(gains=Gains.paper(), velocity_source="tach"))
        Ak, Bk, Ck, Dk = _controller_matrices(cfg.gains, cfg.sample_period_s, cfg.velocity_source, cfg.kvi_filter_hz)
        dt: float = cfg.sample_period_s
    else:
        Ap, Bp, Cp = _plant_matrices(cfg, ideal_velocity=True)
        Ak, Bk, Ck, Dk = _controller_matrices(cfg.gains, None, "tach", cfg.kvi_filter_hz)
        dt = 0.0
    # where each block's inputs come from (signal names)
    p_in = {"u": "a", "w": "d"}
    k_in = {"thin": "ths", "win": "ws"}
    x_sig = None
    if break_at == "actuator":
        p_in["u"], x_sig = "v", "a"
    elif break_at == "position_sensor":
        k_in["thin"], x_sig = "v", "ths"
    elif break_at == "velocity_sensor":
        k_in["win"], x_sig = "v", "ws"
    elif break_at == "friction":
        p_in["w"], x_sig = "wf", "om"  # wf = d − v
    inputs = ["r", "rv", "d"] + (["v"] if break_at else [])
    outputs = ["th", "om", "a"] + ([x_sig] if x_sig else [])
    return _closed(Ap, Bp, Cp, Ak, Bk, Ck, Dk, dt, p_in, k_in, inputs, outputs,
                   output_names=outputs[:3] + (["x"] if x_sig else []))


def _closed(Ap: np.ndarray, Bp: np.ndarray, Cp: np.ndarray, Ak: np.ndarray, Bk: np.ndarray, Ck: np.ndarray,
            Dk: np.ndarray, dt: float, p_in: dict[str, str], k_in: dict[str, str], inputs: list[str],
            outputs: list[str], output_names: list[str]) -> ct.StateSpace:
    """The loop's state space, states [plant; controller], assembled directly.

    The wiring of :func:`build_loop`: plant inputs [u, w], outputs [ths, ws, th, om] (no direct
    feedthrough, D = 0: the loop has no algebraic cycle); controller inputs [r, rv, thin, win],
    output a; ``wf`` = d − v. Each signal is a row over the states and a row over the loop's
    inputs, so the closed loop is a few outer products — what ``ct.interconnect`` computes for
    these blocks, without its general machinery (≈100× faster; the describing-function search
    builds hundreds of loops).
    """
    n_p, n_k, m = Ap.shape[0], Ak.shape[0], len(inputs)
    n = n_p + n_k
    sig: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for i, name in enumerate(("ths", "ws", "th", "om")):
        sig[name] = (np.concatenate([Cp[i], np.zeros(n_k)]), np.zeros(m))
    for i, name in enumerate(inputs):
        u = np.zeros(m)
        u[i] = 1.0
        sig[name] = (np.zeros(n), u)
    if "v" in sig:
        sig["wf"] = (sig["d"][0] - sig["v"][0], sig["d"][1] - sig["v"][1])
    k_sources = [sig["r"], sig["rv"], sig[k_in["thin"]], sig[k_in["win"]]]
    a_x = np.concatenate([np.zeros(n_p), Ck[0]])
    a_u = np.zeros(m)
    for j, (sx, su) in enumerate(k_sources):
        a_x = a_x + Dk[0, j] * sx
        a_u = a_u + Dk[0, j] * su
    sig["a"] = (a_x, a_u)
    A = np.zeros((n, n))
    B = np.zeros((n, m))
    A[:n_p, :n_p] = Ap
    A[n_p:, n_p:] = Ak
    for col, name in enumerate(("u", "w")):
        sx, su = sig[p_in[name]]
        A[:n_p] += np.outer(Bp[:, col], sx)
        B[:n_p] += np.outer(Bp[:, col], su)
    for col, (sx, su) in enumerate(k_sources):
        A[n_p:] += np.outer(Bk[:, col], sx)
        B[n_p:] += np.outer(Bk[:, col], su)
    C = np.array([sig[o][0] for o in outputs]).reshape(len(outputs), n)
    D = np.array([sig[o][1] for o in outputs]).reshape(len(outputs), m)
    return ct.ss(A, B, C, D, dt, inputs=inputs, outputs=output_names, name="loop")


def open_loop(cfg: LoopConfig, sampled: bool) -> ct.StateSpace:
    """The loop transfer broken at the plant input, L = −a/u (SISO): closed loop is stable iff
    1 + L has no unstable zeros; margins are read from L."""
    br = build_loop(cfg, sampled, "actuator")
    return -br[br.output_labels.index("x"), br.input_labels.index("v")]


def closed_loop(cfg: LoopConfig, sampled: bool) -> ct.StateSpace:
    """Command θd → joint angle θ (with ωd = 0; the trajectory generator's ωd adds feedforward)."""
    cl = build_loop(cfg, sampled)
    return cl[0, 0]


def tracking_loop(cfg: LoopConfig, sampled: bool) -> ct.StateSpace:
    """Command θd → θ with a consistent velocity reference ωd = dθd/dt (backward difference when
    sampled): the response of a smooth trajectory, whose error dynamics are s³/(closed-loop poly)."""
    cl = build_loop(cfg, sampled)
    if sampled:
        T = cfg.sample_period_s
        diff = ct.ss([[0.0]], [[1.0]], [[-1.0 / T]], [[1.0 / T]], T)  # (1 − z⁻¹)/T
        return ct.ss(cl[0, 0] + cl[0, 1] * diff)
    # ωd = s·θd: θ = (H_r + H_rv·s)·θd; H_rv is strictly proper so the sum is proper
    s = ct.tf("s")
    return ct.ss(ct.minreal(ct.tf(cl[0, 0]) + ct.tf(cl[0, 1]) * s, verbose=False))


def disturbance_loop(cfg: LoopConfig, sampled: bool) -> ct.StateSpace:
    """Disturbance acceleration (torque/J, rad/s²) → θ (rad). Multiply by 1/J for rad per N·m."""
    cl = build_loop(cfg, sampled)
    return cl[0, 2]


def closed_loop_poles(cfg: LoopConfig, sampled: bool) -> np.ndarray:
    """Poles of the closed loop as seen from θd and the disturbance (z-plane when sampled, s-plane
    otherwise).

    With KvI > 0 the loop has one exact marginal mode, Iv + θ (the velocity integral plus the
    angle), which only ωd drives: it is a constant of motion, uncontrollable from θd and from the
    disturbance, so it is dropped here by the PBH rank test rather than reported as instability.
    """
    cl = build_loop(cfg, sampled)
    return controllable_poles(cl.A, cl.B[:, [0, 2]])


def controllable_poles(A: np.ndarray, B: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """Eigenvalues of A whose modes are controllable from B (PBH test: rank [A − λI, B] = n)."""
    lam = np.linalg.eigvals(A)
    n = A.shape[0]
    scale = max(float(np.linalg.norm(A)), float(np.linalg.norm(B)), 1.0)
    keep = []
    for v in lam:
        M = np.hstack([A - v * np.eye(n), B])
        smin = np.linalg.svd(M, compute_uv=False)[-1]
        keep.append(smin > rtol * scale)
    return lam[np.array(keep, dtype=bool)] if n else lam


def poles_stable(poles: np.ndarray, sampled: bool, margin: float = 1e-9) -> bool:
    """All poles strictly inside the unit circle (sampled) or the open left half-plane."""
    p = np.asarray(poles)
    if p.size == 0:
        return True
    return bool(np.all(np.abs(p) < 1.0 - margin)) if sampled else bool(np.all(p.real < -margin))


def is_stable(cfg: LoopConfig, sampled: bool) -> bool:
    """Whether the closed loop (θd, disturbance → θ) is asymptotically stable."""
    return poles_stable(closed_loop_poles(cfg, sampled), sampled)


def freqresp(sys: ct.StateSpace, f_hz: np.ndarray) -> np.ndarray:
    """Complex frequency response of a SISO system at ``f_hz`` (Hz).

    Sampled systems are evaluated on the unit circle, H(e^{j2πfT}) — done here explicitly, not by
    a library routine that might treat the frequency axis as continuous.
    """
    w = 2 * np.pi * np.asarray(f_hz, dtype=float)
    x = np.exp(1j * w * sys.dt) if sys.isdtime(strict=True) else 1j * w
    return _eval_ss(sys.A, sys.B, sys.C, sys.D, x)[0, 0]


def _eval_ss(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, x: np.ndarray) -> np.ndarray:
    """C (xI − A)⁻¹ B + D at each complex x; returns shape (ny, nu, len(x))."""
    x = np.atleast_1d(np.asarray(x, dtype=complex))
    n = A.shape[0]
    if n == 0:
        return np.repeat(np.asarray(D, dtype=complex)[:, :, None], x.size, axis=2)
    M = x[:, None, None] * np.eye(n)[None] - A[None]
    with np.errstate(all="ignore"):
        X = np.linalg.solve(M, np.broadcast_to(B, (x.size, *B.shape)))
    H = np.einsum("ij,kjl->ilk", C, X) + np.asarray(D)[:, :, None]
    return H
