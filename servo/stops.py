"""Stop categories (IEC 60204-1 §9.2.2, ISO 13850 vocabulary): how the loop stops for each cause.

* **Category 0** — power removed at once: amplifiers disabled, DACs 0 V, PWM off, holding-brake
  lines low (the brakes hold one engage delay later). For the causes where the controller can no
  longer trust its sensors, its drivers or its own code: a controlled deceleration would be
  steered by what failed.
* **Category 1** — a controlled deceleration to rest within the joints' limits (the amplifiers
  still servo), then the holding brakes engaged while the amplifiers still hold (one engage delay),
  then power removed as in category 0. For the causes where sensors and drivers are still sane:
  the operator's stop, the end of a run, an overrun, a signal.
* **Category 2** — a controlled stop with power kept: the joints held where they are (the
  console's ``stay``).

A category-1 stop that cannot complete — a fault during it, or past its time bound — falls to
category 0. A rig file may make a cause's category stricter (a lower number), never looser
(``[servo.stop_categories]``, parsed in :mod:`servo.settings`). The table with the reason per
row is in docs/safe-stop.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from servo.trajectory.base import Sample

__all__ = ["CATEGORIES", "NOT_FAULTS", "ControlledStop", "Deceleration", "HoldingLoad", "StopCategory", "StopSettings",
           "category_for"]


class StopCategory(IntEnum):
    """IEC 60204-1's stop categories."""

    UNCONTROLLED = 0  #: power off at once
    CONTROLLED = 1  #: decelerate, brakes, then power off
    HOLDING = 2  #: decelerate and hold, power kept


#: cause → (category, why). Causes not listed are category 0 (the stricter default).
CATEGORIES: Mapping[str, tuple[StopCategory, str]] = {
    "implausible_sensor": (StopCategory.UNCONTROLLED, "a sensor reads what cannot be: it cannot steer a deceleration"),
    "position_mismatch": (StopCategory.UNCONTROLLED, "encoder and pot disagree: which one is right is unknown"),
    "velocity_mismatch": (StopCategory.UNCONTROLLED, "the velocity feedback is wrong"),
    "current_mismatch": (StopCategory.UNCONTROLLED, "the amplifier does not do what it is told"),
    "encoder_illegal": (StopCategory.UNCONTROLLED, "the decoder is losing counts"),
    "amplifier_fault": (StopCategory.UNCONTROLLED, "the amplifier reports a fault: it cannot decelerate"),
    "following_error": (StopCategory.UNCONTROLLED, "the joint no longer follows its command"),
    "driver_error": (StopCategory.UNCONTROLLED, "a board does not answer: its outputs cannot be trusted"),
    "exception": (StopCategory.UNCONTROLLED, "the controller's own code failed"),
    "plant_lost": (StopCategory.UNCONTROLLED, "no sensor data arrive"),
    "stale_sensor": (StopCategory.UNCONTROLLED, "the sensor data are old, or a reading no longer follows the joint"),
    "plant_restarted": (StopCategory.UNCONTROLLED, "the sensors' state was lost"),
    "estop": (StopCategory.UNCONTROLLED, "the operator's emergency stop: power off now"),
    # the unit controllers' (vmehil.unit_controllers): every unit's power off in the tick the
    # first stop reached the plant (docs/melmalec.md)
    "unit_stop": (StopCategory.UNCONTROLLED, "another unit controller stopped: every unit's power off in that tick"),
    "unit_lost": (StopCategory.UNCONTROLLED, "a unit controller fell silent: its joints are unpowered"),
    "coordinator_lost": (StopCategory.UNCONTROLLED, "no answer from the coordinator: no sensor data arrive"),
    "answer_incomplete": (StopCategory.UNCONTROLLED, "an answer lacks this unit's sensor data"),
    "operator_stop": (StopCategory.CONTROLLED, "the operator's stop: sensors and drivers sane"),
    "operator_shutdown": (StopCategory.CONTROLLED, "the operator's shutdown: sensors and drivers sane"),
    "session_end": (StopCategory.CONTROLLED, "a console session ended: sensors and drivers sane"),
    "end": (StopCategory.CONTROLLED, "the run ended: sensors and drivers sane"),
    "overrun": (StopCategory.CONTROLLED, "the loop is late but its sensors are sane: a late deceleration beats a fall"),
    "soft_limit": (StopCategory.CONTROLLED, "a joint reached its soft limit: sensors sane"),
    "interrupted": (StopCategory.CONTROLLED, "SIGINT/SIGTERM: the process is told to end, nothing has failed"),
    "stay": (StopCategory.HOLDING, "the operator's hold: power kept"),
}


#: causes of a stop that are no fault: the run's planned end (``loop.fault`` stays ``None``)
NOT_FAULTS = frozenset({"end", "session_end"})


def category_for(cause: str, stricter: Mapping[str, int] | None = None) -> StopCategory:
    """The category a stop for ``cause`` takes: the table's, or a rig file's stricter one."""
    base = CATEGORIES.get(cause, (StopCategory.UNCONTROLLED, ""))[0]
    if stricter and cause in stricter:
        return StopCategory(min(int(base), int(stricter[cause])))
    return base


@dataclass(frozen=True)
class HoldingLoad:
    """What holds each joint still: its gravity load ``gravity_nm · cos(θ + phase_rad)`` (N·m at
    the joint), from the controller's own figures (``[joint.servo.nominal] gravity_torque_nm``,
    ``gravity_phase_rad``; NaN: the joint states none).

    A joint at rest needs only this: friction holds in either direction and takes nothing, and
    the torque commanded when a stop came (its move's friction and acceleration, the loop's
    reaction to sensor noise) is no measure of it — j6 of jpl-arm, stopped while moving at
    10°/s, was commanding −0.002 N·m against a 0.29 N·m load. A re-enable starts the law at
    this torque at the angle the brake kept (:meth:`servo.loop.ServoLoop.resume`)."""

    gravity_nm: tuple[float, ...] = ()
    phase_rad: tuple[float, ...] = ()

    def known(self, n: int) -> np.ndarray:
        """Per joint (of ``n``): whether it states its load."""
        g = np.asarray(self.gravity_nm, float)
        return np.isfinite(g) if g.size == n else np.zeros(n, dtype=bool)

    def torque_nm(self, theta_rad: np.ndarray) -> np.ndarray:
        """The torque that holds each joint at ``theta_rad`` (N·m; NaN where the load is unknown)."""
        th = np.asarray(theta_rad, float)
        g = np.asarray(self.gravity_nm, float)
        if g.size != th.size:
            return np.full(th.shape, np.nan)
        return g * np.cos(th + np.asarray(self.phase_rad, float))


@dataclass(frozen=True)
class StopSettings:
    """How a controlled stop runs (SI). ``decel_rad_s2`` per joint: the deceleration it plans with;
    ``settle_s``: held at rest before the brakes engage; ``brake_engage_s``: the longest holding
    brake engage delay of the rig (0: no brakes), held with the amplifiers on; ``time_bound_s``: a
    category-1 stop not done by then falls to category 0; ``stricter``: cause → category from the
    rig file (never looser than :data:`CATEGORIES`); ``load``: what holds each joint still, the
    torque a re-enable starts from."""

    decel_rad_s2: tuple[float, ...]
    settle_s: float = 0.1
    brake_engage_s: float = 0.0
    time_bound_s: float = 1.5
    stricter: Mapping[str, int] = field(default_factory=dict)
    load: HoldingLoad = field(default_factory=HoldingLoad)

    def category(self, cause: str) -> StopCategory:
        return category_for(cause, self.stricter)


class Deceleration:
    """Per joint a constant deceleration from (θ0, ω0) to rest, then held (a trajectory:
    ``sample(t)``, ``duration``)."""

    def __init__(self, theta0: np.ndarray, omega0: np.ndarray, decel_rad_s2: np.ndarray) -> None:
        self.theta0 = np.asarray(theta0, float).copy()
        w = np.asarray(omega0, float)
        self.omega0 = np.where(np.isfinite(w), w, 0.0)
        self.a = np.asarray(decel_rad_s2, float)
        self.t_end = np.abs(self.omega0) / self.a
        self.duration = float(self.t_end.max(initial=0.0))

    def sample(self, t: float) -> Sample:
        tt = np.minimum(max(t, 0.0), self.t_end)
        sgn = np.sign(self.omega0)
        omega = self.omega0 - sgn * self.a * tt
        theta = self.theta0 + self.omega0 * tt - 0.5 * sgn * self.a * tt * tt
        alpha = np.where(t < self.t_end, -sgn * self.a, 0.0)
        return Sample(theta, omega, alpha, t >= self.duration)


@dataclass
class ControlledStop:
    """A category-1 stop under way (:meth:`servo.loop.ServoLoop.stop`)."""

    cause: str
    detail: str
    joint: int | None
    tick0: int  #: the tick it began
    trajectory: Deceleration
    brakes_tick: int | None = None  #: the tick the brake lines dropped
