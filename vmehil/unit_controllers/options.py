"""What ``vmehil run --units parallel`` gives the units like the single run (docs/melmalec.md,
"Options with --units parallel"): one report, the calibration, fault injection.

* **The report.** :class:`MergedUnits` shows the units' loops as the one loop of the rig that
  :mod:`vmehil.reports.run_report` (and :func:`vmehil.fault_scenarios.injection.stop_report`) read: every unit's
  recorded arrays merged in joint order, the switch-off events and integrator states in joint
  order, the sensor resolutions, the first stop. The report code is the single run's; only its
  input is merged. Each unit's own summary goes in the ``units`` section.
* **The calibration.** One file, loaded once with the single run's loader against the whole rig
  (the same checks); every unit's drivers apply its own boards' and joints' entries
  (:meth:`servo.io.JointIO.apply_calibration` looks up only its own).
* **Faults.** :func:`route_faults` gives each fault of ``--fault``/``--faults`` to the unit that
  owns its joint or its board (the rig's ``[[rig.unit]]``); a board no unit owns is refused,
  naming it. Each unit attaches its own :class:`~vmehil.fault_scenarios.injection.FaultSchedule` to its
  runner before its first tick (:func:`fault_hook`), so a fault strikes at the same tick as in
  the single run; a plant-side fault goes to the one plant of every joint.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from servo.control.law import SwitchEvent
from servo.io import SensorResolution
from servo.joint_groups import UnitSpec
from servo.loop import Fault, ServoLoop
from servo.rig import RigSpec
from servo.trajectory.sequencer import Sequencer
from vmehil.errors import VmehilError
from vmehil.fault_scenarios.injection import FaultContext, FaultSchedule, ScheduledFault
from vmehil.unit_controllers.coordinator import ParallelRun, UnitRun


class UnitFaultError(VmehilError, ValueError):
    """A fault that no single unit can take (a board no unit owns, the coordinator's CAN link)."""


# --- faults ------------------------------------------------------------------------------------
def route_faults(faults: list[ScheduledFault], spec: RigSpec, units: list[UnitSpec]) -> dict[str, list[ScheduledFault]]:
    """Each fault to the unit that owns its joint or board (unit name → its faults, in the given
    order). Raises :class:`UnitFaultError` for a board no unit owns and for faults of no joint or
    board (the CAN link, the vision system, a BIT3 card: not a unit's)."""
    out: dict[str, list[ScheduledFault]] = {u.name: [] for u in units}
    for f in faults:
        joint, board = f.params.get("joint"), f.params.get("board")
        owner: UnitSpec | None
        if board:  # adc_noise may name both: its board= wins, as in the single run
            owner = next((u for u in units if board in u.boards), None)
            if owner is None:
                owned = "; ".join(f"{u.name}: {', '.join(u.boards)}" for u in units)
                raise UnitFaultError(
                    f"{f.source}: board {board!r} belongs to no unit of rig {spec.name} (no [[rig.unit]]'s joints are "
                    f"wired to it), so no unit controller has it; the units' boards are {owned}")
        elif joint:
            owner = next(u for u in units if joint in u.joints)  # check_rig: the joint is the rig's
        else:
            raise UnitFaultError(
                f"{f.source}: {f.kind.name} ({f.kind.part}) is not a fault of one unit's joints or boards; "
                "--units parallel injects joint and board faults only (run it with --units single)")
        out[owner.name].append(f)
    return out


@dataclass
class UnitFaultContext(FaultContext):
    """A unit's fault context: its own boards, and the one plant of every joint (the hub's link)."""

    shared_link: Any = None

    def plant(self, what: str) -> Any:
        plant = getattr(self.shared_link, "plant", None)  # the in-process plant (InProcessLink)
        if plant is not None:
            return plant
        node = getattr(self.shared_link, "node", None)  # --plant can: the node thread of this process
        if node is not None:
            return node.node.plant
        raise UnitFaultError(f"{what} needs the plant in this process; the units talk to an external "
                             "`vmehil plant-node` (leave --interface out: on virtual the node runs in this process)")

    def can_link(self, what: str) -> Any:
        raise UnitFaultError(f"{what}: the CAN link is the coordinator's, shared by every unit; "
                             "run it with --units single")


def fault_hook(routed: dict[str, list[ScheduledFault]], shared_link: Any, seed: int
               ) -> tuple[Callable[[UnitRun], None], dict[str, FaultSchedule]]:
    """``before_run`` for :func:`vmehil.unit_controllers.coordinator.run_units`: each unit attaches the
    schedule of its own faults to its runner (faults due at tick 0 are injected at once, the
    others after the tick before theirs: as :func:`vmehil.fault_scenarios.options.attach` does). Returns
    the hook and the schedules it made (unit name → schedule)."""
    schedules: dict[str, FaultSchedule] = {}

    def before_run(ur: UnitRun) -> None:
        faults = routed.get(ur.unit.name) or []
        if not faults:
            return
        assert ur.system is not None and ur.loop is not None and ur.runner is not None
        schedule = FaultSchedule(faults, UnitFaultContext(ur.system, ur.loop, seed, shared_link=shared_link))
        schedules[ur.unit.name] = schedule
        schedule.attach(ur.runner)

    return before_run, schedules


# --- the report ----------------------------------------------------------------------------------
class _MergedRecorder:
    def __init__(self, run: ParallelRun, loops: list[ServoLoop]) -> None:
        self._run = run
        recs = [lp.recorder for lp in loops if lp.recorder is not None]
        self.rows = max((r.rows for r in recs), default=0)
        self.dropped = max((r.dropped for r in recs), default=0)
        self._data: dict[str, np.ndarray] | None = None

    def trimmed(self) -> dict[str, np.ndarray]:
        if self._data is None:
            self._data = self._run.recorded()
        return self._data


class _MergedIO:
    def __init__(self, parts: list[tuple[tuple[int, ...], Any]], n: int) -> None:
        self._parts, self._n = parts, n

    def resolution(self) -> SensorResolution:
        merged: dict[str, np.ndarray] = {}
        for f in dataclasses.fields(SensorResolution):
            out = np.full(self._n, np.nan) if f.name != "linear" else np.zeros(self._n, bool)
            for idx, io in self._parts:
                out[list(idx)] = getattr(io.resolution(), f.name)
            merged[f.name] = out
        return SensorResolution(**merged)


class _MergedLaw:
    def __init__(self, parts: list[tuple[tuple[int, ...], Any]], n: int) -> None:
        events: list[SwitchEvent] = []
        integrating = np.zeros(n, bool)
        for idx, law in parts:
            events += [dataclasses.replace(e, joint=idx[e.joint]) for e in law.events]
            integrating[list(idx)] = law.integrating
        self.events = sorted(events, key=lambda e: (e.tick, e.joint))  # as one law appends them
        self.integrating = integrating


class MergedUnits:
    """The units' loops as the one loop of the rig, for :mod:`vmehil.reports.run_report` (module
    docstring): what :func:`~vmehil.reports.run_report.summarize`, :func:`~vmehil.reports.run_report.write_report`
    and :func:`~vmehil.fault_scenarios.injection.stop_report` read of a :class:`~servo.loop.ServoLoop`."""

    vision = None  #: no visual servo with units

    def __init__(self, run: ParallelRun) -> None:
        ran = [u for u in run.units if u.loop is not None]
        if not ran:
            raise ValueError("no unit ran: nothing to report")
        loops = [u.loop for u in ran if u.loop is not None]
        first = loops[0]
        self.names = [j.name for j in run.rig.joints]
        self.n = len(self.names)
        self.period_s = run.rig.period_s
        self.tick_count = max(lp.tick_count for lp in loops)
        #: the run's own ticks (each unit's end — its category-1 stop and the 2 s after — not counted)
        run_ticks = [lp.run_ticks for lp in loops if lp.run_ticks is not None]
        self.run_ticks: int | None = max(run_ticks) if run_ticks else None
        self.recorder = _MergedRecorder(run, loops)
        self.sequencer: Sequencer = first.sequencer  # every unit plays the same global plan
        self._t_motion0 = first._t_motion0
        self.io = _MergedIO([(u.unit.indices, u.loop.io) for u in ran if u.loop is not None], self.n)
        laws = [(u.unit.indices, u.loop.law) for u in ran if u.loop is not None]
        self.law = _MergedLaw(laws, self.n) if all(law is not None for _, law in laws) else None
        self.fault = _first_fault(run, ran)
        #: the run's faults for the summary: the stop that stopped the run (units do not resume)
        self.faults = [self.fault] if self.fault is not None else []
        self.stop_incomplete = [f"{u.unit.name}: {item}" for u in ran if u.loop is not None
                                for item in u.loop.stop_incomplete]
        self.final_stop = _merged_final_stop(run, ran, self.stop_incomplete)
        notes = [(t, i, src, msg) for i, lp in enumerate(loops) for t, src, msg in lp.log]
        self.log = [(t, src, msg) for t, _, src, msg in sorted(notes, key=lambda x: (x[0], x[1]))]
        self.log_dropped = sum(lp.log_dropped for lp in loops)


def _first_fault(run: ParallelRun, ran: list[UnitRun]) -> Fault | None:
    """The stop that stopped the run: the unit the hub saw stop first, else the earliest fault."""
    stop = run.hub.stop
    if stop is not None:
        for u in ran:
            if u.unit.name == stop.unit and u.loop is not None and u.loop.fault is not None:
                return u.loop.fault
    faults = [u.loop.fault for u in ran if u.loop is not None and u.loop.fault is not None]
    return min(faults, key=lambda f: f.tick) if faults else None


def _merged_final_stop(run: ParallelRun, ran: list[UnitRun], incomplete: list[str]) -> dict[str, Any] | None:
    """The units' final stops as the one loop's: the first stopping unit's reason and cause, the
    strictest category (one unit that fell to category 0 makes the run's stop a category 0), and
    the excursions of every joint in the rig's order (each from its own unit)."""
    stops = {u.unit.name: u.loop.final_stop for u in ran if u.loop is not None and u.loop.final_stop is not None}
    if not stops:
        return None
    who = run.hub.stop.unit if run.hub.stop is not None and run.hub.stop.unit in stops else next(iter(stops))
    out = dict(stops[who])
    out.update(tick=max(s["tick"] for s in stops.values()), verified=all(s["verified"] for s in stops.values()),
               incomplete=list(incomplete), unit=who)
    out["time_s"] = out["tick"] * run.rig.period_s
    categories = [s["category"] for s in stops.values() if s.get("category") is not None]
    out["category"] = min(categories) if categories else None
    fell = [f"{name}: {s['fell_to_0']}" for name, s in stops.items() if s.get("fell_to_0")]
    out["fell_to_0"] = "; ".join(fell) if fell else None
    for key in ("excursion_deg", "excursion_sensor_deg"):
        per_unit = [s.get(key) for s in stops.values()]
        if all(p is None for p in per_unit):
            out[key] = None
            continue
        joined: dict[str, float | None] = {}
        for p in per_unit:
            joined.update(p or {})
        out[key] = {j.name: joined.get(j.name) for j in run.rig.joints}
    return out
