"""The black box: the last seconds of every joint's controller signals and the board lines, always kept.

A flight recorder for the servo loop (issue #35). :meth:`servo.loop.ServoLoop.tick` puts one row per
tick into a preallocated ring (numpy only); nothing here touches a bus: every value is one the
tick already has (the measurement, the sample, the law's state, the lines the drivers last drove),
so a run with the black box makes the same bus cycles as one without it.

The ring holds ``seconds`` before a stop and ``after_s`` after it: while the amplifiers are powered
every tick is kept; once power is off it keeps ``after_s`` more seconds (how the joints came to
rest, the brakes, the excursion), then freezes, so a run that keeps ticking long after a fault (a
fault at 3 s of a 20 s run) still has the fault in its box. Powered again (a console ``resume``),
it records on; the box at the end holds the last stop.

Rows, per tick: ``t`` (s), ``tick``, ``stop_state`` (:data:`STOP_STATES`), and per joint the
:data:`JOINT_SIGNALS` (named as the signal catalog names them). The application writes
:meth:`BlackBox.snapshot` out on every stop (``vmehil``: MCAP or ``.npz`` and a PNG, named in the
run JSON as ``final_stop.blackbox``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["DEFAULT_AFTER_S", "DEFAULT_SECONDS", "JOINT_SIGNALS", "STOP_STATES", "BlackBox", "BlackBoxSnapshot"]

#: seconds kept before a stop unless the rig file says (``[servo] blackbox_s``)
DEFAULT_SECONDS = 5.0
#: seconds kept after the power went off (the watch window of the end of a run is 2 s)
DEFAULT_AFTER_S = 2.0

#: per-joint signals, in the order of the ring's second axis: (leaf, group, kind, unit, what). The
#: names are the signal catalog's (docs/scope.md): group ``ctrl`` is the joint's own group
#: (``j1.target_rad``), ``drv`` the drivers' (``drv.j1.amp_fault``); kind ``f`` a number, ``b`` a
#: level (1/0, NaN: not known).
JOINT_SIGNALS: tuple[tuple[str, str, str, str, str], ...] = (
    ("target_rad", "ctrl", "f", "rad", "the trajectory's position (theta_d)"),
    ("target_rad_s", "ctrl", "f", "rad/s", "the trajectory's velocity (omega_d)"),
    ("position_rad", "ctrl", "f", "rad", "the measured position the law used (pot or encoder)"),
    ("velocity_rad_s", "ctrl", "f", "rad/s", "the measured velocity the law used (tach or encoder)"),
    ("error_rad", "ctrl", "f", "rad", "target - position"),
    ("torque_nm", "ctrl", "f", "N·m", "the law's torque command"),
    ("current_cmd_a", "ctrl", "f", "A", "the current commanded to the amplifier (after the limit)"),
    ("current_a", "ctrl", "f", "A", "the current monitor's reading"),
    ("integral_e", "ctrl", "f", "rad·s", "the law's integrator of the position error"),
    ("integral_edot_rad", "ctrl", "f", "rad", "the law's integrator of the velocity error"),
    ("kp_eff", "ctrl", "f", "1/s²", "the position gain in force (boosted while switched off)"),
    ("integrating", "ctrl", "b", "", "switch-off state: the integrators are fed"),
    ("amp_enable", "drv", "b", "", "the amplifier enable line as the drivers last drove it"),
    ("brake_released", "drv", "b", "", "the holding brake's line: released (energised)"),
    ("amp_fault", "drv", "b", "", "the amplifier's fault line as the PIO read it this tick"),
)
_INDEX = {leaf: i for i, (leaf, *_rest) in enumerate(JOINT_SIGNALS)}

#: ``stop_state`` values (the catalog's ``J.stop_state``): what the loop was doing at that tick
STOP_STATES: tuple[str, ...] = ("running", "stopping", "holding", "stopped")
RUNNING, STOPPING, HOLDING, STOPPED = range(4)

#: the loop's per-tick values (its recorder's names, left) → the ring's signals
_FROM_ROW: tuple[tuple[str, int], ...] = (
    ("theta_d", _INDEX["target_rad"]), ("omega_d", _INDEX["target_rad_s"]), ("theta", _INDEX["position_rad"]),
    ("omega", _INDEX["velocity_rad_s"]), ("torque", _INDEX["torque_nm"]), ("current_cmd", _INDEX["current_cmd_a"]),
    ("current", _INDEX["current_a"]), ("kp_eff", _INDEX["kp_eff"]), ("integrating", _INDEX["integrating"]))
_ERROR, _TARGET, _POSITION = _INDEX["error_rad"], _INDEX["target_rad"], _INDEX["position_rad"]
_IE, _IV, _ENABLE = _INDEX["integral_e"], _INDEX["integral_edot_rad"], _INDEX["amp_enable"]
_BRAKE, _FAULT = _INDEX["brake_released"], _INDEX["amp_fault"]


@dataclass(frozen=True)
class BlackBoxSnapshot:
    """The box's rows in time order: ``t`` (s) and ``tick`` and ``stop_state`` per row, ``joints``
    (rows × signals × joints, :data:`JOINT_SIGNALS`); ``stop_tick`` the tick the last stop began
    (``None``: none), ``names`` the joints', ``period_s``."""

    t: np.ndarray
    tick: np.ndarray
    stop_state: np.ndarray
    joints: np.ndarray
    names: tuple[str, ...]
    period_s: float
    stop_tick: int | None

    def signal(self, leaf: str) -> np.ndarray:
        """One signal (its leaf, e.g. ``position_rad``), rows × joints."""
        return self.joints[:, _INDEX[leaf], :]

    @property
    def seconds_before_stop(self) -> float:
        """How much of the box lies before the stop (s; the whole box when there was none)."""
        if not self.t.size:
            return 0.0
        if self.stop_tick is None:
            return float(self.t[-1] - self.t[0])
        return max(0.0, self.stop_tick * self.period_s - float(self.t[0]))


class BlackBox:
    """A ring of ``seconds + after_s`` of ticks for ``n`` joints (preallocated)."""

    def __init__(self, n: int, period_s: float, names: list[str] | tuple[str, ...], *,
                 seconds: float = DEFAULT_SECONDS, after_s: float = DEFAULT_AFTER_S) -> None:
        if not (seconds > 0 and math.isfinite(seconds)):
            raise ValueError(f"black box seconds {seconds!r}: expected a positive number")
        if not (after_s >= 0 and math.isfinite(after_s)):
            raise ValueError(f"black box after_s {after_s!r}: expected 0 or more")
        self.n = n
        self.period_s = period_s
        self.names = tuple(names)
        self.seconds = seconds
        self.after_s = after_s
        self.capacity = max(1, math.ceil((seconds + after_s) / period_s))
        self._after_ticks = math.ceil(after_s / period_s)
        self._joints = np.full((self.capacity, len(JOINT_SIGNALS), n), np.nan)
        self._t = np.full(self.capacity, np.nan)
        self._tick = np.full(self.capacity, -1, dtype=np.int64)
        self._state = np.zeros(self.capacity, dtype=np.int8)
        self.count = 0  #: rows written so far (the ring holds the newest ``capacity``)
        self._off_ticks = 0  #: ticks recorded since the power went off
        self.stop_tick: int | None = None

    @property
    def frozen(self) -> bool:
        """Power has been off for ``after_s``: rows are no longer written until it is on again."""
        return self._off_ticks > self._after_ticks

    def put(self, k: int, t: float, row: Mapping[str, Any], state: int, *, integrator_e: np.ndarray | None,
            integrator_v: np.ndarray | None, enabled: bool, brake_released: np.ndarray | None,
            amp_fault: np.ndarray | None, stop_tick: int | None) -> None:
        """Tick ``k``'s row: ``row`` holds the loop's per-tick values (absent: NaN); ``state`` one of
        :data:`STOP_STATES` (index)."""
        if state == STOPPED:
            if self._off_ticks > self._after_ticks:
                return
            self._off_ticks += 1
        else:
            self._off_ticks = 0
        self.stop_tick = stop_tick
        i = self.count % self.capacity
        self.count += 1
        r = self._joints[i]
        r.fill(np.nan)
        for key, f in _FROM_ROW:
            v = row.get(key)
            if v is not None:
                r[f] = v
        np.subtract(r[_TARGET], r[_POSITION], out=r[_ERROR])
        if integrator_e is not None:
            r[_IE] = integrator_e
        if integrator_v is not None:
            r[_IV] = integrator_v
        r[_ENABLE] = 1.0 if enabled else 0.0
        if brake_released is not None:
            r[_BRAKE] = brake_released
        if amp_fault is not None:
            r[_FAULT] = amp_fault
        self._t[i] = t
        self._tick[i] = k
        self._state[i] = state

    def latest(self) -> tuple[int, float, int, np.ndarray] | None:
        """The newest row: (tick, t, stop state, signals × joints — a view, read it before the next
        tick); ``None`` before the first."""
        if not self.count:
            return None
        i = (self.count - 1) % self.capacity
        return int(self._tick[i]), float(self._t[i]), int(self._state[i]), self._joints[i]

    def snapshot(self) -> BlackBoxSnapshot:
        """A copy of the rows kept, oldest first."""
        m = min(self.count, self.capacity)
        order = np.arange(self.count - m, self.count) % self.capacity
        return BlackBoxSnapshot(t=self._t[order].copy(), tick=self._tick[order].copy(),
                                stop_state=self._state[order].copy(), joints=self._joints[order].copy(),
                                names=self.names, period_s=self.period_s, stop_tick=self.stop_tick)
