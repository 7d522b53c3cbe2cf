"""The plant's encoder edge model: x4 encoder positions during a servo period →
:class:`QuadratureEvents` per joint, what the harness publishes to the decoder board.

:mod:`emulators.encoder_edges` is a second model of the same thing (a sampler whose state is
carried between intervals), used for an encoder on its own — the calibration bench of the tests
(``tests/support/calib_bench.py``) — and tested there; the two can differ by one count at an
interval's end. One model for both is left to do: it changes the lockstep fingerprint.

Definition used here:

* the x4 state is ``floor(x4)``; its value modulo 4 is the quadrature phase (Gray order);
* if the encoder never moves more than one x4 state per decoder input sample during the
  period, ``counts = floor(end) − floor(start)`` and there are no illegal transitions;
* otherwise the position is linearly interpolated to every decoder sample instant and decoded
  as a decoder would: a state change of 1 or 3 (mod 4) counts +1/−1 (a change of 3 is an
  aliased step and counts the wrong way), a change of 2 is an illegal transition (A and B both
  changed: counted in ``illegal``, no count), 0 is no change;
* an index pulse occurs once per ``index_period_x4`` at x4 position ``p ≡ index_phase_x4``; it is
  reported when the decoded state enters ``p`` (moving up) or leaves it (moving down), with
  ``offset = p − floor(start)`` (slow case) or the decoded count offset at that sample (fast case).
"""

from __future__ import annotations

import numpy as np

from emulators.signals import QuadratureEvents


def _index_hits(f0: np.ndarray, f1: np.ndarray, period: int, phase: int) -> list[int]:
    """Index positions crossed between consecutive integer states f0 → f1 (arrays, in order)."""
    hits: list[int] = []
    a = np.floor_divide(f0 - phase, period)
    b = np.floor_divide(f1 - phase, period)
    for k in np.nonzero(a != b)[0]:
        lo, hi = int(f0[k]), int(f1[k])
        if hi > lo:  # positive: crossing p with lo < p <= hi
            first = lo + 1 + ((phase - (lo + 1)) % period)
            hits.extend(range(first, hi + 1, period))
        else:  # negative: leaving p with hi < p <= lo
            last = lo - ((lo - phase) % period)
            hits.extend(range(last, hi, -period))
    return hits


def encoder_events(
    x4_positions: np.ndarray,
    dt: float,
    sample_hz: float | np.ndarray,
    index_period_x4: int | np.ndarray,
    index_phase_x4: int | np.ndarray,
) -> list[QuadratureEvents]:
    """Quadrature events for each joint over one period.

    Args:
        x4_positions: ``[substeps + 1, joints]`` encoder position (float x4 counts) at every
            substep boundary, start of the period first.
        dt: substep length (s).
        sample_hz: the decoder's input sampling rate (Hz), scalar or per joint.
        index_period_x4: x4 counts per index pulse (4·lines for once per revolution).
        index_phase_x4: x4 position of the index pulse modulo the period.
    """
    x = np.asarray(x4_positions, dtype=float)
    steps, n = x.shape[0] - 1, x.shape[1]
    fs = np.broadcast_to(np.asarray(sample_hz, dtype=float), (n,))
    period = np.broadcast_to(np.asarray(index_period_x4, dtype=np.int64), (n,))
    phase = np.broadcast_to(np.asarray(index_phase_x4, dtype=np.int64), (n,))
    f = np.floor(x).astype(np.int64)
    if steps > 0:
        speed = np.max(np.abs(np.diff(x, axis=0)), axis=0) / dt  # x4 counts per second
    else:
        speed = np.zeros(n)
    out: list[QuadratureEvents] = []
    for j in range(n):
        f0 = int(f[0, j])
        per, ph = int(period[j]), int(phase[j])
        if speed[j] < fs[j]:
            hits = _index_hits(f[:-1, j], f[1:, j], per, ph)
            out.append(
                QuadratureEvents(
                    counts=int(f[-1, j] - f0),
                    illegal=0,
                    index_offsets=tuple(p - f0 for p in hits),
                    phase=int(f[-1, j] % 4),
                )
            )
            continue
        # per-sample evaluation at the decoder's input rate
        m = max(round(steps * dt * fs[j]), 1)
        ts = np.arange(1, m + 1) * (steps / m)  # sample instants in substep units
        xs = np.interp(ts, np.arange(steps + 1), x[:, j])
        states = np.concatenate(([f0], np.floor(xs).astype(np.int64)))
        d = np.diff(states) % 4
        step = np.where(d == 1, 1, np.where(d == 3, -1, 0))
        decoded = np.cumsum(step)
        illegal = int(np.count_nonzero(d == 2))
        hits_idx: list[int] = []
        true_hits = _index_hits(states[:-1], states[1:], per, ph)
        if true_hits:
            a = np.floor_divide(states[:-1] - ph, per)
            b = np.floor_divide(states[1:] - ph, per)
            for k in np.nonzero(a != b)[0]:
                hits_idx.append(int(decoded[k]))
        out.append(
            QuadratureEvents(
                counts=int(decoded[-1]),
                illegal=illegal,
                index_offsets=tuple(hits_idx),
                phase=int(states[-1] % 4),
            )
        )
    return out
