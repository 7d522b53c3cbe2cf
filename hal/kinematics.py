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

Inverse kinematics of the tool point and the hand's orientation (:meth:`ArmModel.solve`), in closed
form: the hand's frame ``R_h = R_w·Rz(q6) = Rz(q1)·Ry(−φ)·Rx(q5)·Rz(q6)`` with ``φ = q2 + q3 + q4``,
and ``R_w·x̂ = Rz(q1)·Ry(−φ)·x̂`` (the roll does not move the hand's axis), so the yaw point
``Y = T − a6·R_h·x̂`` lies in the waist's vertical plane: ``q1 = atan2(Y_y, Y_x)`` (or that + π);
``Rz(−q1)·R_h = Ry(−φ)·Rx(q5)·Rz(q6)`` gives φ, q5, q6 (two branches, cos q5 ≷ 0);
``W = Y − a5·u(φ)`` and the planar two-link solution gives q2, q3 (elbow up/down); q4 = φ − q2 − q3.
Up to eight solutions; :meth:`ArmModel.solve` takes the one within the soft limits nearest the start.
Singular where the arm loses a direction: the elbow straight or folded (q3 = 0, ±180°: the edge of
the workspace), the wrist on the waist axis (r = 0), the wrist roll at ±90° (the yaw axis parallel
to the pitch axis).
"""

from __future__ import annotations

import math
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


def rotation_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """The rotation ``Rz(yaw)·Ry(pitch)·Rx(roll)`` (URDF's roll-pitch-yaw about the fixed base axes).
    For the hand: x̂ its approach vector; pitch +90° points it straight down, yaw turns it about z."""
    return _rz(yaw_rad) @ _ry(pitch_rad) @ _rx(roll_rad)


def rpy_of(rotation: np.ndarray) -> tuple[float, float, float]:
    """``(roll, pitch, yaw)`` (rad) of a rotation, the inverse of :func:`rotation_rpy`
    (pitch in [−90°, 90°])."""
    r = np.asarray(rotation, float)
    pitch = math.asin(max(-1.0, min(1.0, -float(r[2, 0]))))
    if abs(math.cos(pitch)) < 1e-9:  # gimbal lock: roll and yaw share an axis; all in yaw
        return 0.0, pitch, math.atan2(-float(r[0, 1]), float(r[1, 1]))
    return math.atan2(float(r[2, 1]), float(r[2, 2])), pitch, math.atan2(float(r[1, 0]), float(r[0, 0]))


def rotation_angle(r0: np.ndarray, r1: np.ndarray) -> float:
    """The angle (rad) of the rotation taking ``r0`` to ``r1``."""
    c = (float(np.trace(np.asarray(r0, float).T @ np.asarray(r1, float))) - 1.0) / 2.0
    return math.acos(max(-1.0, min(1.0, c)))


def slerp(r0: np.ndarray, r1: np.ndarray, s: float) -> np.ndarray:
    """The rotation a fraction ``s`` of the way from ``r0`` to ``r1`` about one fixed axis (the
    shortest way): ``r0·exp(s·log(r0ᵀ·r1))``."""
    a, b = np.asarray(r0, float), np.asarray(r1, float)
    rel = a.T @ b
    angle = rotation_angle(a, b)
    if angle < 1e-12:
        return a.copy()
    if math.pi - angle < 1e-6:  # half a turn: the axis from the symmetric part
        m = (rel + np.eye(3)) / 2.0
        axis = m[:, int(np.argmax(np.diag(m)))]
    else:
        axis = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    th = s * angle
    return a @ (np.eye(3) + math.sin(th) * k + (1.0 - math.cos(th)) * (k @ k))


def _wrap_near(q: float, ref: float) -> float:
    """``q + 2πk`` nearest ``ref``."""
    return q + 2.0 * math.pi * round((ref - q) / (2.0 * math.pi))


#: a configuration this close (rad) to a singular one is singular: the elbow straight or folded, the
#: wrist roll at ±90° (near one, a Cartesian path needs joint speeds without bound)
SINGULAR_ANGLE_RAD = math.radians(2.0)
#: the wrist point this close (m) to the waist axis is singular (the waist's turn moves it not at all)
SINGULAR_RADIUS_M = 0.02
#: a closed-form solution is checked through the forward kinematics to this (m, rad)
IK_CHECK_TOLERANCE = 1e-7


@dataclass(frozen=True)
class IkResult:
    """What :meth:`ArmModel.solve` found. ``reachable``: a solution within the soft limits exists
    (``theta``, the whole joint vector, rad); else ``reason`` says why (``"beyond reach: …"``,
    ``"inside the arm's inner reach: …"``, ``"past the soft limits: …"``, ``limit_joint`` then the
    index of the joint that stops the nearest solution). ``singular`` and ``singularity`` (its name),
    ``manipulability`` (m³: |det| of the Jacobian of the three joints nearest the base, the (DM)²
    measure, ``a2·a3·|sin q3|·r``) and ``wrist_manipulability`` (``|cos q5|``, 0 at the wrist's
    singularity) describe the solution (0 when there is none)."""

    reachable: bool
    theta: np.ndarray | None
    reason: str = ""
    singular: bool = False
    singularity: str = ""
    manipulability: float = 0.0
    wrist_manipulability: float = 0.0
    limit_joint: int | None = None


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

    # --- inverse kinematics (the tool point and the hand's orientation) ---------------------------
    def hand_rotation(self, theta: FloatVector) -> np.ndarray:
        """The hand's frame ``R_w·Rz(q6)`` in the base frame: x̂ the approach vector (the yaw axis
        to the fingertips), ẑ the yaw axis."""
        return self.wrist_rotation(theta) @ _rz(self._wrist_q(theta)[2])

    @staticmethod
    def default_hand_rotation(position: FloatVector) -> np.ndarray:
        """The default hand orientation (our choice: the JPL paper names a default, not which): the
        hand level, pointing away from the waist axis through the target (roll 0, pitch 0, yaw =
        the target's azimuth; yaw 0 on the axis)."""
        x, y = float(position[0]), float(position[1])
        return rotation_rpy(0.0, 0.0, math.atan2(y, x) if math.hypot(x, y) > 1e-12 else 0.0)

    def singularity(self, theta: FloatVector) -> tuple[str, float, float]:
        """``(name, manipulability, wrist_manipulability)`` at ``theta``: the name of the singularity
        it is within :data:`SINGULAR_ANGLE_RAD` / :data:`SINGULAR_RADIUS_M` of (``""``: none)."""
        _, q2, q3 = self._q(theta)
        q5 = self._wrist_q(theta)[1]
        r = self.a2 * math.cos(q2) + self.a3 * math.cos(q2 + q3)
        manip = self.a2 * self.a3 * abs(math.sin(q3)) * abs(r)
        wrist = abs(math.cos(q5))
        if abs(math.sin(q3)) < math.sin(SINGULAR_ANGLE_RAD):
            name = "the elbow straight (the edge of the workspace)" if math.cos(q3) > 0 else "the elbow folded"
        elif abs(r) < SINGULAR_RADIUS_M:
            name = "the wrist on the waist axis"
        elif wrist < math.sin(SINGULAR_ANGLE_RAD):
            name = "the wrist roll at ±90° (the yaw axis parallel to the pitch axis)"
        else:
            name = ""
        return name, manip, wrist

    def crosses_singularity(self, theta_a: FloatVector, theta_b: FloatVector) -> str:
        """The singularity a move from ``theta_a`` to the nearby ``theta_b`` passes through (its
        name; ``""``: none): the elbow's sin q3, the wrist's distance from the waist axis r (signed)
        or the wrist's cos q5 changing sign between them — a crossing that samples on either side
        of a singularity, each outside its band, would miss."""
        qa, qb = self._q(theta_a), self._q(theta_b)
        ra = self.a2 * math.cos(qa[1]) + self.a3 * math.cos(qa[1] + qa[2])
        rb = self.a2 * math.cos(qb[1]) + self.a3 * math.cos(qb[1] + qb[2])
        if math.sin(qa[2]) * math.sin(qb[2]) < 0.0:
            return "the elbow straight (the edge of the workspace)" if math.cos(qa[2]) > 0 else "the elbow folded"
        if ra * rb < 0.0:
            return "the wrist on the waist axis"
        if math.cos(self._wrist_q(theta_a)[1]) * math.cos(self._wrist_q(theta_b)[1]) < 0.0:
            return "the wrist roll at ±90° (the yaw axis parallel to the pitch axis)"
        return ""

    def ik_candidates(self, position: FloatVector, rotation: np.ndarray) -> tuple[list[tuple[float, ...]], float]:
        """Every closed-form solution ``(q1, …, q6)`` putting the tool at ``position`` with the hand's
        frame ``rotation`` (see the module docstring), and the wrist point's smallest distance from
        the shoulder among the candidates out of reach (0 when none is)."""
        p = np.asarray(position, float).reshape(3)
        rot = np.asarray(rotation, float)
        yp = p - self.a6 * rot[:, 0]
        base = math.atan2(float(yp[1]), float(yp[0])) if math.hypot(float(yp[0]), float(yp[1])) > 1e-12 else 0.0
        out: list[tuple[float, ...]] = []
        far = math.inf
        for q1 in (base, base + math.pi):
            m = _rz(-q1) @ rot  # = Ry(−φ)·Rx(q5)·Rz(q6)
            c5 = math.asin(max(-1.0, min(1.0, -float(m[1, 2]))))
            for q5, sgn in ((c5, 1.0), (math.pi - c5, -1.0)):
                b = math.atan2(sgn * float(m[0, 2]), sgn * float(m[2, 2]))
                q6 = math.atan2(sgn * float(m[1, 0]), sgn * float(m[1, 1]))
                phi = -b
                c1, s1 = math.cos(q1), math.sin(q1)
                w = yp - self.a5 * np.array([math.cos(phi) * c1, math.cos(phi) * s1, math.sin(phi)])
                r = float(w[0]) * c1 + float(w[1]) * s1
                h = float(w[2]) - self.d1
                d = (r * r + h * h - self.a2 ** 2 - self.a3 ** 2) / (2.0 * self.a2 * self.a3)
                if abs(d) > 1.0 + 1e-12:
                    far = min(far, math.hypot(r, h))
                    continue
                d = max(-1.0, min(1.0, d))
                for q3 in {math.acos(d), -math.acos(d)}:
                    q2 = math.atan2(h, r) - math.atan2(self.a3 * math.sin(q3), self.a2 + self.a3 * math.cos(q3))
                    out.append((q1, q2, q3, phi - q2 - q3, q5, q6))
        return out, (0.0 if math.isinf(far) else far)

    def solve(self, position: FloatVector, rotation: np.ndarray | None = None, *, theta0: FloatVector,
              min_rad: FloatVector | None = None, max_rad: FloatVector | None = None) -> IkResult:
        """Joint angles putting the tool point at ``position`` (m, base frame) with the hand's frame
        ``rotation`` (``None``: :meth:`default_hand_rotation`), within ``min_rad``..``max_rad`` (the
        soft limits, whole joint vectors; ``None``: none); of the solutions, the one nearest
        ``theta0`` (the start: its other joints, the hand's, are kept). See :class:`IkResult`."""
        p = np.asarray(position, float).reshape(3)
        rot = self.default_hand_rotation(p) if rotation is None else np.asarray(rotation, float)
        th0 = np.asarray(theta0, float)
        n = len(th0)
        lo = np.full(n, -np.inf) if min_rad is None else np.asarray(min_rad, float)
        hi = np.full(n, np.inf) if max_rad is None else np.asarray(max_rad, float)
        idx = (*self.joints, *self.wrist_joints)
        cands, far = self.ik_candidates(p, rot)
        best: tuple[float, np.ndarray] | None = None
        nearest_bad: tuple[int, float, int] | None = None  # (joints past a limit, excess, the worst joint)
        for cand in cands:
            theta = th0.copy()
            for j, q in zip(idx, cand, strict=True):
                q = _wrap_near(q, float(th0[j]))
                if q > hi[j]:
                    q -= 2.0 * math.pi * math.ceil((q - hi[j]) / (2.0 * math.pi))
                elif q < lo[j]:
                    q += 2.0 * math.pi * math.ceil((lo[j] - q) / (2.0 * math.pi))
                theta[j] = q
            if (np.linalg.norm(self.tool_position(theta) - p) > IK_CHECK_TOLERANCE
                    or rotation_angle(self.hand_rotation(theta), rot) > IK_CHECK_TOLERANCE):
                continue  # a branch at a numerical edge: not a solution
            excess = np.zeros(n)  # the joints the solution sets (the hand's stay as they are)
            excess[list(idx)] = (np.maximum(lo - theta, 0.0) + np.maximum(theta - hi, 0.0))[list(idx)]
            if np.any(excess > 1e-9):
                bad = (int(np.count_nonzero(excess > 1e-9)), float(np.sum(excess)), int(np.argmax(excess)))
                if nearest_bad is None or bad[:2] < nearest_bad[:2]:
                    nearest_bad = bad
                continue
            dist = float(np.sum((theta - th0) ** 2))
            if best is None or dist < best[0]:
                best = (dist, theta)
        if best is None:
            if nearest_bad is not None:
                j = nearest_bad[2]
                why = " (the orientation is outside the wrist's range)" if j in self.wrist_joints else ""
                return IkResult(False, None, f"past the soft limits: every solution puts a joint past its limit, "
                                             f"the nearest joint index {j}{why}", limit_joint=j)
            dist = far if far > 0.0 else float("nan")
            if dist >= self.reach:
                return IkResult(False, None, f"beyond reach: the wrist {dist:.3f} m from the shoulder, the arm "
                                             f"reaches {self.reach:.3f} m")
            return IkResult(False, None, f"inside the arm's inner reach: the wrist {dist:.3f} m from the shoulder, "
                                         f"nearer than {abs(self.a2 - self.a3):.3f} m")
        theta = best[1]
        name, manip, wrist = self.singularity(theta)
        return IkResult(True, theta, "", bool(name), name, manip, wrist)
