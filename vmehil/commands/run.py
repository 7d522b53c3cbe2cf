"""``vmehil run``: the main job — the servo loop moving emulated joints through the full stack.

    vmehil run [--rig NAME|PATH] [--motion PATH|none] [--duration S] [--scene PATH|none]
               [--realtime|--lockstep] [--seed N]
               [--no-integrator-switch-off] [--gains kp=..,kpi=..,kv=..,kvi=..]
               [--json PATH] [--report DIR] [--quiet] [--fault NAME[@T][:k=v,...]]... [--faults FILE]

Progress: a bar on stderr when it is a terminal and ``--quiet`` is not given (:mod:`vmehil.writers.progress`).
"""

from __future__ import annotations

import argparse
import sys
from types import ModuleType
from typing import TYPE_CHECKING, Any

from servo.interrupts import INTERRUPTS, SignalsDeferred, interrupt_exit_status
from vmehil import live as live_extension
from vmehil.commands import console_port_needs_serial, refuse_without, run_units
from vmehil.commands.calibration_file import calibrated
from vmehil.commands.run_options import RunOptions
from vmehil.commands.run_results import finish_run
from vmehil.console import extension as console_extension
from vmehil.errors import CliError
from vmehil.exit_status import EXIT_FAULT
from vmehil.fault_scenarios import options as fault_options
from vmehil.mavlink import extension as mavlink_extension
from vmehil.option_groups import can_options, trace_options, vision_options
from vmehil.option_groups.cli_types import duration_s, seed
from vmehil.option_groups.realtime_options import add_overrun_args, add_pacing_args
from vmehil.option_groups.scene_options import add_scene_argument, resolve_scene

if TYPE_CHECKING:
    from servo.settings import ServoSettings

# Modules that extend `vmehil run` (live tuning over MAVLink, the operator console, ...). Each
# defines ``add_arguments(parser)``, a frozen dataclass of its options (a field of RunOptions) and
# ``attach(options, system, loop, runner, prepared)``, which returns ``None`` when its options are
# unused, or an object with ``close()`` called after the run. ``options`` is the RunOptions; each
# module declares what it reads of them as a protocol (``RunNeeds``). An extension may also define
# ``prepare(options, rig)``, called before the rig is built: it may adjust the rig table and returns
# None or a preparation with ``defaults`` (``{"motion": Motion, "duration": s}``) and ``close()``
# (called when the run ends), handed back to its ``attach`` as ``prepared``; and
# ``make_link(options, rig) -> PlantLink | None`` to run the plant elsewhere (the CAN plant node):
# the first link returned replaces the in-process plant. An attached object with
# ``add_to_summary(summary)`` adds its keys to the run's summary.
RUN_EXTENSIONS: tuple[ModuleType, ...] = (
    mavlink_extension,
    vision_options,
    can_options,
    console_extension,
    fault_options,  # after vision_options: a vision fault needs the attached vision system
    trace_options,  # last: it traces the loop the others have set up
    live_extension,  # --live (and --blackbox): last, so it sees every tick as the others left it
)


def add_rig_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rig", metavar="NAME|PATH", default=None, help="rig preset name or TOML path (default jpl-arm)")
    p.add_argument("--seed", metavar="N", type=seed, default=0, help="seed of every noise source (default 0)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run the servo loop on a rig (the main job)")
    add_rig_args(p)
    p.add_argument("--motion", default=None, metavar="PATH|none",
                   help="motion file (TOML); none: hold the joints where they are (give --duration); "
                        "default: a coordinated demo move + 10 s hold")
    p.add_argument("--duration", metavar="S", type=duration_s, default=None,
                   help="seconds to run (default: the motion, +1 s)")
    add_scene_argument(p)
    add_pacing_args(p, default="the default with --console; otherwise --lockstep is")
    add_overrun_args(p)
    p.add_argument("--no-integrator-switch-off", action="store_true", help="keep the integrators fed at rest")
    p.add_argument("--gains", default=None, metavar="kp=..,kpi=..,kv=..,kvi=..",
                   help="override every joint's gains: kp=..,kpi=..,kv=..,kvi=.. (checked by servo.gain_guard)")
    p.add_argument("--json", metavar="PATH", default=None, help="write the machine-readable summary here")
    p.add_argument("--report", metavar="DIR", default=None, help="write plots and summary.md into this folder")
    p.add_argument("--calibration", metavar="PATH", default=None,
                   help="calibration file for the drivers (default: calibration/<rig>.toml or "
                        "$VMEHIL_CALIBRATION_DIR/<rig>.toml; missing → nominal values with a warning)")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.add_argument("--bus", default="emulated",
                   help="emulated (default) or vme_user[:DIR]: a real crate (dry pass, start-up safe stop; "
                        "docs/vme-user.md)")
    p.add_argument("--enable-amplifiers", action="store_true",
                   help="on a real bus, run the loop after the dry pass (without it: the checks only)")
    for ext in RUN_EXTENSIONS:
        ext.add_arguments(p)
    run_units.add_arguments(p)
    p.set_defaults(func=run, options=RunOptions.from_args)


def run(opts: RunOptions) -> int:
    console = opts.console.port
    for option, extra, used in (("--report", "plots", bool(opts.report)),
                                ("--mavlink", "mavlink", bool(opts.mavlink.url)),
                                ("--console", "console", bool(console and console_port_needs_serial(console))),
                                ("--trace", "trace", opts.trace.wanted),
                                ("--live", "trace", opts.scope.live is not None)):
        if used and refuse_without(f"vmehil run {option}", extra):
            return 2
    opts.scope.live_address()  # a bad or non-loopback --live: one line, exit 2, before anything is built
    from emulators.presets import resolve_rig
    from servo.rig import load_rig
    from servo.settings import servo_settings
    if opts.faults.wants_list:
        return fault_options.list_faults()
    rig = load_rig(resolve_rig(opts.rig))
    if opts.trace.wants_list:
        return trace_options.list_rig_signals(rig, seed=opts.seed)
    # the servo's settings, parsed once; the command line's override applied and guarded here, once
    settings = servo_settings(rig).overridden(opts.gains, opts.integrator_switch_off)
    prepared: dict[ModuleType, Any] = {}  # the extensions' preparations, filled by _run
    try:
        return _run(opts, rig, opts.gains, settings, prepared)
    finally:
        for prep in prepared.values():  # e.g. the shared memory of --vision process
            prep.close()


def _run(opts: RunOptions, rig, gains: dict[str, float], settings: ServoSettings,
         prepared: dict[ModuleType, Any]) -> int:
    from servo.motion import NO_MOTION

    parallel = opts.units == "parallel"
    if parallel:
        refused = run_units.refused_options(opts)
        if refused:
            print("vmehil run --units parallel: not with parallel units (docs/melmalec.md, \"Options with --units "
                  "parallel\"):\n  " + "\n  ".join(refused), file=sys.stderr)
            return 2
        from servo.joint_groups import rig_units
        if not rig_units(rig):
            print(f"vmehil run --units parallel: rig {rig.name} ({rig.path}) declares no [[rig.unit]] tables",
                  file=sys.stderr)
            return 2
    if settings.require_homing and opts.motion != NO_MOTION:
        # an incremental encoder loses its count at power-off: every session homes, and a run does not
        print(f"vmehil run: rig {rig.name} requires homing before moves ([servo] require_homing; "
              "docs/motion-safety.md, \"Homing\"): `vmehil run` does not home; home and move on the console "
              f"(`home all`), or hold with --motion {NO_MOTION}", file=sys.stderr)
        return 2
    if opts.bus != "emulated":
        from vmehil.commands.run_real import run_on_real_bus
        return run_on_real_bus(opts, rig, settings)
    from servo.motion import default_demo_motion, hold_motion, load_motion
    from servo.runner import LockstepRunner, RealtimeRunner
    from vmehil.rig_setup.session import build_loop
    from vmehil.rig_setup.system import build_emulated_rig
    from vmehil.writers.progress import TickProgress

    defaults: dict = {}
    for ext in RUN_EXTENSIONS:
        prepare = getattr(ext, "prepare", None)
        prep = prepare(opts, rig) if prepare is not None else None
        if prep is not None:
            prepared[ext] = prep
            defaults.update(prep.defaults)
    n = rig.n_joints
    scene = resolve_scene(opts.scene, rig, settings)
    if opts.motion == NO_MOTION:
        if opts.duration is None and "duration" not in defaults:
            raise CliError(f"--motion {NO_MOTION} holds the joints: give --duration S (how long to run)")
        motion = hold_motion()
    else:
        motion = load_motion(opts.motion, n) if opts.motion else defaults.get("motion") or default_demo_motion(n)
    if opts.duration is not None:
        duration = opts.duration
    elif "duration" in defaults:
        duration = defaults["duration"]
    else:
        duration = _plan_checked(rig, opts.seed, motion, settings, scene) + 1.0
    if not duration > 0:
        raise CliError("--duration must be > 0")
    n_ticks = round(duration * rig.servo_rate_hz)
    if n_ticks < 1:  # 1e-9 s ran no tick at all and reported a run
        raise CliError(f"--duration {duration:g} s is shorter than one servo period ({rig.period_s * 1e3:g} ms)")
    if parallel:
        from vmehil.calibration.store import load_store_or_nominal

        if opts.duration is not None or "duration" in defaults:
            # the units plan their own segments; the whole motion is checked here all the same
            _plan_checked(rig, opts.seed, motion, settings, scene)

        # one file, the single run's loader and checks; each unit applies its own entries
        store = calibrated(opts.calibration, rig, lambda cal: load_store_or_nominal(cal, rig))
        faults = prepared.get(fault_options)
        return run_units.run_parallel(opts, rig, gains, motion, n_ticks, lambda: _make_link(opts, rig),
                                      calibration=store, faults=list(faults.faults) if faults is not None else [])
    system = _build_calibrated(opts, rig, build_emulated_rig)
    try:  # refused moves, and a trace SPEC the rig cannot meet, raise here: before armed() enables anything
        opts.trace.check(system, [j.name for j in rig.joints])
        loop = build_loop(system, motion=motion, n_ticks=n_ticks, settings=settings, scene=scene)
    except BaseException:
        system.close()
        raise
    from vmehil.rig_setup.hand_world import attach_hand_world

    attach_hand_world(system, scene, settings)  # the scene's [[object]]s between the fingers (docs/hand.md)
    runner = (RealtimeRunner(system, loop, **opts.pacing.runner_options()) if opts.realtime
              else LockstepRunner(system, loop))
    progress = TickProgress("run", quiet=opts.quiet)
    attached: list = []
    interrupted: BaseException | None = None
    # Once the run ends, signals are held (recorded, not raised) until its results are written:
    # a second Ctrl-C must not lose the JSON or the report. armed() begins this section before its
    # final stop's own ends (docs/safe-stop.md, "A second signal").
    after = SignalsDeferred()
    try:
        try:
            # armed(): whatever ends the block (its end, an exception, Ctrl-C, SIGTERM) ends with the
            # amplifiers disabled, 0 V on the DACs and PWM off, read back (loop.final_stop).
            with loop.armed(then=after):
                attached = [a for a in (ext.attach(opts, system, loop, runner, prepared.get(ext))
                                        for ext in RUN_EXTENSIONS) if a is not None]
                if not opts.quiet:
                    print(f"run: {n_ticks} ticks ({duration:g} s) on {rig.name}, amplifiers enabled", file=sys.stderr)
                with progress:
                    runner.run(n_ticks, progress=progress if progress.enabled else None)
                # a category-1 stop at the end, then 2 s watching the joints (final_stop.excursion_deg)
                runner.end_run()
        except INTERRUPTS as e:  # between ticks' reach (set-up), or held by a stop: still reported
            interrupted = e
        finally:
            after.begin()  # when armed() never got as far
            for a in attached:
                a.close()
        for late in list(after.held):
            loop.note_interruption(late, "after")
        noted = len(after.held)
        ended_by = interrupted or runner.ended_by or loop.interrupted_by
        status = finish_run(opts, system, loop, runner, rig, attached, ended_by)
        if len(after.held) > noted and status in (0, EXIT_FAULT):  # a signal while the results were written
            status = interrupt_exit_status(after.held[noted])
        return status
    except Exception:
        # an error outside the ticks (they stop on their own and end in finish_run): the loop is
        # stopped (armed()); no JSON follows, but the box of the seconds before the stop does
        if loop.final_stop is not None and "blackbox" not in loop.final_stop:
            from vmehil.reports.blackbox import save_blackbox
            save_blackbox(loop, rig=rig.name, choice=opts.scope.blackbox, report=opts.report,
                          final_stop=loop.final_stop)
        raise
    finally:
        after.end()


def _build_calibrated(opts: RunOptions, rig, build):
    """Build the rig with the drivers' calibration file; a missing file is a one-line warning."""
    return calibrated(opts.calibration, rig,
                       lambda cal: build(rig, seed=opts.seed, link=_make_link(opts, rig), calibration=cal))


def _make_link(opts: RunOptions, rig):
    """The plant link an extension asks for (``--plant can``), else ``None`` (in-process)."""
    for ext in RUN_EXTENSIONS:
        make = getattr(ext, "make_link", None)
        link = make(opts, rig) if make is not None else None
        if link is not None:
            return link
    return None


def _plan_checked(rig: Any, seed: int, motion: Any, settings: Any, scene: Any) -> float:
    """Plan ``motion`` on a probe of the rig (nothing enabled) and return its planned length (s):
    a move the soft limits or the scene refuse raises here (MotionRefused: exit 2)."""
    from vmehil.rig_setup.session import build_loop
    from vmehil.rig_setup.system import build_emulated_rig

    probe_system = build_emulated_rig(rig, seed=seed)
    try:
        return _planned_duration(build_loop(probe_system, motion=motion, n_ticks=1, settings=settings, scene=scene))
    finally:
        probe_system.close()


def _planned_duration(loop) -> float:
    """Plan every move once (on a throw-away sequencer) to learn the motion's length."""
    from servo.trajectory.base import TrajectoryError

    seq = loop.sequencer
    t = 0.0
    try:
        seq.sample(0.0)
        while not seq.finished and t < 3600.0:
            t += max(seq.current.duration, 1e-3)
            seq.sample(t)
    except TrajectoryError as e:
        raise CliError(f"{e}; or give --duration") from None
    return float(seq.total_duration or t)

