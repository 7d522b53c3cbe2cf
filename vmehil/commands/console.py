"""``vmehil console``: run the servo loop on a rig and serve the operator console on PORT.

    vmehil console [--console PORT] [--rig NAME|PATH] [--seed N] [--motion FILE|none] [--scene PATH|none]
                   [--console-commands FILE] [--console-prompt/--console-echo auto|on|off]
                   [--gains kp=..,..] [--realtime|--lockstep] [--duration S] [--json PATH]

(shipped spellings kept as aliases: ``--port``, ``--commands``, ``--baud``; PORT defaults to pty)

Design: the console attaches to a loop in the same process. ``vmehil console`` is that process —
it builds the rig and the loop the way ``vmehil run`` does, holds the joints where they are (or
plays ``--motion``), paces ticks by the wall clock (``--lockstep``: as fast as possible) and runs
until ``shutdown`` on the console, Ctrl-C, or ``--duration`` seconds. To add a console to a
measured run instead, use ``vmehil run --console PORT``. To reach either from another program,
serve on ``listen://127.0.0.1:N`` and connect with ``socket://127.0.0.1:N``.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from servo.control.gains import parse_gains
from servo.interrupts import Terminated, interrupt_name
from vmehil.console.extension import ConsoleOptions
from vmehil.errors import CliError
from vmehil.option_groups import trace_options
from vmehil.option_groups.cli_types import duration_s
from vmehil.option_groups.realtime_options import RealtimeOptions, add_overrun_args, add_pacing_args
from vmehil.option_groups.scene_options import add_scene_argument
from vmehil.option_groups.scope_options import ScopeOptions, add_scope_arguments
from vmehil.option_groups.trace_options import TraceOptions
from vmehil.reports.run_report import excursion_text
from vmehil.writers.files import write_json


def register(sub: argparse._SubParsersAction) -> None:
    from vmehil.commands.run import add_rig_args
    from vmehil.console.extension import add_console_arguments

    p = sub.add_parser("console", help="run the servo loop and serve the operator console on a serial line")
    add_console_arguments(p, standalone=True)
    add_rig_args(p)
    p.add_argument("--motion", default=None, metavar="PATH|none",
                   help="motion file to play at start (default, and none: hold the joints)")
    add_scene_argument(p)
    p.add_argument("--gains", default=None, metavar="kp=..,kpi=..,kv=..,kvi=..",
                   help="override every joint's gains: kp=..,kpi=..,kv=..,kvi=..")
    add_pacing_args(p, default="the default")
    add_overrun_args(p)
    p.add_argument("--duration", metavar="S", type=duration_s, default=None,
                   help="end after this many seconds of loop time")
    p.add_argument("--calibration", metavar="PATH", default=None,
                   help="calibration file for the drivers, and where the console's calibrate writes "
                        "(default: calibration/<rig>.toml or $VMEHIL_CALIBRATION_DIR/<rig>.toml)")
    p.add_argument("--json", default=None, metavar="PATH",
                   help="write the session's summary here at exit (ticks, commands, how it stopped)")
    trace_options.add_arguments(p)
    add_scope_arguments(p)
    p.set_defaults(func=run_console, options=ConsoleCommandOptions.from_args)


@dataclass(frozen=True)
class ConsoleCommandOptions:
    """``vmehil console``'s options (``gains``: ``--gains`` parsed; paced by the wall clock unless
    ``--lockstep``)."""

    console: ConsoleOptions
    rig: str | None = None
    seed: int = 0
    motion: str | None = None
    gains: dict[str, float] = field(default_factory=dict)
    pacing: RealtimeOptions = field(default_factory=lambda: RealtimeOptions(realtime=True))
    duration: float | None = None
    calibration: str | None = None
    json: str | None = None
    scene: str | None = None
    trace: TraceOptions = field(default_factory=TraceOptions)
    scope: ScopeOptions = field(default_factory=ScopeOptions)

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> ConsoleCommandOptions:
        return cls(console=ConsoleOptions.from_args(args), rig=args.rig, seed=args.seed, motion=args.motion,
                   gains=parse_gains(args.gains, what="--gains"), pacing=RealtimeOptions.from_args(args, default=True),
                   duration=args.duration, calibration=args.calibration, json=args.json, scene=args.scene,
                   trace=TraceOptions.from_args(args), scope=ScopeOptions.from_args(args))


def run_console(opts: ConsoleCommandOptions) -> int:
    from vmehil.commands import console_port_needs_serial, refuse_without

    port = opts.console.port
    assert port is not None  # the parser's default: a new pty
    if console_port_needs_serial(port) and refuse_without("vmehil console --console " + port, "console"):
        return 2
    if opts.trace.wanted and refuse_without("vmehil console --trace", "trace"):
        return 2
    if opts.scope.live is not None and refuse_without("vmehil console --live", "trace"):
        return 2
    opts.scope.live_address()  # a bad or non-loopback --live: one line, exit 2, before anything is built
    from servo.motion import NO_MOTION, hold_motion, load_motion
    from servo.rig import load_rig
    from servo.runner import LockstepRunner, RealtimeRunner
    from vmehil.calibration.store import CalibrationMissingWarning, default_store_path
    from vmehil.console.extension import start_console
    from vmehil.live import open_live
    from vmehil.reports.blackbox import save_blackbox
    from vmehil.rig_setup.session import build_loop
    from vmehil.rig_setup.system import build_emulated_rig

    gains = opts.gains  # values and stability: once, in build_loop
    if opts.duration is not None and opts.duration <= 0:
        raise CliError("--duration must be > 0")
    from emulators.presets import resolve_rig

    rig = load_rig(resolve_rig(opts.rig))
    if opts.trace.wants_list:
        return trace_options.list_rig_signals(rig, seed=opts.seed)
    calibration = opts.calibration or str(default_store_path(rig))
    if opts.calibration and not Path(opts.calibration).exists():
        raise FileNotFoundError(f"--calibration {opts.calibration}: no such file")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationMissingWarning)
        system = build_emulated_rig(rig, seed=opts.seed, calibration=calibration)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    if not caught:
        print(f"calibration: {calibration}", file=sys.stderr)
    try:
        opts.trace.check(system, [j.name for j in rig.joints])  # a SPEC the rig cannot meet: before arming
    except BaseException:
        system.close()
        raise
    n = system.rig.n_joints
    motion = (load_motion(opts.motion, n) if opts.motion and opts.motion != NO_MOTION
              else hold_motion("<console>"))
    from servo.settings import servo_settings
    from vmehil.option_groups.scene_options import resolve_scene
    from vmehil.rig_setup.hand_world import attach_hand_world

    settings = servo_settings(rig)
    try:  # a --motion the soft limits or the scene refuse: refused before anything is enabled
        scene = resolve_scene(opts.scene, rig, settings)
        loop = build_loop(system, motion=motion, gains=gains, n_ticks=0, settings=settings, scene=scene)
    except BaseException:
        system.close()
        raise
    attach_hand_world(system, scene, settings)  # the scene's [[object]]s between the fingers (docs/hand.md)
    paced = opts.pacing.realtime
    runner = RealtimeRunner(system, loop, **opts.pacing.runner_options()) if paced else LockstepRunner(system, loop)
    try:
        live = open_live(opts.scope, loop.names, loop.period_s)  # before the amplifiers are enabled
    except BaseException:
        system.close()
        raise
    if live is not None:
        runner.after_tick.append(live.after_tick)
    loop.start()
    try:
        trace = opts.trace.start(system, loop, runner, rig=rig.name, seed=opts.seed)
    except BaseException:
        loop.safe_stop("exception", "the trace could not start")
        if live is not None:
            live.close()
        system.close()
        raise
    done = threading.Event()
    # calibrate jobs run here between runner chunks (not inside a tick hook), so a wall-clock
    # runner restarts its deadlines after a calibration instead of catching up on them
    prompt, echo = opts.console.terminal_settings()
    console = start_console(port, loop, runner=runner, commands=opts.console.commands,
                            baudrate=opts.console.baud, shutdown=done.set, system=system, calibration=calibration,
                            jobs_on_tick=False, prompt=prompt, echo=echo)
    # SIGTERM ends the session between runner chunks like the console's own `quit`
    previous = signal.signal(signal.SIGTERM, lambda *_: done.set()) if threading.current_thread() is \
        threading.main_thread() else None
    rate = system.rig.servo_rate_hz
    try:
        remaining = round(opts.duration * rate) if opts.duration is not None else None
        while not done.is_set() and (remaining is None or remaining > 0):
            chunk = round(60 * rate) if remaining is None else min(remaining, round(60 * rate))
            k0 = loop.tick_count
            runner.run(chunk, stop=lambda: done.is_set() or console.job_waiting())
            console.run_job()  # a calibration: between ticks, the loop's own thread
            if remaining is not None:
                remaining -= loop.tick_count - k0
            if hasattr(runner, "timing"):
                for series in (runner.timing.compute_s, runner.timing.lateness_s, runner.timing.controller_s,
                               runner.timing.harness_s):
                    series.clear()
    except (KeyboardInterrupt, Terminated) as e:
        runner.stop_by_category("interrupted", f"{interrupt_name(e)} received")  # category 1
    except Exception as e:
        loop.safe_stop("exception", f"{type(e).__name__}: {e}")
        raise
    finally:
        try:
            # a loop still servoing stops by category 1 (decelerate, brakes, power off); then the
            # joints are watched 2 s (EVT stop … excursion_deg=…); a signal ends the window at once
            runner.end_run(cause="session_end", detail="vmehil console ended")
        except (KeyboardInterrupt, Terminated):
            pass
        finally:
            if loop.enabled or loop.stopping is not None:
                loop.safe_stop("session_end", "vmehil console ended")
            console.announce_stop()
        fault = loop.fault
        if live is not None:
            live.finish(loop)
            live.close()
        console.close()
        if trace is not None:
            trace.close()
        system.close()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    final = loop.stop_summary()
    # the session's last seconds before its stop, named in the JSON (docs/scope.md, "Black box")
    save_blackbox(loop, rig=system.rig.name, choice=opts.scope.blackbox, report=None, final_stop=final)
    print(f"vmehil console: {loop.tick_count} ticks ({loop.tick_count * loop.period_s:.3f} s), "
          f"{console.stats.handled} commands, stopped: {fault.cause if fault else '-'}")
    print(f"final stop: {final['cause'] or '-'} (category {final['category']}); "
          f"{excursion_text(final['excursion_deg'])}")
    if opts.json:
        out = summary(loop, console, system.rig.name, paced=paced, fault=fault, final_stop=final)
        if trace is not None:
            out["trace"] = trace.summary()
        write_json(opts.json, out)
    return 0


def summary(loop, console, rig: str, *, paced: bool, fault, final_stop: dict | None = None) -> dict:
    """The ``--json`` summary of a console session: what ran, what was asked, how it stopped
    (``final_stop``: the last stop's summary as reported, with its ``blackbox``; default: the loop's)."""
    s = console.stats
    return {
        "rig": rig, "mode": "realtime" if paced else "lockstep", "ticks": loop.tick_count,
        "loop_s": loop.tick_count * loop.period_s, "commands": s.handled, "lines": s.lines, "busy": s.busy,
        "long": s.long, "binary": s.binary, "dropped_out": s.dropped_out,
        "stopped": None if fault is None else {"cause": fault.cause, "detail": fault.detail, "tick": fault.tick},
        "stop_incomplete": bool(getattr(loop, "stop_incomplete", False)),
        "final_stop": final_stop if final_stop is not None else loop.stop_summary(),
    }
