"""The arm's kinematics: one model of the whole arm (waist, shoulder, elbow, the three-axis wrist).

One model of the arm, outside the driver packages so that both the robot side and the
emulators may use it: the emulated vision system (where is the camera?) and the ``vservo``
trajectory object (which joint increments realize an end-effector increment?). It was
``hal.bit3.arm`` (that name stays as an alias for one release). SI units: metres, rad.

Kinematics (joints ``q1, q2, q3`` = ``theta[joints[0..2]]``; other joints — the wrist — do
not move the end effector in this model)::

    r = a2·cos q2 + a3·cos(q2 + q3)              horizontal distance from the waist axis
    p = [r·cos q1, r·sin q1, d1 + a2·sin q2 + a3·sin(q2 + q3)]

    q1: waist yaw about the base z axis (up); q2: shoulder elevation above the horizontal;
    q3: elbow angle relative to the upper arm (0 = straight).

End-effector (camera) frame ``R = [x_e y_e z_e]`` (columns, in base coordinates): ``x_e``
along the forearm (the camera's optical axis, the approach direction), ``y_e`` horizontal to
the left, ``z_e = x_e × y_e``; i.e. ``R = Rz(q1)·Ry(−(q2 + q3))``.

Default lengths give the jpl-arm reach at full extension a2 + a3 = 1.15 m (design §9).

The whole arm (the wrist joints ``q4, q5, q6`` = ``theta[wrist_joints[0..2]]``) — the points the
links join at, the links as line segments (the JPL paper's collision check: "each of these is
represented as a line P = B + λ(F − B)") and the tool point's Jacobian::

    shoulder S = (0, 0, d1)
    elbow    E = S + a2·u(q2)                   u(φ) = (cos φ·cos q1, cos φ·sin q1, sin φ)
    wrist    W = E + a3·u(q2 + q3)              (= position(): the camera, the forearm's end)
    R_w = Rz(q1)·Ry(−(q2 + q3 + q4))·Rx(q5)      q4 wrist pitch, q5 wrist roll about the hand's axis
    yaw      Y = W + a5·R_w·x̂                   the wrist yaw axis (R_w·ẑ) sits a5 beyond the wrist
    tool     T = Y + a6·R_w·Rz(q6)·x̂            q6 wrist yaw; T the fingertips

    links: upper_arm S→E, forearm E→W, wrist W→Y, hand Y→T
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeAlias

import numpy as np

from hal.config import ConfigTable

#: A vector of floats: a sequence, or a 1-D numpy array (what the callers mostly pass).
FloatVector: TypeAlias = Sequence[float] | np.ndarray

#: no link is longer than this (m): a sanity bound on the rig file, not a design limit
MAX_LENGTH_M = 100.0

#: the links as line segments, each from the point named first to the second (:meth:`ArmModel.segments`)
LINKS: tuple[tuple[str, str, str], ...] = (
    ("upper_arm", "shoulder", "elbow"),
    ("forearm", "elbow", "wrist"),
    ("wrist", "wrist", "yaw"),
    ("hand", "yaw", "tool"),
)


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _ry(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def segment_box_span(p0: FloatVector, p1: FloatVector, lo: FloatVector, hi: FloatVector) -> tuple[float, float] | None:
    """The part of the segment ``P = p0 + λ(p1 − p0)``, λ ∈ [0, 1], inside the axis-aligned box
    ``lo ≤ P ≤ hi`` (closed), as its ``(λ_in, λ_out)``; ``None`` when the segment misses the box.

    The JPL paper's test, dimension by dimension: each axis limits λ to the values that put that
    coordinate inside the box; the segment collides when some λ in [0, 1] satisfies all three."""
    a = np.asarray(p0, float)
    d = np.asarray(p1, float) - a
    lam_in, lam_out = 0.0, 1.0
    for j in range(3):
        lo_j, hi_j = float(lo[j]), float(hi[j])
        if d[j] == 0.0:
            if not lo_j <= a[j] <= hi_j:
                return None
            continue
        t0, t1 = (lo_j - a[j]) / d[j], (hi_j - a[j]) / d[j]
        if t0 > t1:
            t0, t1 = t1, t0
        lam_in, lam_out = max(lam_in, float(t0)), min(lam_out, float(t1))
        if lam_in > lam_out:
            return None
    return lam_in, lam_out


@dataclass(frozen=True)
class ArmModel:
    """Link lengths (m) and which entries of the joint vector are waist, shoulder, elbow."""

    d1: float = 0.30  #: shoulder height above the base frame (m)
    a2: float = 0.60  #: upper arm, shoulder to elbow (m)
    a3: float = 0.55  #: forearm, elbow to the camera/end effector (m)
    joints: tuple[int, int, int] = (0, 1, 2)
    a5: float = 0.10  #: wrist, the pitch/roll centre to the yaw axis (m)
    a6: float = 0.15  #: hand, the yaw axis to the fingertips (m)
    wrist_joints: tuple[int, int, int] = (3, 4, 5)  #: wrist pitch, roll, yaw

    @classmethod
    def from_table(cls, table: Mapping[str, object] | ConfigTable, source: str = "[arm]") -> ArmModel:
        """Build from a parameter table (a rig file's ``[arm]``): keys d1, a2, a3, a5, a6 (m),
        joints, wrist_joints (0-based joint indices). Errors are :class:`hal.config.ConfigError`
        (a ``ValueError``) naming the key."""
        cfg = table if isinstance(table, ConfigTable) else ConfigTable(dict(table), source, "arm")
        cfg.check_unknown({"d1", "a2", "a3", "a5", "a6", "joints", "wrist_joints"})
        kw: dict[str, Any] = {}
        for k in ("d1", "a2", "a3", "a5", "a6"):
            if k in cfg:
                kw[k] = cfg.get_float(k, min=0.0 if k in ("d1", "a5", "a6") else 1e-6, max=MAX_LENGTH_M)
        for k in ("joints", "wrist_joints"):
            if k in cfg:
                raw = cfg.raw(k)
                if (not isinstance(raw, list) or len(raw) != 3
                        or not all(isinstance(j, int) and not isinstance(j, bool) and 0 <= j < 64 for j in raw)):
                    raise cfg.error(k, "three 0-based joint indices", raw)
                kw[k] = tuple(raw)
        if "joints" in kw and "wrist_joints" not in kw:  # the wrist follows the elbow
            last = kw["joints"][2]
            kw["wrist_joints"] = (last + 1, last + 2, last + 3)
        arm = cls(**kw)
        if len({*arm.joints, *arm.wrist_joints}) != 6:
            raise cfg.error("wrist_joints", f"joints other than joints = {list(arm.joints)}, each once",
                            list(arm.wrist_joints))
        return arm

    @property
    def reach(self) -> float:
        """Distance from the shoulder to the end effector at full extension (m)."""
        return self.a2 + self.a3

    def _q(self, theta: FloatVector) -> tuple[float, float, float]:
        return (float(theta[self.joints[0]]), float(theta[self.joints[1]]), float(theta[self.joints[2]]))

    def position(self, theta: FloatVector) -> np.ndarray:
        """End-effector position in the base frame (m)."""
        q1, q2, q3 = self._q(theta)
        r = self.a2 * np.cos(q2) + self.a3 * np.cos(q2 + q3)
        h = self.d1 + self.a2 * np.sin(q2) + self.a3 * np.sin(q2 + q3)
        return np.array([r * np.cos(q1), r * np.sin(q1), h])

    def rotation(self, theta: FloatVector) -> np.ndarray:
        """End-effector (camera) orientation: columns x_e, y_e, z_e in base coordinates."""
        q1, q2, q3 = self._q(theta)
        c1, s1, c23, s23 = np.cos(q1), np.sin(q1), np.cos(q2 + q3), np.sin(q2 + q3)
        x = np.array([c23 * c1, c23 * s1, s23])
        y = np.array([-s1, c1, 0.0])
        return np.column_stack([x, y, np.cross(x, y)])

    def _wrist_q(self, theta: FloatVector) -> tuple[float, float, float]:
        w = self.wrist_joints
        return (float(theta[w[0]]), float(theta[w[1]]), float(theta[w[2]]))

    def wrist_rotation(self, theta: FloatVector) -> np.ndarray:
        """``R_w = Rz(q1)·Ry(−(q2 + q3 + q4))·Rx(q5)``: the hand's frame before the yaw (x̂ its axis)."""
        q1, q2, q3 = self._q(theta)
        q4, q5, _ = self._wrist_q(theta)
        return _rz(q1) @ _ry(-(q2 + q3 + q4)) @ _rx(q5)

    def points(self, theta: FloatVector) -> dict[str, np.ndarray]:
        """The points the links join at, in the base frame (m): shoulder, elbow, wrist, yaw, tool."""
        q1, q2, q3 = self._q(theta)
        q6 = self._wrist_q(theta)[2]

        def u(phi: float) -> np.ndarray:
            return np.array([np.cos(phi) * np.cos(q1), np.cos(phi) * np.sin(q1), np.sin(phi)])

        s = np.array([0.0, 0.0, self.d1])
        e = s + self.a2 * u(q2)
        w = e + self.a3 * u(q2 + q3)
        rw = self.wrist_rotation(theta)
        y = w + self.a5 * rw[:, 0]
        t = y + self.a6 * (rw @ _rz(q6))[:, 0]
        return {"shoulder": s, "elbow": e, "wrist": w, "yaw": y, "tool": t}

    def segments(self, theta: FloatVector) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """The links as line segments ``(name, from, to)`` (m, base frame), in :data:`LINKS` order."""
        p = self.points(theta)
        return [(name, p[a], p[b]) for name, a, b in LINKS]

    def tool_position(self, theta: FloatVector) -> np.ndarray:
        """The fingertips' position in the base frame (m)."""
        return self.points(theta)["tool"]

    def tool_jacobian(self, theta: FloatVector) -> np.ndarray:
        """3×len(theta) position Jacobian of the tool point ∂T/∂θ (m/rad); columns of joints the
        model does not hold (the hand's fingers) are 0. Each revolute joint's column is its axis ×
        (T − a point on the axis)."""
        p = self.points(theta)
        q1 = self._q(theta)[0]
        rw = self.wrist_rotation(theta)
        pitch = _rz(q1) @ np.array([0.0, -1.0, 0.0])  # q2..q4 raise the arm: about −y of the waist frame
        axes = ((self.joints[0], np.array([0.0, 0.0, 1.0]), np.zeros(3)),
                (self.joints[1], pitch, p["shoulder"]), (self.joints[2], pitch, p["elbow"]),
                (self.wrist_joints[0], pitch, p["wrist"]), (self.wrist_joints[1], rw[:, 0], p["wrist"]),
                (self.wrist_joints[2], rw[:, 2], p["yaw"]))
        out = np.zeros((3, len(theta)))
        for j, axis, at in axes:
            out[:, j] = np.cross(axis, p["tool"] - at)
        return out

    def pose(self, theta: FloatVector) -> tuple[np.ndarray, np.ndarray]:
        """(position, rotation) of the end effector."""
        return self.position(theta), self.rotation(theta)

    def jacobian(self, theta: FloatVector) -> np.ndarray:
        """3×3 position Jacobian ∂p/∂(q1, q2, q3) in the base frame (m/rad)."""
        q1, q2, q3 = self._q(theta)
        c1, s1 = np.cos(q1), np.sin(q1)
        r = self.a2 * np.cos(q2) + self.a3 * np.cos(q2 + q3)
        dr2 = -self.a2 * np.sin(q2) - self.a3 * np.sin(q2 + q3)
        dr3 = -self.a3 * np.sin(q2 + q3)
        dh2 = self.a2 * np.cos(q2) + self.a3 * np.cos(q2 + q3)
        dh3 = self.a3 * np.cos(q2 + q3)
        return np.array([
            [-r * s1, dr2 * c1, dr3 * c1],
            [r * c1, dr2 * s1, dr3 * s1],
            [0.0, dh2, dh3],
        ])

    def ee_delta_to_joint_delta(
        self, theta: FloatVector, dxyz: FloatVector, *, frame: str = "ee", damping: float = 0.02
    ) -> np.ndarray:
        """Joint increments (rad, same length as ``theta``) for an end-effector translation.

        Damped least squares: ``dq = Jᵀ (J Jᵀ + λ² I)⁻¹ dx`` with ``λ = damping`` (m), which
        stays bounded near singularities (full extension, the waist axis). ``frame="ee"``
        takes ``dxyz`` in the end-effector (camera) frame, as the vision system sends it;
        ``"base"`` in the base frame. Joints outside ``self.joints`` get 0.
        """
        dx = np.asarray(dxyz, dtype=float).reshape(3)
        if frame == "ee":
            dx = self.rotation(theta) @ dx
        elif frame != "base":
            raise ValueError(f"frame must be 'ee' or 'base', not {frame!r}")
        J = self.jacobian(theta)
        dq3 = J.T @ np.linalg.solve(J @ J.T + damping**2 * np.eye(3), dx)
        out = np.zeros(len(theta))
        for i, j in enumerate(self.joints):
            out[j] = dq3[i]
        return out

    def inverse(self, p: FloatVector, theta0: FloatVector, *, iterations: int = 100,
                tol: float = 1e-9) -> np.ndarray:
        """Joint angles reaching ``p`` (m, base frame), by damped-least-squares iteration from
        ``theta0`` (elbow branch chosen by the start). Raises ``ValueError`` if out of reach."""
        theta = np.array(theta0, dtype=float)
        target = np.asarray(p, dtype=float)
        for _ in range(iterations):
            err = target - self.position(theta)
            if np.linalg.norm(err) < tol:
                return theta
            theta += self.ee_delta_to_joint_delta(theta, err, frame="base", damping=1e-3)
        raise ValueError(f"point {target.tolist()} not reached (reach {self.reach:.3f} m from the shoulder)")
