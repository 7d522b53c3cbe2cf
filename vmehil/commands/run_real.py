"""``vmehil run --bus vme_user[:DIR] --rig FILE``: the same drivers and loop on a real crate.

Dry pass (every board's ID and status against the rig file) and a start-up safe stop read back
come first (:mod:`vmehil.rig_setup.real_bus`); without ``--enable-amplifiers`` the run ends there. With
it, the loop runs paced by the wall clock (:class:`servo.runner.RealtimeRunner`) with the plant
boundary :class:`servo.boundary.WallClockPlant`, inside ``loop.armed()``: whatever ends it ends
with enables low, DACs at 0 V and PWM off, read back.

It takes the options of the emulated run that mean something on a real crate — the drivers'
calibration (loaded and checked as the emulated run does), ``--json``, ``--report``,
``--overrun``, ``--motion``, ``--duration``, ``--gains`` — and writes the same JSON and report
(:func:`vmehil.commands.run_results.finish_run`). The ones that need the emulated rig or are not
built for a real crate yet are refused in one line before the bus is opened
(:func:`refused_on_a_real_bus`).
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from servo.settings import ServoSettings
    from vmehil.commands.run_options import RunOptions


def refused_on_a_real_bus(opts: RunOptions) -> list[str]:
    """The options of ``opts`` a real-bus run does not take, each with why (empty: none)."""
    out = []
    if opts.faults.specs or opts.faults.file:
        out.append("--fault/--faults: fault injection acts on the emulated boards and plant")
    if opts.vision.mode is not None:
        out.append("--vision: the emulated vision computer (a real one talks to the real BIT3 card)")
    if opts.plant is not None:
        out.append("--plant can: the plant of a real crate is the arm itself")
    if opts.mavlink.url is not None:
        out.append("--mavlink: not offered on a real bus yet (live gain changes on a real arm)")
    if opts.console.port is not None:
        out.append("--console: not offered on a real bus yet")
    if opts.units != "single":
        out.append("--units parallel: the unit controllers run on emulated crates")
    return out


def run_on_real_bus(opts: RunOptions, rig, settings: ServoSettings, **bus_options: Any) -> int:
    """``settings``: the rig's servo settings with the command line's override applied
    (:meth:`servo.settings.ServoSettings.overridden`); the exit status is the results' writer's
    (:func:`vmehil.commands.run_results.finish_run`, as the emulated run's); ``bus_options`` go
    to :class:`hal.vme.vme_user.VmeUserBus` (tests inject a clock)."""
    from servo.interrupts import INTERRUPTS, SignalsDeferred
    from servo.motion import default_demo_motion, load_motion
    from servo.runner import RealtimeRunner
    from vmehil.calibration.store import load_store_or_nominal
    from vmehil.commands.calibration_file import calibrated
    from vmehil.commands.run_results import finish_run
    from vmehil.option_groups.trace_options import Attached
    from vmehil.rig_setup.real_bus import RealBusRefused, open_bus, prepare_real_rig
    from vmehil.rig_setup.session import build_loop
    from vmehil.writers.files import write_json

    refused = refused_on_a_real_bus(opts)
    if refused:
        print(f"vmehil run --bus {opts.bus}: not with " + "; ".join(refused) + " (docs/vme-user.md)",
              file=sys.stderr)
        return 2
    n = rig.n_joints
    # everything read from files first: a bad motion file or calibration stops here, bus untouched
    motion = load_motion(opts.motion, n) if opts.motion else default_demo_motion(n)
    from vmehil.option_groups.scene_options import resolve_scene

    scene = resolve_scene(opts.scene, rig, settings)
    bus = open_bus(opts.bus, **bus_options)
    try:
        # the drivers' calibration, loaded and checked as the emulated run does (a file for another
        # rig, a NaN gain: refused before anything is enabled); the boards are checked on this bus
        store = calibrated(opts.calibration, rig, lambda cal: load_store_or_nominal(cal, rig, bus=bus))
        try:
            system, checks = prepare_real_rig(rig, bus, calibration=store)
        except RealBusRefused as e:
            print(f"run: {e}", file=sys.stderr)
            return 1
        for c in checks:
            print(f"dry pass: {c.name:8s} {c.type:5s} {c.space} 0x{c.base:X}: {c.detail}", file=sys.stderr)
        print("start-up safe stop: enables low, DACs 0 V, PWM off — read back", file=sys.stderr)
        if not opts.enable_amplifiers:
            print("run: dry run only (pass --enable-amplifiers to run the loop on this bus)", file=sys.stderr)
            if opts.json:
                write_json(opts.json, {"rig": rig.name, "bus": opts.bus, "enabled": False,
                                       "dry_pass": [c.as_dict() for c in checks]})
            return 0
        duration = opts.duration if opts.duration is not None else 10.0
        n_ticks = round(duration * rig.servo_rate_hz)
        loop = build_loop(system, motion=motion, n_ticks=n_ticks, settings=settings, scene=scene)
        runner = RealtimeRunner(system, loop, **opts.pacing.runner_options())
        interrupted: BaseException | None = None
        attached: list[Attached] = []
        after = SignalsDeferred()  # a second Ctrl-C must not lose the JSON or the report
        try:
            try:
                with loop.armed(then=after):
                    print(f"run: {n_ticks} ticks ({duration:g} s) on {rig.name} over {opts.bus}, amplifiers "
                          "enabled", file=sys.stderr)
                    # a trace here has the controller's and the drivers' signals (no nets, bus or truth)
                    trace = opts.trace.start(system, loop, runner, rig=rig.name)
                    if trace is not None:
                        attached.append(Attached(trace))
                    runner.run(n_ticks)
                    runner.end_run()  # a category-1 stop, then 2 s reading the sensors
            except INTERRUPTS as e:
                interrupted = e
            finally:
                after.begin()
                for a in attached:
                    a.close()
            for late in list(after.held):
                loop.note_interruption(late, "after")
            return finish_run(opts, system, loop, runner, rig, attached,
                              interrupted or runner.ended_by or loop.interrupted_by)
        finally:
            after.end()
    finally:
        bus.close()
