"""LSPB through via points, synchronized across joints, and the move sequencer."""

from __future__ import annotations

import numpy as np
import pytest

from servo.trajectory import JointLimits, Lspb, PlanContext, Quintic, Sequencer, Stay

LIM = JointLimits.make(3, [1.0, 0.5, 2.0], [2.0, 1.0, 4.0])
PTS = [np.zeros(3), np.array([1.0, 0.2, -0.5]), np.array([0.5, 1.0, 0.0]), np.array([2.0, 0.0, 1.0])]


def dense(tr, dt=1e-3):
    ts = np.arange(0.0, tr.duration + 5 * dt, dt)
    s = [tr.sample(t) for t in ts]
    return ts, np.array([x.theta_d for x in s]), np.array([x.omega_d for x in s]), np.array([x.alpha_d for x in s])


def test_passes_through_every_via_at_its_time():
    tr = Lspb(PTS, LIM)
    assert len(tr.via_times) == len(PTS)
    for t, p in zip(tr.via_times, PTS, strict=True):
        np.testing.assert_allclose(tr.sample(t).theta_d, p, atol=1e-12)
    assert np.all(np.diff(tr.via_times) > 0)


def test_position_and_velocity_are_continuous_and_rest_at_the_ends():
    tr = Lspb(PTS, LIM)
    dt = 1e-4
    _, th, w, al = dense(tr, dt)
    vmax, amax = LIM.v_max, LIM.a_max
    # steps bounded by the velocity (position continuous) and by the acceleration (velocity continuous)
    assert np.all(np.abs(np.diff(th, axis=0)) <= vmax * dt * (1 + 1e-6))
    assert np.all(np.abs(np.diff(w, axis=0)) <= amax * dt * (1 + 1e-6))
    # velocity is the derivative of position
    np.testing.assert_allclose(np.diff(th, axis=0) / dt, 0.5 * (w[1:] + w[:-1]), atol=amax.max() * dt)
    np.testing.assert_allclose(w[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(tr.sample(tr.duration - 1e-9).omega_d, 0.0, atol=1e-6)
    assert tr.sample(tr.duration).done and not tr.sample(tr.duration - 1e-3).done
    # limits respected and reached
    assert np.all(np.abs(w) <= vmax * (1 + 1e-9)) and np.all(np.abs(al) <= amax * (1 + 1e-9))
    assert np.max(np.max(np.abs(w), axis=0) / vmax) == pytest.approx(1.0, rel=1e-9) or \
        np.max(np.max(np.abs(al), axis=0) / amax) == pytest.approx(1.0, rel=1e-9)


def test_speed_factor_and_synchronisation():
    tr1, tr2 = Lspb(PTS, LIM, 1.0), Lspb(PTS, LIM, 0.5)
    assert tr2.duration == pytest.approx(2 * tr1.duration)
    np.testing.assert_allclose(tr2.via_times, 2 * tr1.via_times)
    # all joints share the schedule: they all stop at the same instant
    ts, _, w, _ = dense(tr1, 1e-3)
    moving_until = [ts[np.nonzero(np.abs(w[:, j]) > 1e-9)[0].max()] for j in range(3)]
    assert max(moving_until) - min(moving_until) < 2e-3


def test_duplicate_points_and_trivial_paths():
    tr = Lspb([np.zeros(2), np.zeros(2), np.ones(2), np.ones(2)], JointLimits.make(2, 1.0))
    assert tr.points.shape == (2, 2)
    np.testing.assert_allclose(tr.sample(tr.duration / 2).theta_d, [0.5, 0.5], atol=1e-12)
    still = Lspb([np.ones(2)], JointLimits.make(2, 1.0))
    assert still.duration == 0.0 and still.sample(0.0).done


class _Fixed:
    """A test move: quintic to a fixed target with a fixed duration."""

    kind = "fixed"

    def __init__(self, target, duration):
        self.target, self.dur = np.asarray(target, float), duration

    def build(self, start, ctx):
        return Quintic(start, self.target, self.dur)


class _Hold:
    kind = "wait"

    def __init__(self, d):
        self.d = d

    def build(self, start, ctx):
        return Stay(start, self.d)


def test_sequencer_plays_moves_in_order():
    ctx = PlanContext(JointLimits.make(1, 1.0))
    seq = Sequencer([_Fixed([1.0], 1.0), _Hold(0.5), _Fixed([1.0], 0.0), _Fixed([0.0], 1.0)], np.zeros(1), ctx)
    samples = {t: seq.sample(t) for t in (0.0, 0.5, 1.0, 1.2, 1.5, 2.0, 2.5, 3.0)}
    assert not samples[0.0].done and samples[0.5].theta_d[0] == pytest.approx(0.5)
    assert samples[1.0].done and samples[1.2].done and samples[1.2].theta_d[0] == 1.0
    assert not samples[1.5].done  # the zero-length move was skipped; the last move started at 1.5
    assert samples[2.0].theta_d[0] == pytest.approx(0.5)
    assert samples[2.5].done and samples[3.0].done and samples[3.0].theta_d[0] == 0.0
    assert seq.finished and seq.total_duration == pytest.approx(2.5)
    assert [(r.index, r.t_start) for r in seq.records] == [(0, 0.0), (1, 1.0), (2, 1.5), (3, 1.5)]
    assert seq.motion_id == 4
    with pytest.raises(ValueError, match="backwards"):
        seq.sample(1.0)


def test_planning_thousands_of_vias_takes_linear_memory() -> None:
    """A dense solve of the corner system holds an (m−1)² matrix: 72 MB for 3 000 vias (and 7 TiB
    for 10⁶). The tridiagonal elimination holds a few arrays of m × n: well under 4 MB here."""
    import tracemalloc

    rng = np.random.default_rng(7)
    pts = [np.zeros(6), *(rng.uniform(-1.0, 1.0, size=6) for _ in range(3000))]
    lim = JointLimits.make(6, 1.0, 2.0)
    tracemalloc.start()
    try:
        tr = Lspb(pts, lim)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 4_000_000, f"planning 3 000 vias peaked at {peak / 1e6:.1f} MB"
    # and the path is still exact at every via (the spec: it passes through each at its time)
    for k in (1, 1500, 2999, 3000):
        np.testing.assert_allclose(tr.sample(tr.via_times[k]).theta_d, pts[k], atol=1e-9)


def test_a_path_beyond_the_via_limit_is_refused_before_it_is_planned() -> None:
    from servo.trajectory import TrajectoryError
    from servo.trajectory.lspb import MAX_VIA_POINTS

    assert MAX_VIA_POINTS == 10_000  # the limit docs/control.md states
    pts = [np.zeros(1)] + [np.full(1, float(k % 2)) for k in range(MAX_VIA_POINTS + 1)]
    with pytest.raises(TrajectoryError, match="at most 10000"):
        Lspb(pts, JointLimits.make(1, 1.0))
