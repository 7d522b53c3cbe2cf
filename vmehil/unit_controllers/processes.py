"""One unit controller, or the coordinator, as its own process on the unit bus (docs/melmalec.md).

:func:`run_unit` is what ``vmehil unit --rig melmalec-16 --unit leg1`` runs: announce itself,
wait for the coordinator's start, build its own boards, plan the global motion from every
unit's start, run its loop in lockstep inside :meth:`ServoLoop.armed` (every exit path ends with
its amplifiers disabled and its DACs at 0 V, read back), end as the single run does (a category-1
stop, then 2 s watching its joints: ``final_stop``), and leave. :func:`run_coordinator` is
``vmehil coordinate``: the plant of every joint (in this process, or the CAN plant node on the
plant bus with ``--plant can``) served to the units.
"""

from __future__ import annotations

import gc
from collections.abc import Callable
from typing import Any

import numpy as np

from emulators.can.node import new_boot_id
from emulators.plant_link import PlantLink, PlantLinkError
from servo.joint_groups import UnitSegments, rig_units, unit_named, unit_rig
from servo.motion import default_demo_motion, load_motion
from servo.rig import RigSpec
from servo.runner import LockstepRunner, RealtimeRunner
from servo.settings import servo_settings
from servo.trajectory.base import JointLimits
from servo.trajectory.sequencer import PlanContext
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig
from vmehil.unit_controllers.coordinator import UnitHook, UnitRun, plant_link_for
from vmehil.unit_controllers.remote import (
    FREE_STALE_TICKS,
    START_TIMEOUT_S,
    CoordinatorOutcome,
    UnitBus,
    UnitCanLink,
    UnitRefused,
    coordinate,
    file_digest,
    start_gains,
    start_switch_off,
    unit_number,
    wait_for_start,
)


def boot_id() -> int:
    """A boot identifier: this process's, different at every start — the plant node's
    :func:`~emulators.can.node.new_boot_id`, never 0."""
    return new_boot_id() or 1


def run_unit(spec: RigSpec, unit_name: str, bus: UnitBus, *, timeout_s: float, start_timeout_s: float = START_TIMEOUT_S,
             motion_path: str | None = None, realtime: bool = False,
             realtime_options: dict[str, Any] | None = None, after_tick: UnitHook | None = None,
             calibration: Any = None, before_run: Callable[[UnitRun], None] | None = None) -> UnitRun:
    """``vmehil unit``: join the coordinator's run and play this unit's part (module docstring).
    ``after_tick``: a hook after each of the unit's ticks (tests: probes, a hang).
    ``calibration``: the drivers' calibration store of the whole rig (this unit's drivers apply
    their own boards' and joints' entries). ``before_run``: called once the unit's loop and
    runner exist, before its first tick (its faults attach there)."""
    units = rig_units(spec)
    unit = unit_named(units, unit_name, str(spec.path))
    number = unit_number(spec, unit_name)
    boot = boot_id()
    members: dict[int, int] = {}  # the session's units' boot ids (their UNIT_STARTs)
    start = wait_for_start(bus, number=number, digest=file_digest(spec.path), boot_id=boot, timeout_s=start_timeout_s,
                           members=members)
    if int(start.raw["MotionDigest"]) != file_digest(motion_path):
        raise UnitRefused("the coordinator's motion differs from this unit's (give every unit and the coordinator "
                          "the same --motion file, or none)")
    seed, n_ticks = int(start.raw["Seed"]), int(start.raw["NTicks"])
    out = UnitRun(unit, seed=seed)
    link = UnitCanLink(bus, unit, number, boot, timeout_s, session_boot=int(start.raw["BootId"]), members=members)
    link.free_running = bool(int(start.raw["FreeRunning"]))
    link.stale_ticks = max(1, int(start.raw["StaleTicks"]))
    realtime = realtime or link.free_running  # free-running: every unit on its own wall clock
    try:
        system = out.system = build_emulated_rig(unit_rig(spec, unit), seed=seed, link=link,  # power-up: exchange 0
                                                 calibration=calibration)
        theta = np.asarray(system.io.read().theta, float)  # the unit's only read before its loop
        pad = [float(x) for x in theta] + [float("nan")] * (4 - len(theta))
        bus.send("UNIT_POS", Unit=number, BootId=boot, **{f"Theta{i}": pad[i] for i in range(4)})
        link.positions[number] = pad
        while len(link.positions) < len(units):
            f = bus.recv(timeout_s)
            if f is None:
                raise UnitRefused(f"the other units' start positions did not come within {timeout_s:g} s")
            link.note(f)  # UNIT_POS (of the session's units only), and the session's other UNIT_STARTs
        start_all = np.full(spec.n_joints, np.nan)
        for i, u in enumerate(units):
            start_all[list(u.indices)] = link.positions[i][:len(u.indices)]
        motion = load_motion(motion_path, spec.n_joints) if motion_path else default_demo_motion(spec.n_joints)
        limits = JointLimits.make(spec.n_joints, list(servo_settings(spec).max_velocity_rad_s))
        segments = UnitSegments(list(motion.moves), start_all, PlanContext(limits), unit.indices)
        loop = out.loop = build_loop(system, sequencer=segments, gains=start_gains(start) or None,
                                     switch_off=start_switch_off(start), n_ticks=n_ticks)
        link.stopped = lambda: None if loop.fault is None else f"{loop.fault.cause}: {loop.fault.detail}"
        runner = out.runner = (RealtimeRunner(system, loop, **(realtime_options or {})) if realtime
                               else LockstepRunner(system, loop))
        if after_tick is not None:
            runner.after_tick.append(lambda lp: after_tick(unit_name, system, lp))
        with loop.armed():
            if before_run is not None:  # as the threads' units do: armed, before the first tick
                before_run(out)
            if link.free_running:  # the unit's clock starts at the coordinator's first step
                segments.sample(0.0)  # plan the first move now, not in the first tick (tens of ms)
                gc.collect()  # the runner's start-up collection, done before the clock starts:
                gc.freeze()   # what exists now is out of the collector's way (the runner unfreezes)
                try:
                    link.await_first_answer()
                except PlantLinkError as e:
                    loop.safe_stop(e.cause, str(e))
            # a stopped unit's run ends: the others stop in the same exchange (module remote)
            out.completed = runner.run(n_ticks, stop=lambda: loop.fault is not None)
            # the single run's end (servo.runner.LockstepRunner.end_run): a category-1 stop, then
            # 2 s watching the joints; the coordinator serves the plant until every unit has left.
            # A link that is dead (the coordinator gone, or no fresh answer: the loop stopped for
            # it) has only held values to give: nothing to watch
            if not link.dead:
                runner.end_run()
        out.free_running, out.stale, out.incomplete = link.free_running, link.stale, link.incomplete
        if runner.ended_by is not None:
            out.ended = f"{type(runner.ended_by).__name__}: {runner.ended_by}"
        elif loop.fault is not None:
            out.ended = f"{loop.fault.cause}: {loop.fault.detail}"
    except BaseException as e:
        out.ended = f"{type(e).__name__}: {e}"
        if out.system is not None:  # before or outside armed(): the boards safe all the same
            out.system.io.safe_stop()
        raise
    finally:
        runner_ = out.runner
        timing = (runner_.timing.summary(spec.period_s) if isinstance(runner_, RealtimeRunner) and
                  runner_.timing.compute_s.total else None)
        link.leave(out.ended, ticks=out.completed, timing=timing)
    return out


def run_coordinator(spec: RigSpec, bus: UnitBus, *, seed: int, n_ticks: int, timeout_s: float,
                    start_timeout_s: float = START_TIMEOUT_S, motion_path: str | None = None,
                    gains: dict[str, float] | None = None, switch_off: bool | None = None,
                    plant_link: PlantLink | None = None, free_running: bool = False,
                    stale_ticks: int = FREE_STALE_TICKS) -> CoordinatorOutcome:
    """``vmehil coordinate``: serve the plant to the units. ``plant_link``: the plant of every
    joint elsewhere (``--plant can``: a connected link to the CAN plant node, reset with
    ``seed``; closed here), else the plant in this process."""
    link = plant_link if plant_link is not None else plant_link_for(spec, seed)
    try:
        return coordinate(spec, bus, link, seed=seed, n_ticks=n_ticks, boot_id=boot_id(), motion_path=motion_path,
                          gains=gains, switch_off=switch_off, timeout_s=timeout_s, start_timeout_s=start_timeout_s,
                          free_running=free_running, stale_ticks=stale_ticks)
    finally:
        link.close()
