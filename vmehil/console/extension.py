"""``vmehil run --console PORT [--console-commands FILE]``: serve the operator console beside a run.

Registered in :data:`vmehil.commands.run.RUN_EXTENSIONS`. ``attach`` opens the port, loads the
compound command file (errors name file:line:column and end the run before it starts), hooks the
console into the runner's ``after_tick`` and starts its threads; the run closes it at the end.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from servo.control.linear import delay_periods
from vmehil.console.calibrate import calibrator_for
from vmehil.console.compound import CompoundLibrary, load_compound_file
from vmehil.console.server import Console, PtyTransport, open_transport


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("operator console (docs/console.md)")
    g.add_argument("--console", metavar="PORT", default=None,
                   help="serve the console on PORT: pty (a new pty linked at /tmp/vmehil-console), pty:/path/link, "
                        "a serial device, a pyserial URL (loop://, socket://127.0.0.1:N) or listen://127.0.0.1:N")
    g.add_argument("--console-commands", metavar="FILE", default=None,
                   help="compound command file loaded (and checked) at start")
    g.add_argument("--console-baud", metavar="BAUD", type=int, default=115200,
                   help="baud rate for a serial device (default 115200)")


def start_console(port: str, loop: Any, *, runner: Any = None, commands: str | None = None,
                  baudrate: int = 115200, shutdown: Callable[[], None] | None = None,
                  announce: Callable[[str], None] | None = None, system: Any = None,
                  calibration: str | Path | None = None, jobs_on_tick: bool = True) -> Console:
    """Open ``port``, load ``commands`` (compound file), hook into ``runner.after_tick`` and start.

    ``system``: the emulated rig the loop drives (default ``runner.plant``) — it makes ``calibrate``
    available, writing ``calibration`` (default: the rig's calibration file). ``jobs_on_tick``:
    see :class:`Console` (``vmehil console`` runs jobs between its runner chunks instead)."""
    library = (load_compound_file(commands, n_joints=loop.n, names=list(loop.names)) if commands
               else CompoundLibrary())
    delay = 0.0
    period_s = getattr(runner, "period_s", 0) if runner is not None else 0
    if period_s:
        delay = delay_periods(getattr(runner, "delay_s", 0.0), period_s)
    transport = open_transport(port, baudrate=baudrate)
    if system is None and runner is not None:
        system = getattr(runner, "plant", None)
    calibrate = calibrator_for(system, calibration) if system is not None else None
    console = Console(loop, transport, delay=delay, library=library, shutdown=shutdown, calibrate=calibrate,
                      jobs_on_tick=jobs_on_tick)
    if runner is not None:
        runner.after_tick.append(console.on_tick)
    console.start()
    if announce is None:
        def announce(text: str) -> None:
            sys.stderr.write(text + "\n")
            sys.stderr.flush()
    if isinstance(transport, PtyTransport):
        announce(f"console: pty {transport.slave_path}" + (f", linked at {transport.link}" if transport.link else "")
                 + f" — open it with: picocom {transport.link or transport.slave_path}")
    else:
        announce(f"console: {transport.description}")
    if library:
        announce(f"console: {len(library)} compound command(s) from {commands}: {', '.join(library)}")
    return console


def attach(args: argparse.Namespace, system: Any, loop: Any, runner: Any) -> Console | None:
    port = getattr(args, "console", None)
    if not port:
        if getattr(args, "console_commands", None):
            raise ValueError("--console-commands needs --console PORT")
        return None
    from vmehil.calibration.store import default_store_path

    calibration = getattr(args, "calibration", None) or (default_store_path(system.rig) if system is not None
                                                         else None)
    return start_console(port, loop, runner=runner, commands=args.console_commands, baudrate=args.console_baud,
                         system=system, calibration=calibration)
