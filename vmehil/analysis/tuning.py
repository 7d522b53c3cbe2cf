"""The analyses behind ``vmehil tune``: plain functions from a joint's parameters to JSON-ready
dicts, so sweeps and the simulated side can reuse them.

The simulated side: :func:`limit_cycle_analysis` takes an optional callable
``simulate(joint_params, switch_off: bool) -> dict`` — normally
:func:`vmehil.analysis.simulate.simulate` (the full driver stack) — returning at least
``amplitude_deg``, ``frequency_hz`` (None when no cycle) and ``static_error_deg``; optional
``t_s`` and ``theta_deg`` lists are plotted in the report.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from vmehil.analysis.describing import (
    Cycle,
    headline,
    measure_cycle,
    predict_cycles,
    predict_joint_velocity,
    simulate_joint,
)
from vmehil.analysis.loop_model import LoopConfig
from vmehil.analysis.margins import compute_margins, equivalent_s_poles
from vmehil.analysis.rigparams import JointParams, with_gains  # noqa: F401  (re-exported)

Simulate = Callable[..., dict[str, Any]]


def margins_summary(cfg: LoopConfig) -> dict[str, Any]:
    """``{"continuous": {...}, "sampled": {...}}`` margins for one gain set (for sweeps)."""
    mc = compute_margins(cfg, sampled=False)
    ms = compute_margins(cfg, sampled=True)
    sd = ms.as_dict()
    sd["poles_s_equivalent"] = [{"re": p.real, "im": p.imag} for p in equivalent_s_poles(ms.poles, cfg.sample_period_s)]
    return {"continuous": mc.as_dict(), "sampled": sd}


def bode_analysis(jp: JointParams) -> dict[str, Any]:
    """Margins, crossover and bandwidth of the continuous ideal and the sampled loop, and the
    verdict of :mod:`servo.gain_guard` (``guard``: ``ok``, ``kind``, ``reason``)."""
    out: dict[str, Any] = {"command": "tune bode", **jp.describe()}
    out.update(margins_summary(jp.cfg))
    out["stable"] = bool(out["sampled"]["stable"])
    verdict = jp.verdict()
    out["guard"] = {"ok": verdict.ok, "kind": verdict.kind, "reason": verdict.reason}
    return out


def _cycles(cfg: LoopConfig, jp: JointParams, sampled: bool) -> list[Cycle]:
    cycles: list[Cycle] = []
    for nl in jp.nonlinearities():
        cycles.extend(predict_cycles(cfg, nl, sampled=sampled))
    return cycles


def _velocity_nls(jp: JointParams) -> list:
    return [n for n in jp.nonlinearities() if n.location in ("velocity_sensor", "friction")]


def _prediction(cfg: LoopConfig, jp: JointParams) -> dict[str, Any]:
    """Single-nonlinearity DF cycles, the combined joint-velocity cycles (tach dead band and
    friction together), and the headline: the largest stable cycle of the combined analysis and
    of the nonlinearities it does not cover (quantization, saturation)."""
    single = _cycles(cfg, jp, True)
    single_c = _cycles(cfg, jp, False)
    vel = _velocity_nls(jp)
    combined = predict_joint_velocity(cfg, vel, sampled=True) if vel else []
    combined_c = predict_joint_velocity(cfg, vel, sampled=False) if vel else []
    covered = {n.location for n in vel}
    h = headline(combined + [c for c in single if c.location not in covered])
    return {
        "amplitude_deg": None if h is None else h.amplitude_deg,
        "frequency_hz": None if h is None else h.frequency_hz,
        "nonlinearity": None if h is None else h.nonlinearity,
        "stable": None if h is None else h.stable,
        "combined_cycles": [c.as_dict() for c in combined],
        "combined_continuous_cycles": [c.as_dict() for c in combined_c],
        "cycles": [c.as_dict() for c in single],
        "continuous_cycles": [c.as_dict() for c in single_c],
    }


def model_check(cfg: LoopConfig, jp: JointParams, seconds: float = 30.0) -> dict[str, Any] | None:
    """Simulate the reduced nonlinear joint (sampled servo law, 1/s², tach dead band, Coulomb and
    viscous friction with stiction) as a check on the describing function. Starts with a 1 rad/s kick."""
    dz = jp.tach_deadband_rad_s or 0.0
    fr = jp.coulomb_nm / jp.inertia_kg_m2
    if not dz and not fr:
        return None
    sim = simulate_joint(cfg, seconds, deadband_rad_s=dz, coulomb_accel=fr, kick=1.0)
    amp, freq = measure_cycle(sim["t"], sim["theta"])
    cyc = amp is not None and freq is not None
    tail = sim["theta"][len(sim["theta"]) // 2:]
    return {
        "model": "sampled servo law + 1/s² + tach dead band + Coulomb/viscous friction with stiction",
        "amplitude_deg": math.degrees(amp) if cyc and amp is not None else None,
        "frequency_hz": freq if cyc else None,
        "final_error_deg": None if cyc else float(math.degrees(abs(tail[-1]))),
        "t_s": sim["t"].tolist(), "theta_deg": np.degrees(sim["theta"]).tolist(),
    }


def limit_cycle_analysis(jp: JointParams, simulate: Simulate | None = None, with_traces: bool = True,
                         model_checks: bool = True) -> dict[str, Any]:
    """Predicted (describing function) and, when ``simulate`` is given, simulated limit cycles,
    with and without integrator switch-off. ``simulate(jp, switch_off=bool)`` returns a dict (see
    the module docstring). The same as :func:`limit_cycle_prediction` then
    :func:`add_simulations` (``tune limit-cycle`` computes the prediction while its runs go on)."""
    out = limit_cycle_prediction(jp, with_traces=with_traces, model_checks=model_checks)
    if simulate is not None:
        add_simulations(out, jp, simulate)
    return out


def limit_cycle_prediction(jp: JointParams, with_traces: bool = True, model_checks: bool = True) -> dict[str, Any]:
    """The predicted side of :func:`limit_cycle_analysis` (``simulated`` keys None)."""
    off = jp.switch_off_cfg()
    out: dict[str, Any] = {"command": "tune limit-cycle", **jp.describe(),
                           "nonlinearities": [n.describe() for n in jp.nonlinearities()]}
    out["predicted"] = _prediction(jp.cfg, jp)
    pred_off = _prediction(off, jp)
    pred_off["static_error_bound_deg"] = math.degrees(jp.static_error_bound_rad())
    out["switch_off"] = {"gains": off.gains.as_dict(), "predicted": pred_off, "simulated": None,
                         "static_error_deg": None}
    out["simulated"] = None
    mc = model_check(jp.cfg, jp) if model_checks else None
    mc_off = model_check(off, jp) if model_checks else None
    if not with_traces:
        for m in (mc, mc_off):
            if m:
                m.pop("t_s")
                m.pop("theta_deg")
    out["model_check"] = mc
    out["switch_off"]["model_check"] = mc_off
    return out


def add_simulations(out: dict[str, Any], jp: JointParams, simulate: Simulate) -> dict[str, Any]:
    """Fill a :func:`limit_cycle_prediction` with the simulated runs (integrators on, then
    switched off) and the simulated/predicted comparison; returns ``out``."""
    out["simulated"] = simulate(jp, switch_off=False)
    sim_off = simulate(jp, switch_off=True)
    out["switch_off"]["simulated"] = sim_off
    out["switch_off"]["static_error_deg"] = sim_off.get("static_error_deg")
    out["comparison"] = compare(out["predicted"], out["simulated"])
    return out


def compare(predicted: dict[str, Any], simulated: dict[str, Any] | None) -> dict[str, Any]:
    """Simulated / predicted ratios of the limit cycle's amplitude and frequency (None where either
    side has no cycle)."""
    def ratio(key: str) -> float | None:
        a = (simulated or {}).get(key)
        b = predicted.get(key)
        return a / b if a is not None and b else None

    return {"amplitude_ratio": ratio("amplitude_deg"), "frequency_ratio": ratio("frequency_hz")}
