"""Linear segments with parabolic blends (LSPB) through via points, synchronized across joints.

All joints share the segment timing: corner times τ_0 < τ_1 < … < τ_m and one blend duration t_b.
Between blends every joint moves at constant velocity; around each corner it changes velocity at
constant acceleration over [τ_k − t_b/2, τ_k + t_b/2] (the first and last blends start/end at rest).
Unlike the textbook construction (which only passes *near* interior vias), the straight lines'
corner points c_k are solved (a small tridiagonal system, shared by all joints) so that the blended
path passes exactly through every via θ_k at τ_k::

    c_k + (v_k − v_{k−1})·t_b/8 = θ_k,     v_k = (c_{k+1} − c_k)/d_k,   c_0 = θ_0,  c_m = θ_m

Timing: nominal d_k = max_j |Δθ_kj|/(s·v_max_j); t_b from a_max (or ¼ of the shortest segment when no
acceleration limit is given); then the whole schedule is stretched by one factor so that no joint
exceeds s·v_max or s²·a_max (the corner points do not change under a uniform time scaling). Position
and velocity are continuous; the path starts and ends at rest.
"""

from __future__ import annotations

import numpy as np

from servo.trajectory.base import JointLimits, Sample, TrajectoryError, as_positions, check_speed

DEFAULT_BLEND_FRACTION = 0.25


class Lspb:
    """A synchronized LSPB path through ``points`` (list of joint vectors, rad; the first is the start)."""

    def __init__(self, points: list[np.ndarray], limits: JointLimits, speed: float = 1.0) -> None:
        s = check_speed(speed)
        n = limits.n
        if len(points) < 1:
            raise TrajectoryError("an LSPB path needs at least a start point")
        pts = [as_positions(f"via[{i}]", p, n) for i, p in enumerate(points)]
        kept = [pts[0]]
        for p in pts[1:]:
            if not np.array_equal(p, kept[-1]):
                kept.append(p)
        P = np.array(kept)  # (m+1, n)
        self.points = P
        self.start = P[0].copy()
        self.end = P[-1].copy()
        m = P.shape[0] - 1
        if m == 0:
            self.duration = 0.0
            self.via_times = np.array([0.0])
            self._starts = np.array([0.0])
            self._p = P[:1].copy()
            self._v = np.zeros((1, n))
            self._a = np.zeros((1, n))
            return
        vmax = s * limits.v_max
        amax = None if limits.a_max is None else s * s * limits.a_max
        delta = np.diff(P, axis=0)  # (m, n)
        d = np.max(np.abs(delta) / vmax, axis=1)  # (m,)
        if amax is not None:
            v_nom = delta / d[:, None]
            dv = np.diff(np.vstack([np.zeros(n), v_nom, np.zeros(n)]), axis=0)  # (m+1, n)
            tb = float(np.max(np.abs(dv) / amax))
        else:
            tb = DEFAULT_BLEND_FRACTION * float(np.min(d))
        d = np.maximum(d, tb)
        C = self._corners(P, d, tb)
        v = np.diff(C, axis=0) / d[:, None]
        vfull = np.vstack([np.zeros(n), v, np.zeros(n)])
        r = max(1.0, float(np.max(np.abs(v) / vmax)))
        if amax is not None:
            r = max(r, float(np.sqrt(np.max(np.abs(np.diff(vfull, axis=0)) / tb / amax))))
        d, tb, vfull = d * r, tb * r, vfull / r
        self.blend_time = tb
        self.segment_durations = d
        tau = tb / 2.0 + np.concatenate([[0.0], np.cumsum(d)])
        self.duration = float(tau[-1] + tb / 2.0)
        #: times (s) at which the path is at each point: 0, the corner times of the vias, the end
        self.via_times = np.concatenate([[0.0], tau[1:-1], [self.duration]])
        self.corners = C
        # pieces: blend_0, line_0, blend_1, line_1, ..., blend_m
        starts, ps, vs, accs = [], [], [], []
        for k in range(m + 1):
            v_in, v_out = vfull[k], vfull[k + 1]
            starts.append(tau[k] - tb / 2.0)
            ps.append(C[k] - v_in * tb / 2.0)
            vs.append(v_in)
            accs.append((v_out - v_in) / tb)
            if k < m:
                starts.append(tau[k] + tb / 2.0)
                ps.append(C[k] + v_out * tb / 2.0)
                vs.append(v_out)
                accs.append(np.zeros(n))
        self._starts = np.array(starts)
        self._p, self._v, self._a = np.array(ps), np.array(vs), np.array(accs)

    @staticmethod
    def _corners(P: np.ndarray, d: np.ndarray, tb: float) -> np.ndarray:
        m = P.shape[0] - 1
        C = P.copy()
        if m < 2:
            return C
        k_in = m - 1
        M = np.zeros((k_in, k_in))
        rhs = P[1:m].copy()
        for i in range(k_in):
            k = i + 1
            alpha, gamma = tb / (8.0 * d[k - 1]), tb / (8.0 * d[k])
            M[i, i] = 1.0 - alpha - gamma
            if i > 0:
                M[i, i - 1] = alpha
            else:
                rhs[i] -= alpha * P[0]
            if i < k_in - 1:
                M[i, i + 1] = gamma
            else:
                rhs[i] -= gamma * P[m]
        C[1:m] = np.linalg.solve(M, rhs)
        return C

    def sample(self, t: float) -> Sample:
        if t >= self.duration:
            z = np.zeros_like(self.end)
            return Sample(self.end.copy(), z, z.copy(), True)
        t = max(t, 0.0)
        i = int(np.searchsorted(self._starts, t, side="right")) - 1
        dt = t - self._starts[i]
        a = self._a[i]
        return Sample(self._p[i] + self._v[i] * dt + 0.5 * a * dt * dt, self._v[i] + a * dt, a.copy(), False)
