"""Figures of merit measured from recorded runs: limit cycles, tracking and settling.

Limit cycle (docs/jpl-figures.md, issue 5): over the hold after the last motion has ended and the
joint has settled, amplitude = half the peak-to-peak of the angle about its mean; frequency
from the crossings about the mean (with hysteresis: sensor noise adds none), cross-checked
against the spectrum peak.

**The rule (what counts as a limit cycle)**, :func:`is_cycle`: the motion is reported as a cycle
only when

* its amplitude (half peak-to-peak) is at least ``min_amplitude_rad`` and at least
  :data:`CYCLE_MIN_QUANTA` steps of the sensor it is read from (``quantum_rad``; a 12-bit pot
  flickering between neighbouring codes reads ±2–3 codes peak-to-peak with no motion at all);
* its spectrum peaks at or below :data:`CYCLE_MAX_NYQUIST_FRACTION` of the Nyquist frequency of
  the samples (ADC noise has its peak anywhere up to Nyquist, 26–31 Hz at 125 Hz; the paper's
  cycle is at 1–3 Hz);
* the window holds at least two full periods (four crossings about the mean with a hysteresis
  of 3 sensor steps or a tenth of the amplitude, whichever is larger: :func:`_crossing_times`),
  and the frequency they give agrees with the spectrum peak within a factor of 2 (a periodic
  cycle, not irregular hunting).

Otherwise :attr:`LimitCycle.frequency_hz` is ``None`` and :attr:`LimitCycle.cycle` false; the
amplitude is still the residual motion's half peak-to-peak. A window too short to measure
(fewer than 4 samples) gives ``amplitude_rad = None``: printed "—", never 0.000.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a cycle must be at least this many sensor steps (half peak-to-peak): 4 pot codes = 0.33° on jpl-arm
CYCLE_MIN_QUANTA = 4.0
#: and its spectrum peak at or below this fraction of the Nyquist frequency (12.5 Hz at 125 Hz)
CYCLE_MAX_NYQUIST_FRACTION = 0.2
#: the crossings that count periods have this many sensor steps of hysteresis (at least 0.1 × amplitude)
HYSTERESIS_QUANTA = 3.0
#: the rule in one line, for reports' footnotes
CYCLE_RULE = (f"a limit cycle is reported only when its half peak-to-peak is >= {CYCLE_MIN_QUANTA:g} sensor steps "
              f"(pot: ADC codes) and >= 0.02 deg, its spectrum peak is <= {CYCLE_MAX_NYQUIST_FRACTION:g} x Nyquist "
              "and the window holds two full periods at that frequency; otherwise \"—\" "
              "(quantization noise is not a cycle)")


@dataclass(frozen=True)
class LimitCycle:
    """A measured oscillation (SI): amplitude rad (half peak-to-peak; None when the window is too
    short to measure), frequency Hz (None unless it is a cycle by the module's rule)."""

    amplitude_rad: float | None
    frequency_hz: float | None
    mean_rad: float
    window_s: tuple[float, float]
    spectrum_peak_hz: float | None = None

    @property
    def amplitude_deg(self) -> float | None:
        return None if self.amplitude_rad is None else float(np.degrees(self.amplitude_rad))

    @property
    def cycle(self) -> bool:
        """True when the motion is a limit cycle by the module's rule (it then has a frequency)."""
        return self.frequency_hz is not None


def limit_cycle(t: np.ndarray, x: np.ndarray, t_start: float, *, min_amplitude_rad: float = np.radians(0.02),
                quantum_rad: float = 0.0, t_end: float | None = None) -> LimitCycle:
    """Measure the oscillation of ``x`` (rad) sampled at times ``t`` (s) over ``[t_start, t_end]``;
    ``quantum_rad`` is one step of the sensor ``x`` was read from (0: not quantized)."""
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    sel = (t >= t_start) & np.isfinite(x)
    if t_end is not None:
        sel &= t <= t_end
    tw, xw = t[sel], x[sel]
    if tw.size < 4:
        return LimitCycle(None, None, float("nan"), (t_start, t_start))
    mean = float(np.mean(xw))
    amp = 0.5 * float(np.max(xw) - np.min(xw))
    window = (float(tw[0]), float(tw[-1]))
    dev = xw - mean
    freq = None
    peak = spectrum_peak(tw, dev)
    nyquist_hz = 0.5 / float(np.median(np.diff(tw)))
    if is_cycle(amp, peak, nyquist_hz, min_amplitude_rad=min_amplitude_rad, quantum_rad=quantum_rad):
        # hysteresis: above the sensor's noise (3 steps), small against the cycle (a tenth of
        # its amplitude), so that cycles of varying size all count
        tc = _crossing_times(tw, dev, max(HYSTERESIS_QUANTA * quantum_rad, 0.1 * amp))
        if tc.size >= 4:
            f = float((tc.size - 1) / 2.0 / (tc[-1] - tc[0]))
            # a periodic cycle: its crossings and its spectrum agree (irregular hunting does not)
            if peak is not None and 0.5 <= f / peak <= 2.0:
                freq = f
    return LimitCycle(amp, freq, mean, window, peak)


def _crossing_times(t: np.ndarray, dev: np.ndarray, level: float) -> np.ndarray:
    """Instants ``dev`` crosses ``+level`` upwards after having been below ``-level``, and
    ``-level`` downwards after having been above ``+level`` (a Schmitt trigger: sensor noise
    about the mean adds no crossings), interpolated between samples. On a sine the up and
    down crossings are half a period apart, so consecutive instants are half periods."""
    out: list[float] = []
    state = 0
    for k in range(1, dev.size):
        if state <= 0 and dev[k] >= level > dev[k - 1]:
            lv = level
        elif state >= 0 and dev[k] <= -level < dev[k - 1]:
            lv = -level
        else:
            continue
        out.append(float(t[k - 1] + (t[k] - t[k - 1]) * (lv - dev[k - 1]) / (dev[k] - dev[k - 1])))
        state = 1 if lv > 0 else -1
    return np.asarray(out)


def is_cycle(amplitude_rad: float, spectrum_peak_hz: float | None, nyquist_hz: float, *,
             min_amplitude_rad: float = np.radians(0.02), quantum_rad: float = 0.0) -> bool:
    """The amplitude and spectrum parts of the rule (module docstring); the two-period part is
    checked on the zero crossings by :func:`limit_cycle`."""
    if not (amplitude_rad >= min_amplitude_rad and amplitude_rad >= CYCLE_MIN_QUANTA * quantum_rad):
        return False
    return spectrum_peak_hz is not None and spectrum_peak_hz <= CYCLE_MAX_NYQUIST_FRACTION * nyquist_hz


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
