"""Figures of merit measured from recorded runs: limit cycles, tracking and settling.

Limit cycle (docs/jpl-figures.md, issue 5): over the hold after the last motion has ended and the
joint has settled, amplitude = half the peak-to-peak of the angle about its mean; frequency
from the zero crossings of the angle about its mean, cross-checked against the spectrum peak;
``None`` when there is no cycle (amplitude below ``min_amplitude_rad`` or fewer than two full
periods in the window).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LimitCycle:
    """A measured oscillation (SI): amplitude rad (half peak-to-peak), frequency Hz or None."""

    amplitude_rad: float
    frequency_hz: float | None
    mean_rad: float
    window_s: tuple[float, float]
    spectrum_peak_hz: float | None = None

    @property
    def amplitude_deg(self) -> float:
        return float(np.degrees(self.amplitude_rad))


def limit_cycle(t: np.ndarray, x: np.ndarray, t_start: float, *, min_amplitude_rad: float = np.radians(0.02),
                t_end: float | None = None) -> LimitCycle:
    """Measure the oscillation of ``x`` (rad) sampled at times ``t`` (s) over ``[t_start, t_end]``."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    sel = (t >= t_start) & np.isfinite(x)
    if t_end is not None:
        sel &= t <= t_end
    tw, xw = t[sel], x[sel]
    if tw.size < 4:
        return LimitCycle(0.0, None, float("nan"), (t_start, t_start))
    mean = float(np.mean(xw))
    amp = 0.5 * float(np.max(xw) - np.min(xw))
    window = (float(tw[0]), float(tw[-1]))
    dev = xw - mean
    freq = None
    peak = spectrum_peak(tw, dev)
    if amp >= min_amplitude_rad:
        s = np.signbit(dev)
        crossings = np.nonzero(s[1:] != s[:-1])[0]
        if crossings.size >= 4:
            # interpolate crossing instants; frequency = (crossings - 1) / 2 / span
            tc = tw[crossings] + (tw[crossings + 1] - tw[crossings]) * (
                dev[crossings] / (dev[crossings] - dev[crossings + 1]))
            freq = float((tc.size - 1) / 2.0 / (tc[-1] - tc[0]))
    return LimitCycle(amp, freq, mean, window, peak)


def spectrum_peak(t: np.ndarray, dev: np.ndarray) -> float | None:
    """Frequency (Hz) of the largest non-DC peak of a uniformly sampled signal, or None."""
    if t.size < 8:
        return None
    dt = float(np.median(np.diff(t)))
    spec = np.abs(np.fft.rfft((dev - dev.mean()) * np.hanning(dev.size)))
    freqs = np.fft.rfftfreq(dev.size, dt)
    if spec.size < 3 or not np.any(spec[1:] > 0):
        return None
    return float(freqs[1 + int(np.argmax(spec[1:]))])


def settling_time(t: np.ndarray, err: np.ndarray, t_start: float, band: float) -> float | None:
    """Time after ``t_start`` when |err| enters and stays within ``band``; None if it never does."""
    sel = t >= t_start
    tt, ee = t[sel], np.abs(err[sel])
    if tt.size == 0:
        return None
    outside = np.nonzero(ee > band)[0]
    if outside.size == 0:
        return 0.0
    last = outside[-1]
    if last + 1 >= tt.size:
        return None
    return float(tt[last + 1] - t_start)
