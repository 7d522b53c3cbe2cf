"""Reports for ``vmehil tune``: plots and markdown summaries.

Files are written with :mod:`vmehil.writers.files` (atomic: a reader never sees a half-written report).
Plots use matplotlib's Agg backend.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib import patheffects
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from vmehil.analysis.describing import Nonlinearity, linear_response_fn
from vmehil.analysis.loop_model import (
    LoopConfig,
    closed_loop,
    disturbance_loop,
    freqresp,
    open_loop,
    tracking_loop,
)
from vmehil.analysis.margins import frequency_grid
from vmehil.writers.files import save_figure

# ----------------------------------------------------------------------- figure files


def save_figure_both(fig: Figure, directory: Path, stem: str) -> list[Path]:
    """``<stem>.png`` and ``<stem>.svg`` in ``directory`` (atomic writes), then close the figure."""
    paths = save_figure(fig, directory / stem, ("png", "svg"), dpi=120)
    plt.close(fig)
    return paths


# ----------------------------------------------------------------------------- plots

_C = {"continuous": "tab:blue", "sampled": "tab:red"}


def _db(h: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 20 * np.log10(np.abs(h))


def _phase_deg(h: np.ndarray) -> np.ndarray:
    """Unwrapped phase (deg), shifted by whole turns so the high-frequency end is near −90…−270."""
    p = np.degrees(np.unwrap(np.angle(h)))
    return p


def bode_figure(cfg: LoopConfig, result: dict[str, Any]) -> Figure:
    """Open-loop Bode, sampled (to Nyquist) against continuous, with the margins marked."""
    fc = frequency_grid(200.0, 0.05, 1500)
    fs = frequency_grid(cfg.nyquist_hz * (1 - 1e-6), 0.05, 1500)
    Lc, Ls = freqresp(open_loop(cfg, False), fc), freqresp(open_loop(cfg, True), fs)
    pc, ps = _phase_deg(Lc), _phase_deg(Ls)
    # align the two unwrapped phases at low frequency (both start near −270°)
    pc -= 360 * np.round((pc[0] + 270) / 360)
    ps -= 360 * np.round((ps[0] + 270) / 360)
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(8, 7))
    ax1.semilogx(fc, _db(Lc), color=_C["continuous"], label="continuous ideal")
    ax1.semilogx(fs, _db(Ls), color=_C["sampled"], label=f"sampled {1 / cfg.sample_period_s:g} Hz, "
                 f"delay {cfg.delay_s * 1e3:g} ms")
    ax1.axhline(0, color="k", lw=0.6)
    ax2.semilogx(fc, pc, color=_C["continuous"])
    ax2.semilogx(fs, ps, color=_C["sampled"])
    ax2.axhline(-180, color="k", lw=0.6)
    # the two PM arrows usually stand close together: the lower crossover's label goes to the left
    # of its arrow, the other's to the right, each on a white ground, so no label sits on an arrow
    crossovers = [result[k]["crossover_hz"] for k in ("continuous", "sampled") if result[k].get("crossover_hz")]
    for kind, f, p in (("continuous", fc, pc), ("sampled", fs, ps)):
        m = result[kind]
        col = _C[kind]
        if m.get("crossover_hz"):
            x = m["crossover_hz"]
            ax1.axvline(x, color=col, ls=":", lw=0.8)
            ax2.axvline(x, color=col, ls=":", lw=0.8)
            ph = float(np.interp(math.log(x), np.log(f), p))
            ax2.annotate("", xy=(x, -180), xytext=(x, ph), arrowprops={"arrowstyle": "<->", "color": col})
            left = len(crossovers) == 2 and x == min(crossovers)
            ax2.text(x / 1.08 if left else x * 1.08, (ph - 180) / 2, f"PM {m['phase_margin_deg']:.1f}°", color=col,
                     fontsize=8, ha="right" if left else "left", va="center",
                     bbox={"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.85})
        if m.get("gain_margin_hz") and m.get("gain_margin_db") is not None:
            x = m["gain_margin_hz"]
            ax1.annotate("", xy=(x, 0), xytext=(x, -m["gain_margin_db"]),
                         arrowprops={"arrowstyle": "<->", "color": col})
            # beside the middle of its arrow: |L| reaches −GM on the curve, so this is inside the axes
            ax1.text(x * 0.93, -m["gain_margin_db"] / 2, f"GM {m['gain_margin_db']:.1f} dB", color=col, fontsize=8,
                     ha="right", va="center")
    ax1.axvline(cfg.nyquist_hz, color="grey", ls="--", lw=0.8)
    ax1.text(cfg.nyquist_hz * 0.97, ax1.get_ylim()[1] - 10, "Nyquist", ha="right", fontsize=8, color="grey")
    ax1.set_ylabel("|L| (dB)")
    ax2.set_ylabel("∠L (deg)")
    ax2.set_xlabel("frequency (Hz)")
    ax1.set_title(f"Open loop at the plant input — {_gain_text(cfg)}")
    ax1.legend(loc="lower left", fontsize=8)
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
    ax2.set_ylim(max(min(ps.min(), pc.min()) - 20, -540), max(ps.max(), pc.max()) + 20)
    return fig


def responses_figure(cfg: LoopConfig, result: dict[str, Any], inertia_kg_m2: float) -> Figure:
    """Closed-loop (θd → θ, and with ωd) and disturbance-torque responses."""
    fc = frequency_grid(200.0, 0.01, 1200)
    fs = frequency_grid(cfg.nyquist_hz * (1 - 1e-6), 0.01, 1200)
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(8, 7))
    for sampled, f in ((False, fc), (True, fs)):
        kind = "sampled" if sampled else "continuous"
        col = _C[kind]
        ax1.semilogx(f, _db(freqresp(closed_loop(cfg, sampled), f)), color=col, label=f"{kind}: θ/θd (ωd = 0)")
        ax1.semilogx(f, _db(freqresp(tracking_loop(cfg, sampled), f)), color=col, ls="--",
                     label=f"{kind}: θ/θd with ωd = dθd/dt")
        comp = np.degrees(np.abs(freqresp(disturbance_loop(cfg, sampled), f))) / inertia_kg_m2
        ax2.loglog(f, comp, color=col, label=kind)
        bw = result[kind].get("bandwidth_hz")
        if bw:
            ax1.axvline(bw, color=col, ls=":", lw=0.8)
            ax1.text(bw * 1.05, -25 if sampled else -20, f"−3 dB {bw:.2f} Hz", color=col, fontsize=8)
    ax1.axhline(-3, color="k", lw=0.5, ls=":")
    ax1.set_ylim(-40, 10)
    ax1.set_ylabel("|θ/θd| (dB)")
    ax1.set_title(f"Closed loop — {_gain_text(cfg)}")
    ax1.legend(fontsize=8, loc="lower left")
    ax2.set_ylabel(f"|θ/τ| (deg per N·m, J = {inertia_kg_m2:g} kg·m²)")
    ax2.set_xlabel("frequency (Hz)")
    ax2.set_title("Disturbance torque → joint angle (zero at DC: integral action)", fontsize=10)
    ax2.legend(fontsize=8)
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
    return fig


def nyquist_df_figure(cfg: LoopConfig, nl: Nonlinearity, cycles: list[dict], title: str = "") -> Figure:
    """G (sampled and continuous) in the complex plane with −1/N(A) and the predicted cycles."""
    fig, ax = plt.subplots(figsize=(7, 6))
    f_top = cfg.nyquist_hz * (1 - 1e-6) if nl.location != "friction" else 0.5 * cfg.nyquist_hz
    pts = []
    dense = [np.linspace(0.3 * c["frequency_hz"], 3.0 * c["frequency_hz"], 3000) for c in cycles
             if c.get("frequency_hz")]
    ref = [abs(c["g_at_crossing"]) for c in cycles] or [1.0]
    span = 2.5 * max([*ref, 1.0])
    # frequency marks where the curves are on the plot: around the predicted cycles (fixed 1, 3,
    # 10 Hz sat in a heap at the origin); a mark closer than 6 % of the span to a labelled one
    # keeps its dot but not its label
    cycle_hz = [c["frequency_hz"] for c in cycles if c.get("frequency_hz")]
    marks = sorted({float(f"{k * fc:.2g}") for fc in cycle_hz for k in (0.5, 1.0, 2.0)}) or [1.0, 3.0, 10.0]
    labelled: list[complex] = []
    for sampled, f in ((False, frequency_grid(100.0, 0.2, 2000)), (True, frequency_grid(f_top, 0.2, 2000))):
        f = np.unique(np.concatenate([f, *[d[d < f[-1]] for d in dense]]))
        g = linear_response_fn(cfg, nl.location, sampled)(f)[0]
        kind = "sampled" if sampled else "continuous"
        ax.plot(g.real, g.imag, color=_C[kind], label=f"G(jω) {kind}" if not sampled else "G(e^{jωT}) sampled")
        pts.append(g)
        for fm in marks:
            if fm < f[-1]:
                gm = complex(linear_response_fn(cfg, nl.location, sampled)(np.array([fm]))[0][0])
                ax.plot(gm.real, gm.imag, ".", color=_C[kind])
                if all(abs(gm - other) > 0.06 * span for other in labelled):
                    labelled.append(gm)
                    ax.annotate(f"{fm:g} Hz", (gm.real, gm.imag), fontsize=7, color=_C[kind],
                                textcoords="offset points", xytext=(4, 4) if sampled else (-30, 4))
    lo, hi = nl.amplitude_range()
    amps = np.logspace(math.log10(max(lo, 1e-12)), math.log10(min(hi, 1e6)), 600)
    n = np.array([nl.df(a) for a in amps])
    ok = n > 1e-9
    inv = -1.0 / n[ok]
    ax.plot(inv, np.zeros_like(inv), color="k", lw=3, alpha=0.35, label="−1/N(A)")
    for c in cycles:
        mk = "o" if c["stable"] else "x"
        ax.plot(c["g_at_crossing"], 0, mk, ms=10, mfc="none" if c["stable"] else None, color="tab:green")
        ax.annotate(f"{c['amplitude_deg']:.2f}° at {c['frequency_hz']:.2f} Hz\n"
                    f"({'stable' if c['stable'] else 'unstable'})",
                    (c["g_at_crossing"], 0), textcoords="offset points", xytext=(8, -30), fontsize=8,
                    color="tab:green")
    allg = np.concatenate(pts)
    ax.set_xlim(-span, span * 0.6)
    yl = np.clip(np.abs(allg.imag), 0, span).max() if allg.size else span
    ax.set_ylim(-min(yl, span), min(yl, span))
    ax.axhline(0, color="k", lw=0.5)
    ax.axvline(0, color="k", lw=0.5)
    ax.set_xlabel("Re")
    ax.set_ylabel("Im")
    ax.set_title(title or f"Describing function: {nl.name} at the {nl.location.replace('_', ' ')}")
    ax.legend(fontsize=8, loc="upper left")
    ax.grid(True, alpha=0.3)
    return fig


def cycle_time_figure(traces: list[tuple[str, dict]], title: str) -> Figure | None:
    """Time plot and spectrum of simulated joint angle(s): ``[(label, {"t_s": ..., "theta_deg": ...})]``."""
    traces = [(lab, d) for lab, d in traces if d and d.get("t_s") and d.get("theta_deg")]
    if not traces:
        return None
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 7))
    for lab, d in traces:
        t, y = np.asarray(d["t_s"]), np.asarray(d["theta_deg"])
        ax1.plot(t, y, lw=0.8, label=lab)
        n0 = len(t) // 2
        seg = y[n0:] - np.mean(y[n0:])
        if seg.size > 8:
            dt = float(t[1] - t[0])
            spec = np.abs(np.fft.rfft(seg * np.hanning(seg.size))) * 2 / (0.5 * seg.size)
            ax2.semilogy(np.fft.rfftfreq(seg.size, dt), np.maximum(spec, 1e-9), lw=0.8, label=lab)
    t_end = max(float(np.asarray(d["t_s"])[-1]) for _, d in traces)
    ax1.set_xlim(max(0.0, t_end - 3.0), t_end)  # the settled cycle; the spectrum uses the second half
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel("joint angle (deg)")
    ax1.set_title(title)
    ax1.legend(fontsize=8)
    ax2.set_xlabel("frequency (Hz)")
    ax2.set_ylabel("amplitude (deg, second half)")
    ax2.set_xlim(0, 20)
    ax2.legend(fontsize=8)
    for ax in (ax1, ax2):
        ax.grid(True, alpha=0.3)
    return fig


def _gain_text(cfg: LoopConfig) -> str:
    return _gains_line(cfg.gains.as_dict())


# -------------------------------------------------------------------------- text


def fmt(v: Any, spec: str = ".2f", unit: str = "", none: str = "∞") -> str:
    if v is None:
        return none
    return f"{v + 0.0:{spec}}{unit}"  # (+ 0.0 turns −0.0 into 0.0)


def bode_text(r: dict[str, Any]) -> str:
    """The readable summary ``vmehil tune bode`` prints (plain text, also used in the markdown)."""
    c, s = r["continuous"], r["sampled"]
    lines = [
        f"rig {r['rig']}, joint {r['joint']} ({r['joint_name']}); gains {_gains_line(r['gains'])} "
        f"[{r['gains_source']}]",
        f"loop: T = {r['sample_period_s'] * 1e3:g} ms ({1 / r['sample_period_s']:g} Hz), computation delay "
        f"{r['computation_delay_s'] * 1e3:g} ms, velocity from {r['velocity_source']}"
        + (f", KvI on the position error low-passed at {r['kvi_filter_hz']:g} Hz (velocity filter)"
           if r.get("kvi_filter_hz") else ""),
        "",
        f"{'':30s}{'continuous':>14s}{'sampled':>14s}",
        _row("closed loop stable", c["stable"], s["stable"], lambda v: "yes" if v else "NO"),
        _row("phase margin (deg)", c["phase_margin_deg"], s["phase_margin_deg"], lambda v: fmt(v, ".1f", none="—")),
        _row("  at crossover (Hz)", c["crossover_hz"], s["crossover_hz"], lambda v: fmt(v, ".2f", none="—")),
        _row("gain margin (dB)", c["gain_margin_db"], s["gain_margin_db"], lambda v: fmt(v, ".1f")),
        _row("  at (Hz)", c["gain_margin_hz"], s["gain_margin_hz"], lambda v: fmt(v, ".2f", none="—")),
        _row("gain-reduction margin (dB)", c["gain_reduction_margin_db"], s["gain_reduction_margin_db"],
             lambda v: fmt(v, ".1f", none="none")),
        _row("  at (Hz)", c["gain_reduction_hz"], s["gain_reduction_hz"], lambda v: fmt(v, ".2f", none="—")),
        _row("delay margin (ms)", _ms(c["delay_margin_s"]), _ms(s["delay_margin_s"]),
             lambda v: fmt(v, ".1f", none="—")),
        _row("bandwidth −3 dB (Hz)", c["bandwidth_hz"], s["bandwidth_hz"], lambda v: fmt(v, ".2f", none="—")),
        _row("sensitivity peak (dB)", c["sensitivity_peak_db"], s["sensitivity_peak_db"],
             lambda v: fmt(v, ".1f", none="—")),
    ]
    if not s["stable"]:
        bad = [p for p in s["poles"] if abs(complex(p["re"], p["im"])) >= 1]
        lines += ["", "UNSTABLE: the sampled closed loop has pole(s) on or outside the unit circle at "
                  + ", ".join(f"{p['re']:.3f}{p['im']:+.3f}j" for p in bad)
                  + "; margins above are not meaningful. Lower the gains or raise Kv."]
    guard = r.get("guard")
    if guard and not guard["ok"]:
        lines += ["", f"servo.gain_guard refuses these gains (the servo would not run them): {guard['reason']}"]
    if r.get("notes"):
        lines += ["", "assumed (not in the rig file):"] + [f"  - {n}" for n in r["notes"]]
    return "\n".join(lines)


def _ms(v: float | None) -> float | None:
    return None if v is None else v * 1e3


def _row(label: str, a: Any, b: Any, f) -> str:
    return f"{label:30s}{f(a):>14s}{f(b):>14s}"


def _gains_line(g: dict) -> str:
    return f"Kp={g['kp']:g} Kpi={g['kpi']:g} Kv={g['kv']:g} KvI={g['kvi']:g}"


def limit_cycle_text(r: dict[str, Any]) -> str:
    """Summary printed by ``vmehil tune limit-cycle``."""
    lines = [
        f"rig {r['rig']}, joint {r['joint']} ({r['joint_name']}); gains {_gains_line(r['gains'])} "
        f"[{r['gains_source']}]; switch-off gains {_gains_line(r['switch_off']['gains'])}",
        "nonlinearities: " + "; ".join(_nl_line(n) for n in r["nonlinearities"]),
        "",
    ]
    for label, block in (("integrators on", r), ("integrators switched off", r["switch_off"])):
        p = block["predicted"]
        head = (f"±{p['amplitude_deg']:.3f}° at {p['frequency_hz']:.2f} Hz ({p['nonlinearity']})"
                if p["amplitude_deg"] is not None else "no stable cycle")
        lines.append(f"{label}: predicted (sampled DF) {head}")
        for c in p["combined_cycles"]:
            lines.append(f"    {c['nonlinearity']:40s} {c['amplitude_deg']:8.3f}° {c['frequency_hz']:6.2f} Hz  "
                         f"{_stab(c)}")
        for c in p["combined_continuous_cycles"]:
            lines.append(f"    {'(continuous ideal) ' + c['nonlinearity']:40s} {c['amplitude_deg']:8.3f}° "
                         f"{c['frequency_hz']:6.2f} Hz  {_stab(c)}")
        for c in p["cycles"]:
            lines.append(f"    {c['nonlinearity'] + ' alone':40s} {c['amplitude_deg']:8.3f}° "
                         f"{c['frequency_hz']:6.2f} Hz  {_stab(c)}")
        mc = block.get("model_check")
        if mc:
            got = (f"±{mc['amplitude_deg']:.3f}° at {mc['frequency_hz']:.2f} Hz" if mc["amplitude_deg"] is not None
                   else f"no cycle (stops {mc['final_error_deg']:.4f}° from the target)")
            lines.append(f"    reduced nonlinear joint simulated: {got}")
        sim = block.get("simulated")
        if sim:
            if sim.get("fault"):
                got = f"stopped by the watchdog: {sim['fault']['cause']} ({sim['fault']['detail']})"
            elif sim.get("frequency_hz") is not None:
                got = f"±{sim['amplitude_deg']:.3f}° at {sim['frequency_hz']:.2f} Hz" + unsettled_note(sim)
            else:
                got = ("no cycle (hold too short to measure)" if sim["amplitude_deg"] is None
                       else f"no cycle (±{sim['amplitude_deg']:.3f}°)")
            lines.append("    full-stack simulation: " + got + f"; static error {sim['static_error_deg']:.3f}° "
                         f"(servo), {sim['static_error_true_deg']:.3f}° (true angle)" if not sim.get("fault") else
                         "    full-stack simulation: " + got)
            if block is not r and not sim.get("fault") and sim.get("balance_error_deg") is not None:
                lines.append(f"    frozen integral terms {sim['integral_terms_rad_s2']:+.2f} rad/s² centre the "
                             f"stuck joint at {sim['balance_error_deg']:+.3f}° (± the bound below)")
        lines.append("")
    bound = r["switch_off"]["predicted"]["static_error_bound_deg"]
    lines.append(f"switch-off static error bound T_F/(J·Kp_off) (T_F the largest local breakout, "
                 f"integral terms ≈ 0): {bound:.3f}°")
    if r["simulated"] is None:
        lines.append("simulated (full driver stack): not run")
    cmp_ = r.get("comparison")
    if cmp_:
        def _x(v):
            return "—" if v is None else f"×{v:.2f}"
        lines.append(f"simulated / predicted: amplitude {_x(cmp_['amplitude_ratio'])}, "
                     f"frequency {_x(cmp_['frequency_ratio'])}")
    if r.get("notes"):
        lines += ["", "assumed (not in the rig file):"] + [f"  - {n}" for n in r["notes"]]
    return "\n".join(lines)


def _stab(c: dict) -> str:
    return "stable" if c["stable"] else "unstable (threshold)"


def _nl_line(n: dict) -> str:
    val = next((n[k] for k in ("half_width", "level", "step", "limit") if k in n), None)
    return f"{n['type']} {val:.4g} {n.get('unit', 'rad/s²')} ({n['location'].replace('_', ' ')})"


def markdown(title: str, command: str, text: str, images: list[str]) -> str:
    out = [f"# {title}", "", f"Command: `{command}`", "", "```text", text, "```", ""]
    for img in images:
        out += [f"![{img}]({img})", ""]
    return "\n".join(out)


# ------------------------------------------------------------- full-stack simulations


def unsettled_note(sim: dict) -> str:
    """`` (NOT SETTLED: …)`` for a simulated cycle whose amplitude still changes through the window."""
    if sim.get("settled") is not False:
        return ""
    return (f" (NOT SETTLED: ±{sim['amplitude_first_third_deg']:.3f}° in the window's first third, "
            f"±{sim['amplitude_last_third_deg']:.3f}° in its last: hold longer, --hold)")


def limit_cycle_sim_figure(sim_on: dict | None, sim_off: dict | None, predicted: dict, title: str) -> Figure | None:
    """The full-stack runs: joint error over the whole run (integrators on / switched off) with the
    measurement window, a zoom on the cycle, and the spectrum of the window with the predicted
    frequency marked."""
    runs = [(lab, d, col) for lab, d, col in (("integrators on", sim_on, "tab:red"),
                                               ("switch-off", sim_off, "tab:blue")) if d and d.get("t_s")]
    if not runs:
        return None
    fig, ax = plt.subplots(3, 1, figsize=(9, 10))
    f_pred, a_pred = predicted.get("frequency_hz"), predicted.get("amplitude_deg")
    for lab, d, col in runs:
        t = np.asarray(d["t_s"])
        th = np.asarray(d["theta_deg"])
        err = np.asarray(d["theta_d_deg"]) - th
        w0, w1 = d["window_s"]
        amp = d.get("amplitude_deg")
        freq = d.get("frequency_hz")
        desc = f"{lab}: ±{amp:.3f}°" + (f" at {freq:.2f} Hz" if freq else " (no cycle)") if amp is not None else lab
        if d.get("settled") is False:
            desc += (f" — not settled: ±{d['amplitude_first_third_deg']:.2f}° → "
                     f"±{d['amplitude_last_third_deg']:.2f}° over the window")
        ax[0].plot(t, err, lw=0.8, color=col, label=desc)
        sel = (t >= w0) & (t <= w1)
        mean = float(np.mean(th[sel])) if sel.any() else 0.0
        zoom = t >= max(w0, t[-1] - 3.0)
        ax[1].plot(t[zoom], th[zoom] - mean, lw=1.0, color=col, label=f"{lab} (true angle about its mean)")
        meas = np.asarray(d["theta_meas_deg"])
        mean_m = float(np.mean(meas[sel])) if sel.any() else 0.0
        ax[1].plot(t[zoom], meas[zoom] - mean_m, lw=0.6, color=col, alpha=0.45, ls="--",
                   label=f"{lab} (pot reading about its mean, as the servo sees it)")
        seg = th[sel] - mean
        if seg.size > 16:
            dt = float(np.median(np.diff(t)))
            spec = np.abs(np.fft.rfft(seg * np.hanning(seg.size))) * 2 / (0.5 * seg.size)
            ax[2].semilogy(np.fft.rfftfreq(seg.size, dt), np.maximum(spec, 1e-5), lw=1.0, color=col, label=lab)
        ax[0].axvspan(w0, w1, color="grey", alpha=0.08)
    if a_pred is not None:
        for a in (ax[1],):
            a.axhline(a_pred, color="k", ls=":", lw=0.8, label=f"predicted ±{a_pred:.3f}°")
            a.axhline(-a_pred, color="k", ls=":", lw=0.8)
    if f_pred is not None:
        ax[2].axvline(f_pred, color="k", ls=":", lw=0.8, label=f"predicted {f_pred:.2f} Hz")
    ax[0].set_ylabel("error θd − θ (deg, true angle)")
    ax[0].set_xlabel("time (s); shaded: the limit-cycle window (from 2 s after the move)")
    ax[0].set_title(title)
    ax[1].set_ylabel("angle about the mean (deg)")
    ax[1].set_xlabel("time (s), last 3 s")
    ax[2].set_ylabel("amplitude (deg)")
    ax[2].set_xlabel("frequency (Hz), spectrum of the window")
    ax[2].set_xlim(0, 15)
    for a in ax:
        a.grid(True, alpha=0.3)
        a.legend(fontsize=7, loc="best")
    fig.tight_layout()
    return fig


def step_figure(step: dict, step_lin: np.ndarray, move: dict, move_lin: np.ndarray, title: str) -> Figure:
    """Step and quintic-move responses simulated through the full stack, with the sampled linear
    loop's prediction overlaid, and the tracking errors."""
    fig, ax = plt.subplots(2, 2, figsize=(12, 8))
    for col, d, lin, name in ((0, step, step_lin, "step"), (1, move, move_lin, "quintic move")):
        t = np.asarray(d["t_s"])
        th = np.asarray(d["theta_deg"])
        thm = np.asarray(d["theta_meas_deg"])
        thd = np.asarray(d["theta_d_deg"])
        th0, thm0, thd0 = th[0], thm[0], d["theta_start_deg"]
        lin_deg = np.degrees(lin)
        a = ax[0, col]
        a.plot(t, thd - thd0, "k--", lw=1, label="target θd")
        a.plot(t, th - th0, color="tab:red", lw=1.2, label="simulated, true angle")
        a.plot(t, thm - thm0, color="tab:orange", lw=0.7, alpha=0.7, label="simulated, pot (servo)")
        a.plot(t, lin_deg, color="tab:blue", lw=1.2, ls="-.", label="linear prediction (sampled loop)")
        a.set_ylabel("angle from start (deg)")
        a.set_title(f"{name}: settling {fmt(d.get('settling_time_s'), '.2f', ' s', none='never')} "
                    f"(steady state ±{d['settle_band_deg']:g}°)")
        e = ax[1, col]
        e.plot(t, (thd - thd0) - (thm - thm0), color="tab:orange", lw=0.8, label="simulated (servo's error)")
        e.plot(t, (thd - thd0) - (th - th0), color="tab:red", lw=0.8, alpha=0.7, label="simulated (true angle)")
        e.plot(t, (thd - thd0) - lin_deg, color="tab:blue", lw=1.0, ls="-.", label="linear prediction")
        e.set_ylabel("error θd − θ (deg)")
        e.set_xlabel("time (s)")
        if name == "step":
            e.set_ylim(-0.5 * abs(thd[-1] - thd0), 1.05 * abs(thd[-1] - thd0))
        for x in (a, e):
            x.grid(True, alpha=0.3)
            x.legend(fontsize=7, loc="best")
            if d.get("motion_end_s"):
                x.axvline(d["motion_end_s"], color="grey", lw=0.6, ls=":")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


HEATMAP_METRICS = (("lc_amplitude_deg", "limit-cycle amplitude (deg)", "viridis_r"),
                   ("phase_margin_deg", "sampled phase margin (deg)", "viridis"),
                   ("rms_tracking_error_deg", "rms tracking error during the move (deg)", "viridis_r"),
                   ("settling_time_s", "settling time into the steady state (s)", "viridis_r"))


#: why a cell of each map has no value (grey "—"), said on the map
NO_VALUE_REASON = {"lc_amplitude_deg": "no limit cycle", "phase_margin_deg": "no gain crossover",
                   "rms_tracking_error_deg": "not simulated", "settling_time_s": "never settled"}

IN_BAND_METRIC = "settling_time_s"
IN_BAND_LABEL = "in band\nfrom start"  #: settling 0 s: never left the band (not "settled at once")


def _unstable_point(row: dict) -> bool:
    """A sweep point in the ``unstable`` class: refused by servo.gain_guard (``stable`` false) or
    unstable in the sampled linear model (``sampled_stable`` false); neither was simulated."""
    return row.get("stable") is False or row.get("sampled_stable") is False


def sweep_heatmaps(rows: list[dict], x: str, y: str, title: str) -> Figure | None:
    """One heat map per metric over gains ``x`` and ``y``; cells show the value (mean over any other
    gains that vary); red hatched "unstable" = every point of the cell is unstable (its class, not a
    value: :func:`_unstable_point`); grey "—" = no value (not simulated, no cycle, never settled);
    on the settling map, green dotted "in band from start" = every point's settling time is exactly
    0 s: the joint never left its steady-state band after the move (a joint that left it and came
    back settles after ≥ one servo period, and shows that time)."""
    if not rows:
        return None
    xs = sorted({r[x] for r in rows})
    ys = sorted({r[y] for r in rows})
    unstable = np.zeros((len(ys), len(xs)), bool)
    for iy, yv in enumerate(ys):
        for ix, xv in enumerate(xs):
            cell = [r for r in rows if r[x] == xv and r[y] == yv]
            unstable[iy, ix] = bool(cell) and all(_unstable_point(r) for r in cell)
    fig, axes = plt.subplots(2, 2, figsize=(11, 9))
    for a, (key, label, cmap) in zip(axes.flat, HEATMAP_METRICS, strict=True):
        grid = np.full((len(ys), len(xs)), np.nan)
        in_band = np.zeros((len(ys), len(xs)), bool)
        for iy, yv in enumerate(ys):
            for ix, xv in enumerate(xs):
                vals = [r[key] for r in rows if r[x] == xv and r[y] == yv and r.get(key) is not None
                        and not _unstable_point(r)]
                if vals:
                    grid[iy, ix] = float(np.mean(vals))
                    if key == IN_BAND_METRIC and all(v == 0.0 for v in vals):
                        in_band[iy, ix] = True
                        grid[iy, ix] = np.nan  # a class, not a colour on the scale
        a.set_facecolor("#dddddd")
        m = np.ma.masked_invalid(grid)
        im = a.imshow(m, origin="lower", aspect="auto", cmap=cmap,
                      extent=(-0.5, len(xs) - 0.5, -0.5, len(ys) - 0.5))
        reason = NO_VALUE_REASON.get(key, "no value")
        if np.isfinite(grid).any():
            fig.colorbar(im, ax=a, shrink=0.85)
        else:  # a colour bar of nothing (−0.1…+0.1 by default) would only mislead
            a.text(0.5, 0.5, f"no point has a value here:\n{reason} (or unstable)", transform=a.transAxes,
                   ha="center", va="center", fontsize=9, bbox={"fc": "white", "ec": "#888888"})
        for iy in range(len(ys)):
            for ix in range(len(xs)):
                v = grid[iy, ix]
                if unstable[iy, ix]:
                    a.add_patch(Rectangle((ix - 0.5, iy - 0.5), 1, 1, facecolor="#f4cccc", edgecolor="#cc0000",
                                          hatch="//", lw=0))
                if in_band[iy, ix]:
                    a.add_patch(Rectangle((ix - 0.5, iy - 0.5), 1, 1, facecolor="#d9ead3", edgecolor="#38761d",
                                          hatch="..", lw=0))
                text = ("unstable" if unstable[iy, ix] else IN_BAND_LABEL if in_band[iy, ix]
                        else "—" if not np.isfinite(v) else f"{v:.3g}")
                a.text(ix, iy, text, ha="center", va="center", fontsize=8, color="w",
                       path_effects=[patheffects.withStroke(linewidth=2, foreground="k")])
        a.set_xticks(range(len(xs)), [f"{v:g}" for v in xs])
        a.set_yticks(range(len(ys)), [f"{v:g}" for v in ys])
        a.set_xlabel(x)
        a.set_ylabel(y)
        a.set_title(label + (f"\ngrey —: {reason}" if not np.isfinite(grid).all() else ""), fontsize=10)
    fig.suptitle(title)
    fig.tight_layout()
    return fig
