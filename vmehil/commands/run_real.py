"""``vmehil run --bus vme_user[:DIR] --rig FILE``: the same drivers and loop on a real crate.

Dry pass (every board's ID and status against the rig file) and a start-up safe stop read back
come first (:mod:`vmehil.real_bus`); without ``--enable-amplifiers`` the run ends there. With
it, the loop runs paced by the wall clock (:class:`servo.runner.RealtimeRunner`) with the plant
boundary :class:`servo.boundary.WallClockPlant`, inside ``loop.armed()``: whatever ends it ends
with enables low, DACs at 0 V and PWM off, read back.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from servo.settings import ServoSettings
    from vmehil.commands.run_options import RunOptions


def run_on_real_bus(opts: RunOptions, rig, settings: ServoSettings, *,
                    exit_status: Callable[[Any, BaseException | None], int], **bus_options: Any) -> int:
    """``settings``: the rig's servo settings with the command line's override applied
    (:meth:`servo.settings.ServoSettings.overridden`). ``exit_status``:
    ``vmehil.commands.run.run_exit_status`` (passed in: no import cycle); ``bus_options`` go to
    :class:`hal.vme.vme_user.VmeUserBus` (tests inject a clock)."""
    from servo.interrupts import Terminated
    from servo.motion import default_demo_motion, load_motion
    from servo.runner import RealtimeRunner
    from vmehil.real_bus import RealBusRefused, open_bus, prepare_real_rig
    from vmehil.run_report import summarize, table
    from vmehil.session import build_loop

    bus = open_bus(opts.bus, **bus_options)
    try:
        try:
            system, checks = prepare_real_rig(rig, bus)
        except RealBusRefused as e:
            print(f"run: {e}", file=sys.stderr)
            return 1
        for c in checks:
            print(f"dry pass: {c.name:8s} {c.type:5s} {c.space} 0x{c.base:X}: {c.detail}", file=sys.stderr)
        print("start-up safe stop: enables low, DACs 0 V, PWM off — read back", file=sys.stderr)
        if not opts.enable_amplifiers:
            print("run: dry run only (pass --enable-amplifiers to run the loop on this bus)", file=sys.stderr)
            return 0
        n = rig.n_joints
        motion = load_motion(opts.motion, n) if opts.motion else default_demo_motion(n)
        duration = opts.duration if opts.duration is not None else 10.0
        n_ticks = round(duration * rig.servo_rate_hz)
        loop = build_loop(system, motion=motion, n_ticks=n_ticks, settings=settings)
        runner = RealtimeRunner(system, loop)
        interrupted: BaseException | None = None
        try:
            with loop.armed():
                print(f"run: {n_ticks} ticks ({duration:g} s) on {rig.name} over {opts.bus}, amplifiers enabled",
                      file=sys.stderr)
                runner.run(n_ticks)
        except (KeyboardInterrupt, Terminated) as e:
            interrupted = e
        summary = summarize(loop, rig=rig.name, seed=0, realtime=True, overruns=runner.overruns,
                            timing=runner.timing.summary(rig.period_s))
        print(table(summary))
        return exit_status(loop, interrupted or runner.ended_by)
    finally:
        bus.close()
