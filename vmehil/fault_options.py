"""``vmehil run --fault NAME[@T][:key=value,...]`` (repeatable), ``--faults FILE`` and
``--fault list`` (a ``RUN_EXTENSIONS`` module of :mod:`vmehil.commands.run`).

The faults are those of :data:`vmehil.fault_injection.CATALOGUE`; they are checked before the
rig is built (names, parameters, joints and boards of the rig, the options they need) and
injected at their ticks. The summary JSON gets ``injected_faults`` (each with the tick it struck
and the emulator part and pin it hit) and ``stop`` (:func:`vmehil.fault_injection.stop_report`).
"""

from __future__ import annotations

import argparse
from typing import Any

from servo.rig import RigSpec
from vmehil.fault_injection import (
    FaultContext,
    FaultSchedule,
    ScheduledFault,
    announcement,
    catalogue_text,
    check_rig,
    load_scenario,
    parse_fault_spec,
    stop_report,
)

LIST = "list"


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("fault injection (docs/faults.md)")
    g.add_argument("--fault", action="append", default=None, metavar="NAME[@T][:key=value,...]",
                   help="inject a named fault at T s of simulated time (default 0), e.g. pot_frozen@0.8:joint=j1; "
                        "repeatable; `--fault list` lists the faults and their parameters")
    g.add_argument("--faults", default=None, metavar="FILE",
                   help="a TOML scenario: [[fault]] tables with name, at_s and params = {...}")


def wants_list(args: argparse.Namespace) -> bool:
    """``--fault list``: print the catalogue instead of running."""
    return LIST in (getattr(args, "fault", None) or [])


def list_faults() -> int:
    print(catalogue_text())
    return 0


def scenario(args: argparse.Namespace) -> list[ScheduledFault]:
    """Every fault of ``--fault`` and ``--faults``, parsed and checked (defaults filled in)."""
    faults = [parse_fault_spec(text) for text in (getattr(args, "fault", None) or []) if text != LIST]
    if getattr(args, "faults", None):
        faults += load_scenario(args.faults)
    return faults


def _check_needs(faults: list[ScheduledFault], args: argparse.Namespace) -> None:
    for f in faults:
        name = f.kind.name
        if name.startswith("can_") and getattr(args, "plant", "inprocess") != "can":
            raise ValueError(f"{f.source}: {name} needs the plant over CAN (--plant can)")
        if name == "vision_death" and getattr(args, "vision", None) != "inprocess":
            raise ValueError(f"{f.source}: vision_death needs the vision system in this process (--vision inprocess)")


def prepare(args: argparse.Namespace, rig: RigSpec) -> dict[str, Any] | None:
    """Before the rig is built: parse and check the scenario, so that a typo costs no run."""
    faults = scenario(args)
    check_rig(faults, rig)
    _check_needs(faults, args)
    args._fault_scenario = faults
    return None


class _Attachment:
    def __init__(self, schedule: FaultSchedule, loop: Any) -> None:
        self.schedule, self.loop = schedule, loop

    def close(self) -> None:
        """Nothing to release (the emulators' faults end with the run)."""

    def add_to_summary(self, summary: dict[str, Any]) -> None:
        summary["injected_faults"] = [f.as_dict() for f in self.schedule.faults]
        summary["stop"] = stop_report(self.loop, self.schedule.first_tick, self.schedule.joint)


def attach(args: argparse.Namespace, system: Any, loop: Any, runner: Any) -> _Attachment | None:
    faults = getattr(args, "_fault_scenario", None)
    if not faults:
        return None
    schedule = FaultSchedule(faults, FaultContext(system, loop, args.seed))
    schedule.attach(runner)
    for f in faults:
        print(announcement(f))
    return _Attachment(schedule, loop)
