"""The ``vmehil`` command line. Each subcommand lives in :mod:`vmehil.commands`."""

from __future__ import annotations

import os

# One BLAS thread unless the user says otherwise — set before anything imports numpy/scipy. The
# largest matrix vmehil multiplies is ~8×8 (the analysis' sampled loops, the plant's joints):
# a BLAS thread pool only adds hand-offs, and on a shared 2-core machine its spinning threads
# made `tune limit-cycle`'s describing-function search 3× slower (48 s → 16 s, docs/benchmarks.md);
# sweep workers (one per core) would each bring a pool of their own.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402  (after the BLAS setting above)
import signal  # noqa: E402
import sys  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Callable  # noqa: E402

from emulators.errors import EmulatorError  # noqa: E402
from hal.errors import HalError  # noqa: E402
from hal.vme.errors import VmeError  # noqa: E402
from servo.errors import ServoError  # noqa: E402
from servo.interrupts import (  # noqa: E402
    DEFERRED_SIGNALS,
    EXIT_SIGINT,
    EXIT_SIGTERM,
    Terminated,
    interrupt_exit_status,
    interrupt_name,
    stop_signals_raise,
)
from vmehil import cli_style  # noqa: E402
from vmehil.commands import calibrate, console, crate, plan, plant_node, reproduce, run, trace, tune, vision  # noqa: E402
from vmehil.commands import unit_coordinate as units  # noqa: E402
from vmehil.commands.errors import CliError  # noqa: E402
from vmehil.errors import VmehilError  # noqa: E402
from vmehil.exit_status import EXIT_BROKEN_PIPE, EXIT_UNEXPECTED, EXIT_USAGE  # noqa: E402
from vmehil.writers.output_paths import OutputPaths, check_outputs, mark_output_dirs, remove_unused  # noqa: E402

__all__ = ["COMMANDS", "ROOTS", "CliError", "build_parser", "main"]

# Every typed error of ours derives from one of the four package roots (tests/test_exception_roots.py).
ROOTS = (HalError, EmulatorError, ServoError, VmehilError)

# The subcommands, in the order of `vmehil --help`; each ``register(subparsers)`` adds its parser
# and sets two defaults on it: ``options``, the one step that reads the parsed namespace into the
# command's typed options (a frozen dataclass's ``from_args``), and ``func``, the command, which
# receives those options: nothing below this module sees the namespace.
COMMANDS: tuple[Callable[[argparse._SubParsersAction], None], ...] = (
    crate.register,
    run.register,
    plan.register,
    tune.register,
    vision.register,
    plant_node.register,
    units.register,
    console.register,
    calibrate.register,
    reproduce.register,
    trace.register,
)


def build_parser() -> argparse.ArgumentParser:
    parser = cli_style.VmehilArgumentParser(
        prog="vmehil",
        description="VME hardware-in-the-loop emulation, drivers and servo tools for robot joints.",
    )
    parser.add_argument("--debug", action="store_true",
                        help="show the traceback of an unexpected error (also VMEHIL_DEBUG=1); anywhere on the line")
    parser.add_argument("--force", action="store_true",
                        help="overwrite output files and directories vmehil did not write; anywhere on the line")
    parser.add_argument("--version", action="version", version=f"vmehil {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for register in COMMANDS:
        register(sub)
    cli_style.apply(parser)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vmehil")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "(not installed)"


def main(argv: list[str] | None = None) -> int:
    # --debug is accepted anywhere on the line (before or after the subcommand)
    process = argv is None  # the program itself, not a call from Python
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv or os.environ.get("VMEHIL_DEBUG", "") not in ("", "0")
    force = "--force" in argv  # overwrite output files that vmehil did not write (vmehil.writers.output_paths)
    argv = [a for a in argv if a not in ("--debug", "--force")]
    parser = build_parser()
    if not argv:  # bare `vmehil`: the commands, not argparse's "the following arguments are required"
        parser.print_help()
        return EXIT_USAGE
    args = parser.parse_args(argv)
    made: list = []
    try:
        outputs = OutputPaths.from_args(args)
        made = check_outputs(outputs, force=force)
        try:
            with stop_signals_raise():
                status = _ending(int(args.func(args.options(args)) or 0), process)
        finally:
            mark_output_dirs(outputs)
        if status == EXIT_USAGE:  # refused (bad input, a missing extra): the folders made for it go again
            remove_unused(made)
        return status
    except (HalError, EmulatorError, ServoError, VmehilError, FileNotFoundError) as e:
        if not _bad_input(e):
            return _unexpected(args.command, e, debug)
        if debug:
            traceback.print_exc()
        print(f"vmehil {args.command}: error: {e}", file=sys.stderr)
        remove_unused(made)  # refused: the output folders made for it go again
        return EXIT_USAGE
    except BrokenPipeError as e:
        if not _stdout_closed():  # another pipe or socket: not the reader of our output
            return _unexpected(args.command, e, debug)
        # the reader of stdout went away (`| head`): end quietly, as a shell tool does; the
        # interpreter's own flush at exit must not fail again
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except (KeyboardInterrupt, Terminated) as e:
        status = _ending(interrupt_exit_status(e), process)
        print(f"vmehil {args.command}: interrupted ({interrupt_name(e)})", file=sys.stderr)
        return status
    except Exception as e:
        return _unexpected(args.command, e, debug)


def _ending(status: int, process: bool) -> int:
    """A program ending by a signal (status 130/143, its stop done, its results written) ignores
    further signals while it exits: a burst of them must not kill the interpreter's shutdown and
    turn the exit status into a death by signal (docs/safe-stop.md, "A second signal")."""
    if process and status in (EXIT_SIGINT, EXIT_SIGTERM):
        for s in DEFERRED_SIGNALS:
            signal.signal(s, signal.SIG_IGN)
    return status


def _bad_input(e: BaseException) -> bool:
    """Bad input (exit 2, nothing moved) is what the argument and file checks refuse, with their
    typed errors: a refused value (a typed error that is also a ``ValueError``: ``ConfigError``,
    ``FaultSpecError``, ``GainError``…), a ``CliError``, the bus configuration (``VmeError``), a
    file that is not there. Any other error — a typed runtime one, or a ``ValueError`` from numpy
    or a bug — is unexpected (exit 3), never reported as the user's mistake."""
    if isinstance(e, FileNotFoundError):
        return True
    return isinstance(e, ROOTS) and isinstance(e, (CliError, VmeError, ValueError))


def _unexpected(command: str, e: BaseException, debug: bool) -> int:
    if debug:
        traceback.print_exception(e)
    print(f"vmehil {command}: unexpected error: {type(e).__name__}: {e} "
          "(run with --debug or VMEHIL_DEBUG=1 for the traceback)", file=sys.stderr)
    return EXIT_UNEXPECTED


def _stdout_closed() -> bool:
    """Whether stdout is a pipe whose reader has gone (poll reports an error on its write end)."""
    import select

    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(ev & select.POLLERR for _, ev in poller.poll(0))
    except (OSError, ValueError, AttributeError):
        return False


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
