"""The hand's current-command mode: "the 'hand' servo loop is driven by a fixed current command"
(the JPL paper). ``open``, ``close`` and ``squeeze`` set the hand joint's motor current; the
position law no longer drives that joint (its desired position follows the measured one, so its
integrators do not wind up and its following error stays 0) until the loop is resumed from a stop
(:meth:`servo.loop.ServoLoop.resume`: the hand is then held where it is, by position again).

Near its soft limits the current stops pushing: within :data:`LIMIT_ZONE_RAD` of the soft limit it
drives towards, the hand is held *at* that limit by position (its desired position becomes the
limit), so a close on nothing ends with the fingers at the soft minimum (2° on jpl-arm: the pot's
"closed on nothing") and an open at the soft maximum — the soft-limit watchdog never trips on a
hand doing what it was told. Between them nothing but the object stops the fingers: a close
stops on contact, a squeeze presses harder. The fingers' speed is governed: above
:data:`MAX_SPEED_RAD_S` the current is withheld for the tick (the fingers coast), so that the
position law can take them at the limit zone without an overshoot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hal.hand import GRAVITY_M_S2
from servo.errors import ServoError
from servo.trajectory.stay import Stay

__all__ = ["ACTIONS", "DEFAULT_CURRENT_A", "HandCurrent", "HandError", "HandStay", "MassEstimate", "TorqueWindow",
           "check_grasp", "estimate_mass"]

#: action → direction of the current (+ opens: the hand angle grows with the gap)
ACTIONS = {"open": 1.0, "close": -1.0, "squeeze": -1.0}
#: the hand is held at a soft limit by position within this of it (rad)
LIMIT_ZONE_RAD = math.radians(3.0)
#: [assumed] the fingers' top speed under a current command (rad/s): the gap closes at 50 mm/s
#: on jpl-arm (0.1 m/rad), a careful approach to an object
MAX_SPEED_RAD_S = 0.5
#: the hand is at rest below this speed (rad/s): the holding-torque window restarts while it moves
REST_SPEED_RAD_S = 0.02
#: [assumed] the currents of open and close (A): enough to overcome the gearhead's friction
#: (0.0015 N·m breakout at the motor ≈ 0.15 A on jpl-arm's hand) with margin, a light grip
DEFAULT_CURRENT_A = {"open": 0.5, "close": 0.5, "squeeze": 1.0}


class HandError(ServoError, ValueError):
    """A hand command that cannot be carried out as given (an unknown action, a bad current)."""


@dataclass(frozen=True)
class HandCurrent:
    """The hand ``joint`` driven at ``current_a`` (A, ≥ 0) in the direction of ``action``."""

    joint: int
    action: str
    current_a: float

    @classmethod
    def make(cls, joint: int, action: str, current_a: float | None, limit_a: float) -> HandCurrent:
        """A checked command: ``current_a`` ``None`` takes the action's default; at most ``limit_a``."""
        if action not in ACTIONS:
            raise HandError(f"hand action {action!r}: use one of {', '.join(ACTIONS)}")
        amps = DEFAULT_CURRENT_A[action] if current_a is None else float(current_a)
        if not (math.isfinite(amps) and 0.0 < amps <= limit_a):
            raise HandError(f"hand current {amps!r} A: more than 0 and at most the amplifier's limit {limit_a:g} A")
        return cls(joint, action, amps)

    @property
    def signed_a(self) -> float:
        """The current with its direction (A; + opens)."""
        return ACTIONS[self.action] * self.current_a

    def limit_hold(self, theta_rad: float, soft_min_rad: float, soft_max_rad: float) -> float | None:
        """The soft limit (rad) to hold the hand at, once within :data:`LIMIT_ZONE_RAD` of the one
        it drives towards; ``None``: not there."""
        if self.signed_a < 0.0 and theta_rad <= soft_min_rad + LIMIT_ZONE_RAD:
            return soft_min_rad
        if self.signed_a > 0.0 and theta_rad >= soft_max_rad - LIMIT_ZONE_RAD:
            return soft_max_rad
        return None

    def current_at(self, omega_rad_s: float) -> float:
        """The current (A) to command with the hand moving at ``omega_rad_s``: withheld (0) while
        it runs faster than :data:`MAX_SPEED_RAD_S` in the driven direction."""
        i = self.signed_a
        if math.isfinite(omega_rad_s) and omega_rad_s * math.copysign(1.0, i) > MAX_SPEED_RAD_S:
            return 0.0
        return i


class HandStay(Stay):
    """A motion file's hand move as the sequencer plays it: the arm holds its target for
    ``duration`` s while the loop drives the hand by ``action`` at ``current_a`` (``None``: the
    action's default) from the move's first tick (:meth:`servo.loop.ServoLoop.tick`)."""

    def __init__(self, position: np.ndarray, duration: float, action: str, current_a: float | None) -> None:
        super().__init__(position, duration)
        self.hand_action = action
        self.hand_current_a = current_a


class TorqueWindow:
    """The arm's holding torques as the current monitors measure them, over the last ``size``
    ticks with the hand at rest (N·m at the joints: imon amperes · N · Kt, the nominal chain): it
    restarts whenever the hand moves, so that a full window after a close holds only the object's
    load. ``weigh`` compares two such means, without and with the object."""

    def __init__(self, torque_per_a: np.ndarray, size: int) -> None:
        self.torque_per_a = np.asarray(torque_per_a, float)
        self.size = int(size)
        self._buf = np.zeros((self.size, self.torque_per_a.shape[0]))
        self.count = 0
        #: the window's mean, its standard error and the joint angles when the hand began to close
        #: on the object (``None``: not yet): what the holding torques were without it
        self.baseline: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def mark_baseline(self, theta: np.ndarray) -> bool:
        """Keep the present mean as the baseline (when the window is full); True if kept."""
        if not self.full:
            self.baseline = None
            return False
        self.baseline = (self.mean(), self.std_of_mean(), np.asarray(theta, float).copy())
        return True

    def add(self, current_a: np.ndarray, hand_speed_rad_s: float = 0.0) -> None:
        """One tick's measured currents (A) and the hand's speed; a tick with a non-finite
        current is skipped, a moving hand restarts the window."""
        if not abs(hand_speed_rad_s) < REST_SPEED_RAD_S:  # (a non-finite speed too)
            self.count = 0
            return
        c = np.asarray(current_a, float)
        if not np.all(np.isfinite(c)):
            return
        self._buf[self.count % self.size] = c * self.torque_per_a
        self.count += 1

    @property
    def full(self) -> bool:
        return self.count >= self.size

    def mean(self) -> np.ndarray:
        """Mean torque per joint over the window (N·m)."""
        k = min(self.count, self.size)
        return np.asarray(self._buf[:k].mean(axis=0), float)

    def std_of_mean(self) -> np.ndarray:
        """The standard error of :meth:`mean` per joint (N·m), from the samples' scatter
        (taken as independent: the imon noise is white at the tick rate)."""
        k = min(self.count, self.size)
        return np.asarray(self._buf[:k].std(axis=0, ddof=1) / np.sqrt(k), float)


@dataclass(frozen=True)
class MassEstimate:
    """``mass_kg`` ± ``uncertainty_kg`` (one standard deviation) from ``joints`` joints."""

    mass_kg: float
    uncertainty_kg: float
    joints: int


def estimate_mass(delta_torque_nm: np.ndarray, jacobian: np.ndarray, sigma_nm: np.ndarray,
                  joints: Sequence[int]) -> MassEstimate:
    """The held mass from the change of the holding torques when the object came on.

    The object's weight ``F = (0, 0, −m·g)`` at the tool point loads joint j with ``(Jᵀ·F)_j``;
    the servo holds it with the opposite torque, so ``Δτ_j = m·a_j``, ``a_j = g·J_zj`` (the z row
    of the tool point's Jacobian). Weighted least squares over ``joints`` with the per-joint
    standard deviations ``sigma_nm``: ``m = Σ(a·Δτ/σ²) / Σ(a²/σ²)``, ``σ_m = 1/√Σ(a²/σ²)``."""
    idx = list(joints)
    a = GRAVITY_M_S2 * np.asarray(jacobian, float)[2, idx]
    dt = np.asarray(delta_torque_nm, float)[idx]
    w = 1.0 / np.square(np.asarray(sigma_nm, float)[idx])
    info = float(np.sum(a * a * w))
    if not info > 0.0:
        raise HandError("weigh: in this pose no joint feels a vertical force at the tool point")
    return MassEstimate(float(np.sum(a * dt * w)) / info, 1.0 / math.sqrt(info), len(idx))


def check_grasp(gap_m: float, switches: Sequence[bool], tolerance_m: float, width_m: float | None = None) -> str | None:
    """The JPL paper's check "that an object of approximately the anticipated size has been
    grasped", by the finger tactile switches and the hand pot: ``None`` when they agree, else why
    not. ``gap_m``: the fingertip gap the hand pot reads; ``switches``: each finger's switch
    (closed = True); ``width_m``: the anticipated object's width (``None``: any object)."""
    closed = [bool(s) for s in switches]
    if closed and not all(closed) and any(closed):
        return ("the tactile switches disagree (" + ", ".join("closed" if c else "open" for c in closed)
                + f") with the fingers {gap_m * 1e3:.1f} mm apart")
    if closed and all(closed):
        if gap_m <= tolerance_m:
            return f"the switches are closed but the hand pot says the fingers are shut ({gap_m * 1e3:.1f} mm)"
        if width_m is not None and abs(gap_m - width_m) > tolerance_m:
            side = "wider" if gap_m > width_m else "narrower"
            return (f"the switches are closed but the hand pot says the fingers are {gap_m * 1e3:.1f} mm apart, "
                    f"{side} than the object ({width_m * 1e3:.1f} mm) by more than {tolerance_m * 1e3:.1f} mm")
        return None
    if gap_m <= tolerance_m:
        return f"the hand pot says closed on nothing ({gap_m * 1e3:.1f} mm) and the switches are open"
    return f"no contact: the switches are open with the fingers {gap_m * 1e3:.1f} mm apart"
