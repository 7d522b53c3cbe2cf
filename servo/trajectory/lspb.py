"""Linear segments with parabolic blends (LSPB) through via points, synchronized across joints.

All joints share the segment timing: corner times τ_0 < τ_1 < … < τ_m and one blend duration t_b.
Between blends every joint moves at constant velocity; around each corner it changes velocity at
constant acceleration over [τ_k − t_b/2, τ_k + t_b/2] (the first and last blends start/end at rest).
Unlike the textbook construction (which only passes *near* interior vias), the straight lines'
corner points c_k are solved (a small tridiagonal system, shared by all joints) so that the blended
path passes exactly through every via θ_k at τ_k::

    c_k + (v_k − v_{k−1})·t_b/8 = θ_k,     v_k = (c_{k+1} − c_k)/d_k,   c_0 = θ_0,  c_m = θ_m

The system is tridiagonal and strictly diagonally dominant (t_b ≤ d_k, so each off-diagonal term is
at most 1/8 and the diagonal at least 3/4): it is solved by elimination in O(m) time and memory
(a dense solve was O(m²) memory and O(m³) time: 3 000 vias took 1.9 s, 10⁶ asked for 7 TiB). A
path has at most :data:`MAX_VIA_POINTS` vias, so planning one is bounded (about 0.1 s at the limit).

Timing: nominal d_k = max_j |Δθ_kj|/(s·v_max_j); t_b from a_max (or ¼ of the shortest segment when no
acceleration limit is given); then the whole schedule is stretched by one factor so that no joint
exceeds s·v_max or s²·a_max (the corner points do not change under a uniform time scaling). Position
and velocity are continuous; the path starts and ends at rest.
"""

from __future__ import annotations

import numpy as np

from servo.trajectory.base import JointLimits, Sample, TrajectoryError, as_positions, check_speed

DEFAULT_BLEND_FRACTION = 0.25
#: the most via points one LSPB path may have (the start point not counted); docs/control.md
MAX_VIA_POINTS = 10_000


class Lspb:
    """A synchronized LSPB path through ``points`` (list of joint vectors, rad; the first is the start)."""

    def __init__(self, points: list[np.ndarray], limits: JointLimits, speed: float = 1.0) -> None:
        s = check_speed(speed)
        n = limits.n
        if len(points) < 1:
            raise TrajectoryError("an LSPB path needs at least a start point")
        if len(points) - 1 > MAX_VIA_POINTS:
            raise TrajectoryError(f"an LSPB path of {len(points) - 1} via points; at most {MAX_VIA_POINTS} are planned")
        try:
            raw = np.asarray(points, dtype=float)
        except (TypeError, ValueError):
            raw = None
        if raw is None or raw.shape != (len(points), n) or not np.all(np.isfinite(raw)):
            for i, p in enumerate(points):  # name the first bad point
                as_positions(f"via[{i}]", p, n)
            raise TrajectoryError(f"via points must be {n} finite joint angles in rad each")
        # drop a point equal to the one before it (a zero-length segment)
        keep = np.concatenate([[True], np.any(raw[1:] != raw[:-1], axis=1)])
        P = raw[keep]  # (m+1, n)
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
        # pieces: blend_0, line_0, blend_1, line_1, ..., blend_m (even rows blends, odd rows lines)
        v_in, v_out = vfull[:-1], vfull[1:]  # (m+1, n): the velocity into and out of each corner
        starts = np.empty(2 * m + 1)
        starts[0::2] = tau - tb / 2.0
        starts[1::2] = tau[:-1] + tb / 2.0
        ps, vs, accs = np.empty((2 * m + 1, n)), np.empty((2 * m + 1, n)), np.zeros((2 * m + 1, n))
        ps[0::2], vs[0::2], accs[0::2] = C - v_in * tb / 2.0, v_in, (v_out - v_in) / tb
        ps[1::2], vs[1::2] = C[:-1] + v_out[:-1] * tb / 2.0, v_out[:-1]
        self._starts, self._p, self._v, self._a = starts, ps, vs, accs

    @staticmethod
    def _corners(P: np.ndarray, d: np.ndarray, tb: float) -> np.ndarray:
        """The line corners: the tridiagonal system of the module docstring, for all joints at
        once (its coefficients are shared), by elimination (Thomas): O(m)."""
        m = P.shape[0] - 1
        C = P.copy()
        if m < 2:
            return C
        k_in = m - 1
        alpha = tb / (8.0 * d[:-1])  # sub-diagonal of row i (k = i + 1): the segment before the via
        gamma = tb / (8.0 * d[1:])  # super-diagonal: the segment after it
        diag = 1.0 - alpha - gamma
        rhs = P[1:m].copy()
        rhs[0] -= alpha[0] * P[0]
        rhs[-1] -= gamma[-1] * P[m]
        # forward elimination (the coefficients are scalars shared by every joint)
        a_, g_, b_ = alpha.tolist(), gamma.tolist(), diag.tolist()
        c_prime = [g_[0] / b_[0]]
        scale = [1.0 / b_[0]]  # 1/denominator of each row
        for i in range(1, k_in):
            scale.append(1.0 / (b_[i] - a_[i] * c_prime[i - 1]))
            c_prime.append(g_[i] * scale[i])
        x = rhs
        x[0] *= scale[0]
        for i in range(1, k_in):
            x[i] = (x[i] - a_[i] * x[i - 1]) * scale[i]
        # back substitution
        for i in range(k_in - 2, -1, -1):
            x[i] -= c_prime[i] * x[i + 1]
        C[1:m] = x
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
