"""The real-time overrun options shared by every command that paces the loop by the wall clock."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

from servo.runner import OVERRUN_POLICIES
from vmehil.option_groups.cli_types import bounded_float, bounded_int


def add_overrun_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--overrun", choices=OVERRUN_POLICIES, default="stop",
                   help="real time: what a loop that falls --max-lateness periods behind does: safe-stop "
                        "(default) or warn and run on")
    p.add_argument("--max-lateness", type=bounded_float(0.0, 1000.0, what="a lateness in periods", lo_open=True),
                   default=5.0, metavar="PERIODS",
                   help="real time: how far behind its deadline the loop may fall, in servo periods (default 5)")
    p.add_argument("--rt-priority", type=bounded_int(1, 99, what="a SCHED_FIFO priority"), default=None,
                   metavar="P",
                   help="real time: run the loop's thread under SCHED_FIFO at priority P (1..99) so ordinary "
                        "processes do not preempt a tick; needs CAP_SYS_NICE or RLIMIT_RTPRIO, and a refusal "
                        "is reported, not fatal (docs/servo-loop.md)")
    p.add_argument("--lock-memory", action="store_true",
                   help="real time: mlockall the process's memory (no page faults inside a tick); a refusal "
                        "is reported, not fatal")


@dataclass(frozen=True)
class RealtimeOptions:
    """The pacing of a command's ticks and, when paced by the wall clock, its overrun policy and
    real-time settings (``--realtime``/``--lockstep``, ``--overrun``, ``--max-lateness``,
    ``--rt-priority``, ``--lock-memory``)."""

    realtime: bool = False
    overrun: str = "stop"
    max_lateness_periods: float = 5.0
    rt_priority: int | None = None
    lock_memory: bool = False

    @classmethod
    def from_args(cls, args: argparse.Namespace, *, default: bool) -> RealtimeOptions:
        """``default``: whether the command paces by the wall clock without ``--realtime``/``--lockstep``."""
        value = getattr(args, "realtime", None)
        return cls(realtime=default if value is None else bool(value),
                   overrun=getattr(args, "overrun", "stop"), max_lateness_periods=getattr(args, "max_lateness", 5.0),
                   rt_priority=getattr(args, "rt_priority", None), lock_memory=getattr(args, "lock_memory", False))

    def runner_options(self) -> dict[str, Any]:
        """The keyword arguments of :class:`servo.runner.RealtimeRunner` these options set."""
        return {"overrun": self.overrun, "max_lateness_periods": self.max_lateness_periods,
                "rt_priority": self.rt_priority, "lock_memory": self.lock_memory}


def realtime_settings_summary(runner: object) -> dict[str, Any] | None:
    """What a paced run's real-time settings were (``applied`` and ``refused`` with the reason),
    for the run's JSON and its stderr line; ``None`` when none were asked for."""
    rt = getattr(runner, "rt_settings", None)
    if rt is None:
        return None
    return {"applied": list(rt.applied), "refused": dict(rt.refused), "described": rt.describe()}


def add_pacing_args(p: argparse.ArgumentParser, *, default: str) -> None:
    """``--realtime`` / ``--lockstep``: one spelling for the pacing of ticks in every command
    (``default``: what the command does without either, said in the help)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--realtime", dest="realtime", action="store_true", default=None,
                   help=f"pace ticks by the wall clock at the servo rate ({default})")
    g.add_argument("--lockstep", dest="realtime", action="store_false",
                   help="tick as fast as the CPU allows, on simulated time")
