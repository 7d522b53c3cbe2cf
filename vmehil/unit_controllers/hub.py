"""One plant for several unit controllers, in lockstep (docs/melmalec.md).

Each unit controller has its own boards and its own harness; its harness's plant link is a
:class:`UnitLink`, which hands the unit's :class:`PlantCommand` for exchange ``r`` to the
:class:`PlantHub`. The hub steps the plant (any :class:`PlantLink` of every joint: in-process,
or the CAN plant node through :class:`~emulators.can.can_plant_link.CanPlantLink`) for exchange ``r``
only when every unit still running has handed in its commands for ``r``; each unit gets its
own joints' part of the answer. Merging and slicing copy values, never compute them, so the
plant sees exactly the command a single controller of every joint would send.

Faults travel with the exchange:

* a unit whose loop has stopped (its watchdog, an exception, a signal) says so with its
  commands for exchange ``r`` (already the safe outputs); every unit's :meth:`UnitLink.exchange`
  for ``r`` then raises :class:`UnitStopError`, which the unit's runner turns into a safe stop
  in that same tick: every unit's amplifiers are off on its own boards at the end of the tick
  in which the first one stopped, and in the plant from exchange ``r + 1`` on;
* a unit that hands in nothing for ``timeout_s`` (hung, killed) is declared lost: the plant
  steps with that unit's amplifiers disabled (what the amplifier-side command watchdog does on
  a CAN node), and every other unit's exchange raises :class:`UnitLostError` in the tick the
  lost unit missed. Lockstep time does not pass without the unit, so the bound is that tick
  (0 ticks) after at most ``timeout_s`` of wall time;
* a unit that leaves early (its runner ended before the run's last tick) counts as stopped.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from emulators.plant import PlantCommand, PlantSensors
from emulators.plant_link import PlantLink, PlantLinkError
from servo.joint_groups import UnitSpec
from vmehil.errors import VmehilError

#: default wall-clock wait for a unit's commands before it is declared lost (s)
UNIT_TIMEOUT_S = 2.0


class UnitStopError(VmehilError, PlantLinkError):
    """Another unit stopped: this one safe-stops in the same tick."""

    cause = "unit_stop"


class UnitLostError(VmehilError, PlantLinkError):
    """A unit fell silent (no commands within the hub's timeout): every unit safe-stops."""

    cause = "unit_lost"


@dataclass
class _Round:
    cmds: dict[str, PlantCommand] = field(default_factory=dict)
    answer: PlantSensors | None = None
    waiting: int = 0


@dataclass
class HubEvent:
    """What the hub saw, for the report and the tests: exchange number, unit, what."""

    exchange: int
    unit: str
    what: str


class PlantHub:
    """The lockstep meeting point of the unit controllers and the plant (module docstring)."""

    def __init__(self, link: PlantLink, units: Sequence[UnitSpec], n_joints: int, *,
                 watchdog_unit: str | None = None, timeout_s: float = UNIT_TIMEOUT_S) -> None:
        self.link = link
        self.units = {u.name: u for u in units}
        self.n = n_joints
        self.watchdog_unit = watchdog_unit
        self.timeout_s = timeout_s
        self._cv = threading.Condition()
        self._rounds: dict[int, _Round] = {}
        self._next: dict[str, int] = {u.name: 0 for u in units}
        self.running: set[str] = set(self.units)  #: units the plant waits for
        self.stop: HubEvent | None = None  #: the first stop (exchange, unit, why)
        self._told: set[str] = set()
        self.events: list[HubEvent] = []
        self.lost = threading.Event()  #: set when a unit was declared lost
        self.exchanges = 0  #: plant steps made
        #: per exchange made: how many amplifiers the plant had on after it (``truth['amp_enabled']``)
        self.amps_on: list[int] = []

    # --- a unit's side -----------------------------------------------------------------------
    def exchange(self, unit: str, cmd: PlantCommand, period_s: float, delay_s: float,
                 stopped: str | None = None) -> PlantSensors:
        """Hand in ``unit``'s commands for its next exchange and wait for the plant's answer."""
        with self._cv:
            r = self._next[unit]
            self._next[unit] = r + 1
            if unit not in self.running:
                self._tell(unit, UnitLostError(f"unit {unit}: declared lost or gone before exchange {r}; "
                                               "the plant no longer waits for it"))
                return self._held(unit)
            rd = self._rounds.setdefault(r, _Round())
            rd.cmds[unit] = cmd
            if stopped is not None:
                self._stopped(r, unit, stopped)
            self._try_step(r, period_s, delay_s)
            deadline = time.monotonic() + self.timeout_s
            rd.waiting += 1
            while rd.answer is None:
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    self._declare_lost(r, period_s, delay_s)
                    break
                self._cv.wait(remaining)
            rd.waiting -= 1
            answer = rd.answer
            if rd.waiting == 0 and set(rd.cmds) >= self.running:
                self._rounds.pop(r, None)
            assert answer is not None
            self._last_answer = answer
            # a stop is news from its own exchange on: a unit still reading an earlier answer
            # (another already handed in the stopping exchange) is told at its next one
            if self.stop is not None and r >= self.stop.exchange and unit not in self._told:
                s = self.stop
                err: PlantLinkError = (UnitLostError if s.what.startswith("lost") else UnitStopError)(
                    f"unit {s.unit} {s.what} at exchange {s.exchange}: every unit stops")
                self._tell(unit, err)
        return self._slice(answer, unit)

    def leave(self, unit: str, why: str | None) -> None:
        """``unit``'s runner has ended (``why``: None at the run's end, else what ended it early)."""
        with self._cv:
            if unit not in self.running:
                return
            self.running.discard(unit)
            r = self._next[unit]
            if why is not None:
                self._stopped(r, unit, f"left: {why}")
            self.events.append(HubEvent(r, unit, "left" if why is None else f"left: {why}"))
            # a round waiting only for this unit can be stepped now
            for rr in sorted(self._rounds):
                rd = self._rounds[rr]
                if rd.answer is None and rd.cmds and set(rd.cmds) >= self.running:
                    self._step(rr, rd, *self._timing)
            self._cv.notify_all()

    # --- internals (called with the lock held) ---------------------------------------------------
    _timing: tuple[float, float] = (0.0, 0.0)
    _last_answer: PlantSensors | None = None

    def _tell(self, unit: str, err: PlantLinkError) -> None:
        if unit in self._told:
            return
        self._told.add(unit)
        raise err

    def _stopped(self, r: int, unit: str, why: str) -> None:
        if self.stop is None:
            self.stop = HubEvent(r, unit, why)
        self.events.append(HubEvent(r, unit, why))

    def _try_step(self, r: int, period_s: float, delay_s: float) -> None:
        self._timing = (period_s, delay_s)
        rd = self._rounds[r]
        if rd.answer is None and set(rd.cmds) >= self.running:
            self._step(r, rd, period_s, delay_s)

    def _declare_lost(self, r: int, period_s: float, delay_s: float) -> None:
        rd = self._rounds[r]
        for name in sorted(self.running - set(rd.cmds)):
            self.running.discard(name)
            self._stopped(r, name, f"lost: no commands for exchange {r} within {self.timeout_s:g} s")
        self.lost.set()
        if rd.answer is None:
            try:
                self._step(r, rd, period_s, delay_s)
            except PlantLinkError as e:
                # the plant's side reacted to the silence too (its node latched the amplifiers off:
                # no commands reached it either); the run already stops for the lost unit, and that
                # is what every unit hears — the plant's reaction is kept as an event
                if self._last_answer is None:
                    raise
                self.events.append(HubEvent(r, "plant", f"after the loss: {e.cause}: {e}"))
                rd.answer = self._last_answer
                self._cv.notify_all()

    def _step(self, r: int, rd: _Round, period_s: float, delay_s: float) -> None:
        cmd = PlantCommand.idle(self.n)  # a unit not handing in (lost, gone): its amplifiers off
        for name, c in rd.cmds.items():
            idx = list(self.units[name].indices)
            cmd.amp_command_v[idx] = c.amp_command_v
            cmd.amp_enable[idx] = c.amp_enable
            cmd.fault_reset[idx] = c.fault_reset
            cmd.pwm_duty[idx] = c.pwm_duty
            cmd.pwm_direction[idx] = c.pwm_direction
            cmd.brake[idx] = c.brake
            cmd.holding_brake[idx] = c.holding_brake
        wd = rd.cmds.get(self.watchdog_unit) if self.watchdog_unit is not None else None
        cmd.watchdog_line = bool(wd.watchdog_line) if wd is not None else False
        rd.answer = self.link.exchange(cmd, period_s, delay_s)
        self.exchanges += 1
        enabled = rd.answer.truth.get("amp_enabled")
        self.amps_on.append(int(np.count_nonzero(enabled)) if enabled is not None else -1)
        self._cv.notify_all()

    def _held(self, unit: str) -> PlantSensors:
        if self._last_answer is None:
            raise UnitLostError(f"unit {unit}: no answer from the plant yet")
        return self._slice(self._last_answer, unit)

    def _slice(self, s: PlantSensors, unit: str) -> PlantSensors:
        idx = list(self.units[unit].indices)
        n = self.n

        def cut(a: Any) -> Any:
            arr = np.asarray(a)
            return arr[idx] if arr.ndim >= 1 and arr.shape[0] == n else a

        return PlantSensors(pot_v=cut(s.pot_v), tach_v=cut(s.tach_v), imon_v=cut(s.imon_v),
                            amp_fault=cut(s.amp_fault), encoder=[s.encoder[i] for i in idx],
                            switching=cut(s.switching), switching_noise_v=cut(s.switching_noise_v),
                            truth={k: cut(v) for k, v in s.truth.items()})


class UnitLink(PlantLink):
    """A unit controller's plant link: its harness's exchange goes through the hub.

    ``stopped``: asked at each exchange; returns why the unit's loop has stopped (``None``
    while it runs) — set once the unit's loop exists."""

    def __init__(self, hub: PlantHub, unit: str) -> None:
        self.hub = hub
        self.unit = unit
        self.names = list(hub.units[unit].joints)
        self.stopped: Callable[[], str | None] = lambda: None

    def exchange(self, cmd: PlantCommand, period_s: float, delay_s: float) -> PlantSensors:
        return self.hub.exchange(self.unit, cmd, period_s, delay_s, self.stopped())
