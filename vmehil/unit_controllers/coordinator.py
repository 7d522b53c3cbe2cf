"""The coordinator and its unit controllers in one process, one thread each (docs/melmalec.md).

The coordinator owns the motion and the plant: it reads the global move list (a motion file,
or the default demo) for every joint of the rig, collects every unit's measured start,
and hands each unit its segments of the one global plan (:class:`servo.joint_groups.UnitSegments`:
they start and end together); the gains and the run's length go to every unit alike. Each unit
controller builds its own emulated boards (only those it owns), its drivers, its 125 Hz loop
and its runner, and exchanges with the one plant through the :class:`~vmehil.unit_controllers.hub.PlantHub`
in lockstep. Every unit's run is inside :meth:`ServoLoop.armed`: whatever ends it, it ends with
its amplifiers disabled and its DACs at 0 V, read back.

Like for like with the single controller (``--units single``) by construction: the same rig
file, the same per-board noise streams (``rng_for(seed, board, ...)``: a board's stream does
not depend on which crate holds it), the H-bridge noise only in the driving unit's boards in
both runs, the same start reading (one ``read()`` of every board), the same global plan, the
plant stepped once per exchange with the merged command. Lockstep results are bit-identical
(tests/vmehil/test_units_parallel.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from emulators.harness import InProcessLink
from emulators.plant import Plant
from emulators.plant_link import PlantLink
from emulators.presets import resolve_rig
from servo.interrupts import INTERRUPTS, Terminated
from servo.joint_groups import UnitSegments, UnitSpec, rig_units, unit_rig, watchdog_unit
from servo.loop import ServoLoop
from servo.motion import Motion, default_demo_motion
from servo.rig import RigSpec, load_rig
from servo.runner import WATCH_AFTER_STOP_S, LockstepRunner, RealtimeRunner
from servo.settings import servo_settings
from servo.trajectory.base import JointLimits
from servo.trajectory.sequencer import PlanContext
from vmehil.errors import VmehilError
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import NON_PLANT_JOINT_KEYS, EmulatedRig, build_emulated_rig
from vmehil.unit_controllers.hub import UNIT_TIMEOUT_S, PlantHub, UnitLink

#: a hook run after each of a unit's ticks: (unit name, its rig, its loop)
UnitHook = Callable[[str, EmulatedRig, ServoLoop], None]


class UnitsRefused(VmehilError, ValueError):
    """The rig cannot run as units (it declares none), or a unit is not the rig's."""


@dataclass
class UnitRun:
    """One unit controller's run: its rig (boards), loop, runner and how it ended."""

    unit: UnitSpec
    system: EmulatedRig | None = None
    loop: ServoLoop | None = None
    runner: LockstepRunner | None = None
    completed: int = 0
    error: BaseException | None = None
    seed: int = 0
    ended: str | None = None  #: why the run ended early (None: it ran to the end)
    free_running: bool = False  #: on the unit bus: the unit ran on its own wall clock
    stale: int = 0  #: free-running: exchanges that found no fresh answer (held values)
    incomplete: int = 0  #: free-running: answers dropped for a missing SENS frame


@dataclass
class ParallelRun:
    """The outcome of :func:`run_units`."""

    rig: RigSpec
    hub: PlantHub
    units: list[UnitRun] = field(default_factory=list)

    def recorded(self) -> dict[str, np.ndarray]:
        """Every unit's recorder merged into the rig's joint order (as one controller records)."""
        recs = []
        for u in self.units:
            assert u.loop is not None and u.loop.recorder is not None
            recs.append(u.loop.recorder.trimmed())
        # a unit that stopped a tick before the others recorded fewer ticks: NaN after its last
        ref = max(recs, key=lambda r: r["t"].shape[0])
        out: dict[str, np.ndarray] = {}
        n = self.rig.n_joints
        for key, arr in ref.items():
            if arr.ndim == 1:
                out[key] = arr.copy()
                continue
            out[key] = np.full((arr.shape[0], n), np.nan)
        for u, rec in zip(self.units, recs, strict=True):
            for key, arr in rec.items():
                if arr.ndim == 2:
                    out[key][: arr.shape[0], list(u.unit.indices)] = arr
        return out

    def close(self) -> None:
        for u in self.units:
            if u.system is not None:
                u.system.close()
        self.hub.link.close()


#: the cause and detail of the units' stop when the coordinator is interrupted (SIGINT/SIGTERM)
INTERRUPT_CAUSE = "interrupted"
INTERRUPT_DETAIL = "the coordinator was interrupted (SIGINT/SIGTERM)"


def _stop_news(loop: ServoLoop, ending: list[str]) -> str | None:
    """What a unit's exchanges tell the others (:class:`~vmehil.unit_controllers.hub.UnitLink`):
    why its loop stopped, or ``None``. The unit's own end — the category-1 stop every unit makes
    at the run's end or on the coordinator's interruption — is no news: each unit makes its own
    (the others would otherwise fall to category 0 mid-deceleration); a fault, or an end that
    fell to category 0, is."""
    f = loop.fault
    if f is None:
        return None
    if ending and f.cause == ending[0] and loop.stop_fell is None:
        return None
    return f"{f.cause}: {f.detail}"


def _cut_short(cut: threading.Event, second: list[BaseException], loop: ServoLoop) -> None:
    """After each of a unit's ticks: the coordinator's second signal (``second``: SIGINT when
    none is named), raised in the unit's thread — its runner makes a category-1 stop under way a
    category 0 and ends the window after the stop, as for the single run's second signal."""
    if cut.is_set():
        sig = second[0] if second else None
        raise Terminated(sig.signum) if isinstance(sig, Terminated) else KeyboardInterrupt()


def _wait_all(ended: dict[str, threading.Event], seconds: float) -> None:
    """Wait for every unit to say it has ended, at most ``seconds`` in all, in slices: Ctrl-C and
    SIGTERM are handled while waiting (a simulated one, ``_thread.interrupt_main``, too)."""
    end = time.monotonic() + seconds
    for e in ended.values():
        while not e.wait(min(0.2, max(0.0, end - time.monotonic()))):
            if time.monotonic() >= end:
                return


def plant_link_for(spec: RigSpec, seed: int) -> PlantLink:
    """The in-process plant of every joint (as :func:`vmehil.rig_setup.system.build_emulated_rig` builds it)."""
    return InProcessLink(Plant.from_config(spec.table, seed=seed, foreign_keys=NON_PLANT_JOINT_KEYS))


def run_units(rig: str | Path | RigSpec, *, seed: int = 0, n_ticks: int, motion: Motion | None = None,
              gains: dict[str, float] | None = None, switch_off: bool | None = None,
              link: PlantLink | None = None, realtime: bool = False, realtime_options: dict[str, Any] | None = None,
              timeout_s: float = UNIT_TIMEOUT_S, after_tick: UnitHook | None = None,
              abort: threading.Event | None = None, cut_short: threading.Event | None = None,
              calibration: Any = None,
              before_run: Callable[[UnitRun], None] | None = None) -> ParallelRun:
    """Run the rig's units in parallel (one thread each) against one plant, in lockstep; returns
    when every unit's runner has ended (each one safe-stopped). ``abort``: set it to stop every
    unit at its next tick: each makes the single run's end for a signal, a category-1 stop then
    2 s watched (Ctrl-C and SIGTERM set it, then go on). ``cut_short``: set it, after ``abort``,
    to end those at once — a stop under way falls to category 0, the window ends (a second
    Ctrl-C or SIGTERM sets it). ``calibration``: a store of
    the whole rig (each unit's drivers apply their own boards' and joints' entries).
    ``before_run``: called in each unit's thread once its loop is armed, before its first tick
    (``vmehil run --units parallel`` attaches the unit's fault schedule there)."""
    spec = rig if isinstance(rig, RigSpec) else load_rig(resolve_rig(rig))
    units = rig_units(spec)
    if not units:
        raise UnitsRefused(f"rig {spec.name} ({spec.path}): no [[rig.unit]] tables; "
                           "--units parallel needs the rig's units (docs/melmalec.md)")
    hub = PlantHub(link if link is not None else plant_link_for(spec, seed), units, spec.n_joints,
                   watchdog_unit=watchdog_unit(spec, units), timeout_s=timeout_s)
    run = ParallelRun(spec, hub, [UnitRun(u) for u in units])
    motion = motion or default_demo_motion(spec.n_joints)
    settings = servo_settings(spec)
    limits = JointLimits.make(spec.n_joints, list(settings.max_velocity_rad_s))
    starts: dict[str, np.ndarray] = {}
    go = threading.Barrier(len(units))
    stop_all = abort if abort is not None else threading.Event()
    started = threading.Condition()

    def global_start() -> np.ndarray:
        # every unit's start is in: the one start vector of the global plan
        with started:
            if not started.wait_for(lambda: len(starts) == len(units), timeout=timeout_s * 4):
                raise TimeoutError("not every unit reported its start position")
        theta = np.full(spec.n_joints, np.nan)
        for u in units:
            theta[list(u.indices)] = starts[u.name]
        return theta

    #: a second SIGINT/SIGTERM to the coordinator during the units' end (their category-1 stops
    #: and the 2 s after): each unit's next tick raises it, as the single run's second signal does
    second: list[BaseException] = []
    cut = cut_short if cut_short is not None else threading.Event()

    def unit_main(ur: UnitRun) -> None:
        unit = ur.unit
        ulink = UnitLink(hub, unit.name)
        ending: list[str] = []  # the cause of the unit's own end, once its run proper is over
        why: str | None = "it never started"
        try:
            system = ur.system = build_emulated_rig(unit_rig(spec, unit), seed=seed, link=ulink,
                                                    calibration=calibration)
            start = system.io.read().theta  # the unit's only read before the loop (as build_loop's)
            with started:
                starts[unit.name] = np.asarray(start, float).copy()
                started.notify_all()
            segments = UnitSegments(list(motion.moves), global_start(), PlanContext(limits), unit.indices)
            loop = ur.loop = build_loop(system, sequencer=segments, gains=gains, switch_off=switch_off,
                                        n_ticks=n_ticks)
            ulink.stopped = partial(_stop_news, loop, ending)
            runner = ur.runner = (RealtimeRunner(system, loop, **(realtime_options or {})) if realtime
                                  else LockstepRunner(system, loop))
            if after_tick is not None:
                runner.after_tick.append(lambda lp: after_tick(unit.name, system, lp))
            runner.after_tick.append(partial(_cut_short, cut, second))
            with loop.armed():
                if before_run is not None:
                    before_run(ur)
                # every unit starts its runner together: a real-time runner's deadlines count
                # from its start, and lockstep couples the units from the first exchange on
                go.wait(timeout=timeout_s * 4)
                ur.completed = runner.run(n_ticks, stop=stop_all.is_set)
                # the single run's end (servo.runner.LockstepRunner.end_run): a category-1 stop
                # (decelerate, brakes, power off), then 2 s watching the joints; each unit its own
                ending.append(INTERRUPT_CAUSE if stop_all.is_set() else "end")
                if stop_all.is_set():
                    runner.end_run(cause=INTERRUPT_CAUSE, detail=INTERRUPT_DETAIL)
                else:
                    runner.end_run()
            # an abort ends every unit's run early, each with its own end: leaving then is no
            # news for the others (the hub would cut their windows short)
            why = (None if ur.completed == n_ticks or ending == [INTERRUPT_CAUSE]
                   else f"its run ended after {ur.completed} ticks")
            if runner.ended_by is not None:
                why = f"{type(runner.ended_by).__name__}: {runner.ended_by}"
        except (Exception, KeyboardInterrupt, Terminated) as e:
            # (the coordinator's second signal, raised here by _cut_short, is no error of the unit's)
            if not (cut.is_set() and isinstance(e, INTERRUPTS)):
                ur.error = e
            why = f"{type(e).__name__}: {e}"
            if ur.system is not None:  # no loop yet, or armed() already stopped it: the boards safe
                ur.system.io.safe_stop()
        finally:
            try:
                hub.leave(unit.name, why)
            finally:
                ended[ur.unit.name].set()

    # Each unit says it has ended (safe-stopped, left the hub) through an Event of its own. The
    # main thread waits on those, not on Thread.join: a join that Ctrl-C interrupts can leave
    # the thread marked as stopped while it still runs (CPython before 3.13), and the join after
    # the interrupt then returns at once, before the unit's safe stop.
    ended = {ur.unit.name: threading.Event() for ur in run.units}
    threads = [threading.Thread(target=unit_main, args=(ur,), name=f"unit-{ur.unit.name}", daemon=True)
               for ur in run.units]
    for t in threads:
        t.start()
    try:
        for e in ended.values():
            while not e.wait(0.2):  # in slices: Ctrl-C and SIGTERM are handled while waiting
                pass
    except BaseException:
        # Ctrl-C or SIGTERM reaches this (the main) thread: every unit stops at its next tick
        # boundary as the single run does (category 1, then 2 s watching), then the signal goes on
        stop_all.set()
        try:
            _wait_all(ended, timeout_s * 4 + WATCH_AFTER_STOP_S)
        except INTERRUPTS as again:  # a second one: category 0 now, the window ends (_cut_short)
            second.append(again)
            cut.set()
            _wait_all(ended, timeout_s * 4)
        raise
    for t in threads:
        t.join(timeout=timeout_s)  # each has set its Event: only its thread's own ending is left
    return run
