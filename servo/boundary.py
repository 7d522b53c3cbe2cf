"""The plant boundary: what the runners need from the rest of the rig, and nothing more.

A runner (:mod:`servo.runner`) executes servo tick ``k`` as::

    plant.advance_to(k · T)            let time pass on the rig to the tick's instant
    plant.sense(k)                     the sensor values for tick k are in place
    loop.tick(truth=plant.truth())     drivers → law → drivers
    plant.advance_to(k · T + delay)    the command takes effect after the computation delay
    plant.exchange(k)                  the one exchange per servo period

Implementations:

* the emulated rig (:class:`vmehil.rig_setup.system.EmulatedRig`): the crate's simulated clock, the
  harness's publish and exchange, in-process or over CAN, and the plant's true state as truth;
* a real rig: the wall clock is the plant — ``advance_to`` and ``exchange`` do nothing (the
  boards and the arm move by themselves), ``truth`` is ``None`` (:class:`WallClockPlant`).

Several controllers that each drive a subset of the joints may share one plant: each holds a
boundary that names its joints (``joints``); the plant steps tick ``k`` once every boundary's
exchange for tick ``k`` has been made. The tick number travels with every call for that reason.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from servo.errors import ServoError


class PlantBoundaryError(ServoError, RuntimeError):
    """The rest of the rig failed at the boundary (no fresh data, a lost or restarted plant node).

    The runner turns it into a safe stop in the same tick, with :attr:`cause` as the fault cause.
    """

    def __init__(self, cause: str, detail: str) -> None:
        super().__init__(detail)
        self.cause = cause


@runtime_checkable
class PlantBoundary(Protocol):
    """What a runner drives between the loop's ticks (see the module docstring)."""

    # read-only for the runner (plain attributes or properties both implement them)
    @property
    def joints(self) -> Sequence[str]:
        """The plant joints this boundary serves, in the loop's joint order."""
        ...

    @property
    def period_s(self) -> float:
        """The servo period (s)."""
        ...

    @property
    def computation_delay_s(self) -> float:
        """The delay from sampling to the command taking effect (s)."""
        ...

    def advance_to(self, t_ns: int) -> None:
        """Let time pass on the rig up to ``t_ns`` (integer nanoseconds since the run's start)."""
        ...

    def sense(self, tick: int) -> None:
        """Put the sensor values for ``tick`` in place (called at the start of the tick)."""
        ...

    def exchange(self, tick: int) -> None:
        """The one exchange per period after ``tick``'s commands were written; may raise
        :class:`PlantBoundaryError`."""
        ...

    def truth(self) -> Mapping[str, np.ndarray] | None:
        """The plant's true state for reports (``theta_joint``, ``omega_joint``…), or ``None``."""
        ...

    @property
    def answer_lag_ticks(self) -> int:
        """Ticks the plant's answers may lag the commands beyond lockstep timing (0: lockstep, an
        in-process plant or a real rig; a free-running plant node answers 1-2 periods late). The
        watchdog's current check accepts any command of the last ``1 + answer_lag_ticks`` ticks."""
        ...

    @property
    def sample_clock(self) -> Callable[[], float | None] | None:
        """Where the plant free-runs: a function giving the plant time (s) of the values the
        sensors hold now (the loop's cross-checks integrate over it); ``None``: one period per tick."""
        ...


class WallClockPlant:
    """A real rig's boundary: time passes by itself, the boards are the exchange, no truth."""

    def __init__(self, joints: Sequence[str], period_s: float, computation_delay_s: float = 0.0) -> None:
        self.joints = list(joints)
        self.period_s = period_s
        self.computation_delay_s = computation_delay_s

    def advance_to(self, t_ns: int) -> None:
        return None

    def sense(self, tick: int) -> None:
        return None

    def exchange(self, tick: int) -> None:
        return None

    def truth(self) -> Mapping[str, np.ndarray] | None:
        return None

    @property
    def answer_lag_ticks(self) -> int:
        return 0  # the boards are read and written in the tick itself

    @property
    def sample_clock(self) -> Callable[[], float | None] | None:
        return None  # the wall clock paces the ticks: one period per tick
