"""Encoder edge generation as a quadrature decoder's input sampler sees it (plant side).

The encoder's position is ``x`` in x4 units (quadrature states; ``x = θ·lines·4/2π``). The
physical A/B state is ``floor(x) mod 4`` (Gray order: 0 = A0 B0, 1 = A1 B0, 2 = A1 B1,
3 = A0 B1, so a rising ``x`` means A leads B). The index Z is high in one quadrature state per
``index_period_x4`` states (``floor(x) mod P == index_phase_x4``), as on gated-index encoders.

The decoder samples A, B and Z at ``sample_hz``. Between two samples the state difference
``d = Δfloor mod 4`` decodes as 0 → no count, 1 → +1, 3 → −1, and 2 → *illegal* (A and B both
changed; direction unknown, no count). So a step of 2 states per sample is illegal and lost,
3 states looks like −1 and 4 like 0 — exactly what a sampled hardware decoder (HCTL-2016,
LS7166 behind a filter) does when the shaft outruns its clock. An index is seen when Z is
sampled high after being sampled low; a fast shaft can step over it.

:func:`quadrature_events` evaluates one interval with ``x`` interpolated linearly from
``x4_start`` to ``x4_end``. Below one state change per sample it is closed-form (O(1) plus one
entry per index crossing); above, it evaluates every sample with numpy. The sampler's state
(last sampled state and time to the next sample) is carried between calls in
:class:`SamplerState`; intervals may have any length (a servo period or an integration step).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from emulators.signals import QuadratureEvents

_DECODE = np.array([0, 1, 0, -1], dtype=np.int64)  # d mod 4 → count (2 = illegal, no count)


@dataclass(frozen=True)
class SamplerState:
    """The decoder input sampler between intervals.

    Attributes:
        position: ``floor(x)`` at the last sample (absolute quadrature state number; the
            A/B phase is ``position mod 4``).
        next_sample_s: time from the start of the next interval to the next sample,
            in ``[0, 1/sample_hz)``.
        index_high: Z level at the last sample.
    """

    position: int
    next_sample_s: float = 0.0
    index_high: bool = False

    @property
    def phase(self) -> int:
        return self.position % 4


def _is_index(f: int, period: int, phase: int) -> bool:
    return period > 0 and f % period == phase


def initial_state(x4: float, index_period_x4: int = 0, index_phase_x4: int = 0) -> SamplerState:
    """The sampler state with the shaft at ``x4`` (its first sample at the next interval's start)."""
    f = math.floor(x4)
    return SamplerState(f, 0.0, _is_index(f, index_period_x4, index_phase_x4))


def x4_from_angle(theta_rad: float, counts_per_rev: float) -> float:
    """Shaft angle (rad) → position in x4 states, for an encoder with ``counts_per_rev`` = lines·4."""
    return theta_rad * counts_per_rev / (2.0 * math.pi)


def quadrature_events(
    x4_start: float,
    x4_end: float,
    duration_s: float,
    sample_hz: float,
    index_period_x4: int = 0,
    index_phase_x4: int = 0,
    state: SamplerState | None = None,
) -> tuple[QuadratureEvents, SamplerState]:
    """What the decoder's sampler decodes while ``x`` moves linearly from ``x4_start`` to ``x4_end``.

    Args:
        x4_start, x4_end: encoder position (x4 states) at the interval's start and end.
        duration_s: interval length (> 0).
        sample_hz: the decoder's input sampling rate (> 0).
        index_period_x4: states per index pulse (lines·4 for one index per revolution); 0: no index.
        index_phase_x4: the state, ``0 <= phase < period``, in which Z is high.
        state: the sampler state from the previous call (``None``: start at ``x4_start``).

    Returns:
        (events, new_state): ``events.counts`` the decoded net x4 counts (valid transitions
        only), ``events.illegal`` the number of illegal samples, ``events.index_offsets`` the
        decoded count (from the interval start) at each index rising edge, ``events.phase``
        the last sampled A/B state.
    """
    if not duration_s > 0:
        raise ValueError(f"duration_s must be > 0 (got {duration_s})")
    if not sample_hz > 0:
        raise ValueError(f"sample_hz must be > 0 (got {sample_hz})")
    period, ph = int(index_period_x4), int(index_phase_x4)
    if period < 0 or period == 1 or (period and not 0 <= ph < period):
        raise ValueError(f"index period {period} / phase {ph}: need period 0 or >= 2 and 0 <= phase < period")
    if state is None:
        state = initial_state(x4_start, period, ph)
    ts = 1.0 / sample_hz
    t0 = state.next_sample_s
    n = 0 if t0 >= duration_s else math.ceil((duration_s - t0) * sample_hz)
    while n > 0 and t0 + (n - 1) / sample_hz >= duration_s:
        n -= 1
    while t0 + n / sample_hz < duration_s:
        n += 1
    if n == 0:
        return (
            QuadratureEvents(0, 0, (), state.phase),
            SamplerState(state.position, max(t0 - duration_s, 0.0), state.index_high),
        )
    slope = (x4_end - x4_start) / duration_s
    next_s = min(max(t0 + n / sample_hz - duration_s, 0.0), ts)
    f_first = math.floor(x4_start + slope * t0)
    if abs(slope) * ts < 1.0 and abs(f_first - state.position) <= 1:
        # At most one state change per sample: every change is legal and the sampler visits
        # every state in between, so the count is the net change of floor(x). The first
        # sample may step against the interval's direction (the previous interval moved the
        # other way); after it the motion is monotonic.
        f_last = math.floor(x4_start + slope * (t0 + (n - 1) / sample_hz))
        counts = f_last - state.position
        first = f_first - state.position
        offsets: tuple[int, ...] = ()
        if period:
            found: list[int] = []
            if first and _is_index(f_first, period, ph) and not state.index_high:
                found.append(first)
            if f_last > f_first:
                m0 = f_first + 1 + (ph - f_first - 1) % period
                found += [first + m - f_first for m in range(m0, f_last + 1, period)]
            elif f_last < f_first:
                m0 = f_first - 1 - (f_first - 1 - ph) % period
                found += [first + m - f_first for m in range(m0, f_last - 1, -period)]
            offsets = tuple(found)
        z_last = _is_index(f_last, period, ph)
        return QuadratureEvents(counts, 0, offsets, f_last % 4), SamplerState(f_last, next_s, z_last)
    # Fast shaft: evaluate every sample (same float expressions as the closed form).
    t = t0 + np.arange(n, dtype=np.float64) / sample_hz
    f = np.floor(x4_start + slope * t).astype(np.int64)
    prev = np.empty_like(f)
    prev[0] = state.position
    prev[1:] = f[:-1]
    d = (f - prev) % 4
    steps = _DECODE[d]
    cum = np.cumsum(steps)
    illegal = int(np.count_nonzero(d == 2))
    offsets = ()
    z_last = False
    if period:
        z = (f % period) == ph
        zprev = np.empty_like(z)
        zprev[0] = state.index_high
        zprev[1:] = z[:-1]
        offsets = tuple(int(v) for v in cum[z & ~zprev])
        z_last = bool(z[-1])
    f_last = int(f[-1])
    return QuadratureEvents(int(cum[-1]), illegal, offsets, f_last % 4), SamplerState(f_last, next_s, z_last)


class EncoderSampler:
    """Stateful convenience around :func:`quadrature_events` for one encoder channel.

    Args:
        counts_per_rev: x4 counts per revolution (lines·4).
        sample_hz: decoder input sampling rate.
        index_phase_x4: the state within a revolution where Z is high (``None``: no index).
        theta0_rad: initial shaft angle.
    """

    def __init__(
        self, counts_per_rev: int, sample_hz: float, *, index_phase_x4: int | None = 0, theta0_rad: float = 0.0
    ) -> None:
        self.counts_per_rev = int(counts_per_rev)
        self.sample_hz = float(sample_hz)
        self.index_period = self.counts_per_rev if index_phase_x4 is not None else 0
        self.index_phase = int(index_phase_x4 or 0)
        self.x4 = x4_from_angle(theta0_rad, self.counts_per_rev)
        self.state = initial_state(self.x4, self.index_period, self.index_phase)

    def step(self, theta_end_rad: float, duration_s: float) -> QuadratureEvents:
        """Advance the shaft linearly to ``theta_end_rad`` over ``duration_s``; return the events."""
        x_end = x4_from_angle(theta_end_rad, self.counts_per_rev)
        ev, self.state = quadrature_events(
            self.x4, x_end, duration_s, self.sample_hz, self.index_period, self.index_phase, self.state
        )
        self.x4 = x_end
        return ev
