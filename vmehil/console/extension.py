"""``vmehil run --console PORT [--console-commands FILE] [--console-prompt/--console-echo auto|on|off]``:
serve the operator console beside a run.

Registered in :data:`vmehil.commands.run.RUN_EXTENSIONS`. ``attach`` opens the port, loads the
compound command file (errors name file:line:column and end the run before it starts), hooks the
console into the runner's ``after_tick`` and starts its threads; the run closes it at the end.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from servo.control.linear import delay_periods
from vmehil.console.calibrate import calibrator_for
from vmehil.console.compound import CompoundLibrary, load_compound_file
from vmehil.console.server import Console, PtyTransport, open_transport
from vmehil.errors import CliError
from vmehil.option_groups.cli_types import bounded_int

#: ``--console-prompt`` / ``--console-echo`` values; auto = on for a pty or serial device (a
#: person at a terminal), off for network and pyserial URLs (programs)
TERMINAL_CHOICES = ("auto", "on", "off")
PROMPT = "> "


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("operator console (docs/console.md)")
    add_console_arguments(g)  # type: ignore[arg-type]


def add_console_arguments(g: argparse.ArgumentParser, *, standalone: bool = False) -> None:
    """The console's options, one spelling for ``vmehil run`` and ``vmehil console``; the
    standalone command keeps its shipped spellings (``--port``, ``--commands``, ``--baud``) as
    aliases, and its port defaults to ``pty``."""
    alias = (lambda name: (name,)) if standalone else (lambda name: ())
    g.add_argument("--console", *alias("--port"), dest="console", metavar="PORT", default="pty" if standalone else None,
                   help="serve the console on PORT: pty (a new pty linked at /tmp/vmehil-console"
                        + ("; the default" if standalone else "") + "), pty:/path/link, a serial device, "
                        "a pyserial URL (loop://, socket://127.0.0.1:N) or listen://127.0.0.1:N")
    g.add_argument("--console-commands", *alias("--commands"), dest="console_commands", metavar="FILE", default=None,
                   help="compound command file loaded (and checked) at start")
    g.add_argument("--console-baud", *alias("--baud"), dest="console_baud", metavar="BAUD",
                   type=bounded_int(50, 4_000_000, what="a baud rate"), default=115200,
                   help="baud rate for a serial device (default 115200)")
    g.add_argument("--console-prompt", choices=TERMINAL_CHOICES, default="auto",
                   help=f"show the prompt {PROMPT.strip()!r} (auto: on a pty or serial device, off for network ports)")
    g.add_argument("--console-echo", choices=TERMINAL_CHOICES, default="auto",
                   help="echo what is typed, with up/down history (auto: on a pty or serial device, off for network "
                        "ports; off when the terminal program echoes, e.g. picocom --echo)")


def is_terminal_port(port: str) -> bool:
    """Whether a person at a terminal program is the likely client: a pty or a serial device."""
    return "://" not in port


@dataclass(frozen=True)
class ConsoleOptions:
    """The console's options (``port`` None: no console beside a run). ``prompt`` and ``echo``
    default to off for a program that builds its own (as before these options); the command line
    gives auto."""

    port: str | None = None
    commands: str | None = None
    baud: int = 115200
    prompt: str = "off"
    echo: str = "off"

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> ConsoleOptions:
        return cls(port=args.console, commands=args.console_commands, baud=args.console_baud,
                   prompt=args.console_prompt, echo=args.console_echo)

    def terminal_settings(self) -> tuple[str | None, bool]:
        """(prompt, echo) from ``--console-prompt`` / ``--console-echo`` for the port."""
        port = self.port or ""

        def on(value: str) -> bool:
            return is_terminal_port(port) if value == "auto" else value == "on"

        return (PROMPT if on(self.prompt) else None, on(self.echo))


class RunNeeds(Protocol):
    """What of ``vmehil run``'s options (:class:`vmehil.commands.run_options.RunOptions`) the console reads."""

    @property
    def console(self) -> ConsoleOptions: ...
    @property
    def calibration(self) -> str | None: ...


def start_console(port: str, loop: Any, *, runner: Any = None, commands: str | None = None,
                  baudrate: int = 115200, shutdown: Callable[[], None] | None = None,
                  announce: Callable[[str], None] | None = None, system: Any = None,
                  calibration: str | Path | None = None, jobs_on_tick: bool = True, prompt: str | None = None,
                  echo: bool = False) -> Console:
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
                      jobs_on_tick=jobs_on_tick, prompt=prompt, echo=echo)
    if runner is not None:
        runner.after_tick.append(console.on_tick)
    console.start()
    if announce is None:
        def announce(text: str) -> None:
            sys.stderr.write(text + "\n")
            sys.stderr.flush()
    if isinstance(transport, PtyTransport):
        path = transport.link or transport.slave_path
        # the console echoes (or the terminal program must): the hint matches the setting
        how = f"picocom -q {'' if echo else '--echo '}{path} (quit: Ctrl-A Ctrl-X)"
        announce(f"console: pty {transport.slave_path}" + (f", linked at {transport.link}" if transport.link else "")
                 + f"; open it with: {how}")
    else:
        announce(f"console: {transport.description}")
    if library:
        announce(f"console: {len(library)} compound command(s) from {commands}: {', '.join(library)}")
    return console


def attach(run: RunNeeds, system: Any, loop: Any, runner: Any, prepared: None = None) -> Console | None:
    opts = run.console
    port = opts.port
    if not port:
        if opts.commands:
            raise CliError("--console-commands needs --console PORT")
        return None
    from vmehil.calibration.store import default_store_path

    calibration = run.calibration or (default_store_path(system.rig) if system is not None else None)
    prompt, echo = opts.terminal_settings()
    return start_console(port, loop, runner=runner, commands=opts.commands, baudrate=opts.baud,
                         system=system, calibration=calibration, prompt=prompt, echo=echo)
