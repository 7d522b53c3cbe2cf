"""A tolerance study's report: percentiles and histograms of the sweep rows' figures, and the
fraction of samples over the user's thresholds (``--threshold lc_amp_deg=0.5``), for each
integrator switch-off mode.

A sample counts in a metric's percentiles when its run gave that figure (a run the watchdog
stopped, or a point not simulated, gives none; their number is reported as ``missing``). The
fraction over a threshold is over ALL the samples of the mode: a sample without the figure is
not over it — except a watchdog fault, which is counted over (a fault is worse than any limit
cycle), and said so in ``faults``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from vmehil.errors import VmehilError

#: reported metrics: row column -> (label, unit)
METRICS: dict[str, tuple[str, str]] = {
    "lc_amplitude_deg": ("limit-cycle amplitude", "deg"),
    "lc_frequency_hz": ("limit-cycle frequency", "Hz"),
    "phase_margin_deg": ("sampled phase margin", "deg"),
    "rms_tracking_error_deg": ("rms tracking error", "deg"),
    "max_tracking_error_deg": ("max tracking error", "deg"),
    "settling_time_s": ("settling time", "s"),
}
ALIASES = {"lc_amp_deg": "lc_amplitude_deg", "lc_amp": "lc_amplitude_deg", "lc_freq_hz": "lc_frequency_hz",
           "lc_hz": "lc_frequency_hz", "pm_deg": "phase_margin_deg", "track_rms_deg": "rms_tracking_error_deg",
           "track_max_deg": "max_tracking_error_deg", "settle_s": "settling_time_s", "settling_s": "settling_time_s"}
PERCENTILES = (5, 25, 50, 75, 95)


class ThresholdError(VmehilError, ValueError):
    """A malformed ``--threshold``."""


def parse_thresholds(texts: Iterable[str]) -> dict[str, float]:
    """``METRIC=VALUE`` terms (METRIC a column of :data:`METRICS` or an alias such as lc_amp_deg)."""
    out: dict[str, float] = {}
    names = ", ".join([*METRICS, *ALIASES])
    for text in texts:
        name, sep, value = text.partition("=")
        key = ALIASES.get(name.strip().lower(), name.strip().lower())
        if not sep or key not in METRICS:
            raise ThresholdError(f"--threshold {text!r}: write METRIC=VALUE with METRIC one of {names}")
        try:
            v = float(value)
        except ValueError:
            raise ThresholdError(f"--threshold {text!r}: {value.strip()!r} is not a number") from None
        if not math.isfinite(v):
            raise ThresholdError(f"--threshold {text!r}: the value must be finite")
        if key in out:
            raise ThresholdError(f"--threshold: {key} is given twice")
        out[key] = v
    return out


def _mode(row: dict[str, Any]) -> str:
    return "switch_off" if row.get("switch_off") else "integrators_on"


def _values(rows: list[dict[str, Any]], key: str) -> list[float]:
    """``key`` of the rows that have it, leaving out runs the watchdog stopped (their figures are
    of a run cut short)."""
    return [float(r[key]) for r in rows if not r.get("fault") and r.get(key) is not None and math.isfinite(r[key])]


def summarize(rows: list[dict[str, Any]], thresholds: dict[str, float]) -> dict[str, Any]:
    """Per switch-off mode (``integrators_on``, ``switch_off``): ``samples``, ``faults``, and per
    metric ``n``, ``missing``, ``min``, ``max``, ``mean``, ``p5``…``p95``; per threshold ``over``
    (count) and ``fraction``."""
    out: dict[str, Any] = {}
    for mode in ("integrators_on", "switch_off"):
        mine = [r for r in rows if _mode(r) == mode]
        if not mine:
            continue
        faults = sum(1 for r in mine if r.get("fault"))
        block: dict[str, Any] = {"samples": len(mine), "faults": faults, "metrics": {}, "thresholds": {}}
        for key in METRICS:
            vals = np.array(_values(mine, key))
            m: dict[str, Any] = {"n": int(vals.size), "missing": len(mine) - int(vals.size)}
            if vals.size:
                m.update({"min": float(vals.min()), "max": float(vals.max()), "mean": float(vals.mean()),
                          **{f"p{q}": float(np.percentile(vals, q)) for q in PERCENTILES}})
            block["metrics"][key] = m
        for key, limit in thresholds.items():
            over = sum(1 for r in mine if r.get("fault") or (r.get(key) is not None and r[key] > limit))
            block["thresholds"][key] = {"limit": limit, "over": over, "fraction": over / len(mine)}
        out[mode] = block
    return out


def summary_text(summary: dict[str, Any]) -> str:
    lines = []
    for mode, block in summary.items():
        label = "integrators on (no switch-off)" if mode == "integrators_on" else "integrator switch-off"
        lines.append(f"{label}: {block['samples']} samples, {block['faults']} stopped by the watchdog")
        head = f"  {'':28s}{'n':>5s}" + "".join(f"{'p' + str(q):>10s}" for q in PERCENTILES)
        lines.append(head)
        for key, m in block["metrics"].items():
            name, unit = METRICS[key]
            cells = "".join(f"{m[f'p{q}']:>10.4g}" if m["n"] else f"{'—':>10s}" for q in PERCENTILES)
            lines.append(f"  {name + ' (' + unit + ')':28s}{m['n']:>5d}{cells}")
        for key, t in block["thresholds"].items():
            name, unit = METRICS[key]
            lines.append(f"  over {name} {t['limit']:g} {unit}: {t['over']} of {block['samples']} "
                         f"({100 * t['fraction']:.1f} %)")
        lines.append("")
    return "\n".join(lines).rstrip()


def histogram_figure(rows: list[dict[str, Any]], thresholds: dict[str, float], title: str) -> Any:
    """Histograms of every metric, one panel each, switch-off modes overlaid; thresholds drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(11, 6.2))
    for ax, (key, (name, unit)) in zip(axes.flat, METRICS.items(), strict=True):
        drawn = False
        every = _values(rows, key)
        edges = np.histogram_bin_edges(every, bins=20) if every else None  # one set of bins for both modes
        for mode, colour, label in (("integrators_on", "C0", "integrators on"), ("switch_off", "C1", "switch-off")):
            vals = _values([r for r in rows if _mode(r) == mode], key)
            if vals:
                ax.hist(vals, bins=edges, alpha=0.6, color=colour, label=f"{label} (n={len(vals)})")
                drawn = True
        if key in thresholds:
            ax.axvline(thresholds[key], color="k", linestyle="--", linewidth=1, label=f"threshold {thresholds[key]:g}")
        ax.set_xlabel(f"{name} ({unit})")
        ax.set_ylabel("samples")
        if drawn:
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "no value", ha="center", va="center", transform=ax.transAxes)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig
