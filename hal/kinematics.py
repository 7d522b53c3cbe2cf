"""The arm's kinematics: today a 3-DOF (waist, shoulder, elbow) position model.

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
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TypeAlias

import numpy as np

#: A vector of floats: a sequence, or a 1-D numpy array (what the callers mostly pass).
FloatVector: TypeAlias = Sequence[float] | np.ndarray


@dataclass(frozen=True)
class ArmModel:
    """Link lengths (m) and which entries of the joint vector are waist, shoulder, elbow."""

    d1: float = 0.30  #: shoulder height above the base frame (m)
    a2: float = 0.60  #: upper arm, shoulder to elbow (m)
    a3: float = 0.55  #: forearm, elbow to the camera/end effector (m)
    joints: tuple[int, int, int] = (0, 1, 2)

    @classmethod
    def from_table(cls, table: Mapping[str, object]) -> ArmModel:
        """Build from a parameter table (e.g. a rig file's ``[arm]``): keys d1, a2, a3, joints."""
        known = {"d1", "a2", "a3", "joints"}
        unknown = set(table) - known
        if unknown:
            raise ValueError(f"unknown arm parameters {sorted(unknown)}; expected {sorted(known)}")
        kw: dict[str, object] = {k: float(table[k]) for k in ("d1", "a2", "a3") if k in table}  # type: ignore[arg-type]
        if "joints" in table:
            kw["joints"] = tuple(int(j) for j in table["joints"])  # type: ignore[attr-defined]
        arm = cls(**kw)  # type: ignore[arg-type]
        if arm.a2 <= 0 or arm.a3 <= 0:
            raise ValueError(f"arm link lengths must be > 0 (a2={arm.a2}, a3={arm.a3})")
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
