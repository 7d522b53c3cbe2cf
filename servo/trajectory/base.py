"""The common trajectory interface and joint limits."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np

from servo.control.normalize import per_joint
from servo.errors import ServoError


class TrajectoryError(ServoError, ValueError):
    """A trajectory cannot be planned (bad limits, wrong number of joints, bad speed factor)."""


class Sample(NamedTuple):
    """One trajectory sample (arrays of length n): θd rad, ωd rad/s, αd rad/s², ``done`` True once the
    motion has ended (the target is being held)."""

    theta_d: np.ndarray
    omega_d: np.ndarray
    alpha_d: np.ndarray
    done: bool


@runtime_checkable
class Trajectory(Protocol):
    """``sample(t)`` with ``t`` seconds since the trajectory started; ``duration`` s (0 for an
    immediate hold); ``start`` and ``end`` positions (rad)."""

    # read-only for the callers (properties or plain attributes both implement them)
    @property
    def duration(self) -> float: ...
    @property
    def start(self) -> np.ndarray: ...
    @property
    def end(self) -> np.ndarray: ...

    def sample(self, t: float) -> Sample: ...


@dataclass(frozen=True)
class JointLimits:
    """Per-joint planning limits: ``v_max`` rad/s (> 0) and optional ``a_max`` rad/s² (> 0, or None).

    The speed factor of a move scales these as a time scaling: velocities by s, accelerations by s²,
    so the duration becomes exactly duration/s.
    """

    v_max: np.ndarray
    a_max: np.ndarray | None = None

    @classmethod
    def make(cls, n: int, v_max: float | list[float] | np.ndarray,
             a_max: float | list[float] | np.ndarray | None = None) -> JointLimits:
        try:
            v = per_joint("v_max", v_max, n, positive=True)
            a = None if a_max is None else per_joint("a_max", a_max, n, positive=True)
        except ValueError as e:
            raise TrajectoryError(str(e)) from None
        return cls(v, a)

    @property
    def n(self) -> int:
        return int(self.v_max.shape[0])


def check_speed(speed: float) -> float:
    """A speed factor must be in (0, 1] (1 = the joints' maximum allowed velocity)."""
    if not (isinstance(speed, int | float) and 0.0 < float(speed) <= 1.0):
        raise TrajectoryError(f"speed factor {speed!r} must be in (0, 1]; 0.5 makes a move twice as long")
    return float(speed)


def as_positions(name: str, value: np.ndarray | list[float], n: int) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise TrajectoryError(f"{name} must be {n} finite joint angles in rad, got {value!r}")
    return arr
