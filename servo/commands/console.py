"""``vmehil console``: run the servo loop on a rig and serve the operator console on PORT.

    vmehil console --port PORT [--rig NAME|PATH] [--seed N] [--motion FILE] [--commands FILE]
                   [--gains kp=..,..] [--lockstep] [--duration S]

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
import threading


def register(sub: argparse._SubParsersAction) -> None:
    from servo.commands.run import add_rig_args

    p = sub.add_parser("console", help="run the servo loop and serve the operator console on a serial line")
    p.add_argument("--port", required=True,
                   help="pty (linked at /tmp/vmehil-console), pty:/path/link, a serial device, a pyserial URL "
                        "(loop://, socket://127.0.0.1:N) or listen://127.0.0.1:N")
    add_rig_args(p)
    p.add_argument("--motion", default=None, help="motion file to play at start (default: hold the joints)")
    p.add_argument("--commands", default=None, help="compound command file (checked at load)")
    p.add_argument("--gains", default=None, help="override every joint's gains: kp=..,kpi=..,kv=..,kvi=..")
    p.add_argument("--baud", type=int, default=115200, help="baud rate for a serial device (default 115200)")
    p.add_argument("--lockstep", action="store_true", help="do not pace ticks by the wall clock")
    p.add_argument("--duration", type=float, default=None, help="end after this many seconds of loop time")
    p.set_defaults(func=run_console)


def run_console(args: argparse.Namespace) -> int:
    from servo.commands.run import parse_gains
    from servo.console.extension import start_console
    from servo.motion import Motion, WaitMove, load_motion
    from servo.runner import LockstepRunner, RealtimeRunner
    from servo.session import build_loop
    from servo.system import build_emulated_rig

    gains = parse_gains(args.gains)
    if args.duration is not None and args.duration <= 0:
        raise ValueError("--duration must be > 0")
    system = build_emulated_rig(args.rig, seed=args.seed)
    n = system.rig.n_joints
    motion = load_motion(args.motion, n) if args.motion else Motion((WaitMove(0.0),), "hold", "<console>")
    loop = build_loop(system, motion=motion, gains=gains, n_ticks=0)
    loop.start()
    runner = LockstepRunner(system, loop) if args.lockstep else RealtimeRunner(system, loop)
    done = threading.Event()
    console = start_console(args.port, loop, runner=runner, commands=args.commands, baudrate=args.baud,
                            shutdown=done.set)
    previous = signal.signal(signal.SIGTERM, lambda *_: done.set()) if threading.current_thread() is \
        threading.main_thread() else None
    rate = system.rig.servo_rate_hz
    try:
        if args.duration is not None:
            runner.run(round(args.duration * rate), stop=done.is_set)
        else:
            while not done.is_set():
                runner.run(round(60 * rate), stop=done.is_set)
                if hasattr(runner, "timing"):
                    runner.timing.compute_s.clear()
                    runner.timing.lateness_s.clear()
    except KeyboardInterrupt:
        pass
    finally:
        fault = loop.fault
        if not loop.fault:
            loop.safe_stop("session_end", "vmehil console ended")
        console.close()
        system.close()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    print(f"vmehil console: {loop.tick_count} ticks ({loop.tick_count * loop.period_s:.3f} s), "
          f"{console.stats.handled} commands, stopped: {fault.cause if fault else '-'}")
    return 0
