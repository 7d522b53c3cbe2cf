"""``vmehil run --fault NAME[@T][:key=value,...]`` (repeatable), ``--faults FILE`` and
``--fault list`` (a ``RUN_EXTENSIONS`` module of :mod:`vmehil.commands.run`).

The faults are those of :data:`vmehil.fault_scenarios.injection.CATALOGUE`; they are checked before the
rig is built (names, parameters, joints and boards of the rig, the options they need) and
injected at their ticks. The summary JSON gets ``injected_faults`` (each with the tick it struck
and the emulator part and pin it hit) and ``stop`` (:func:`vmehil.fault_scenarios.injection.stop_report`).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from typing import Any, Protocol

from servo.rig import RigSpec
from vmehil.errors import CliError
from vmehil.fault_scenarios.injection import (
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


@dataclass(frozen=True)
class FaultOptions:
    """``--fault`` (each as given) and ``--faults``; parsed into faults by :func:`scenario`."""

    specs: tuple[str, ...] = ()
    file: str | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> FaultOptions:
        return cls(specs=tuple(args.fault or ()), file=args.faults)

    @property
    def wants_list(self) -> bool:
        """``--fault list``: print the catalogue instead of running."""
        return LIST in self.specs


class RunNeeds(Protocol):
    """What of ``vmehil run``'s options (:class:`vmehil.commands.run_options.RunOptions`) the faults read."""

    @property
    def faults(self) -> FaultOptions: ...
    @property
    def plant_over_can(self) -> bool: ...
    @property
    def vision_mode(self) -> str | None: ...
    @property
    def seed(self) -> int: ...


def list_faults() -> int:
    print(catalogue_text())
    return 0


def scenario(options: FaultOptions) -> list[ScheduledFault]:
    """Every fault of ``--fault`` and ``--faults``, parsed and checked (defaults filled in)."""
    faults = [parse_fault_spec(text) for text in options.specs if text != LIST]
    if options.file:
        faults += load_scenario(options.file)
    return faults


def _check_needs(faults: list[ScheduledFault], run: RunNeeds) -> None:
    for f in faults:
        name = f.kind.name
        if name.startswith("can_") and not run.plant_over_can:
            raise CliError(f"{f.source}: {name} needs the plant over CAN (--plant can)")
        if name == "vision_death" and run.vision_mode != "inprocess":
            raise CliError(f"{f.source}: vision_death needs the vision system in this process (--vision inprocess)")


@dataclass(frozen=True)
class FaultPreparation:
    """The run's scenario, parsed and checked before the rig is built."""

    faults: tuple[ScheduledFault, ...]
    defaults: dict[str, Any] = field(default_factory=dict)  #: none: the faults change no run default

    def close(self) -> None:
        """Nothing to release."""


def prepare(run: RunNeeds, rig: RigSpec) -> FaultPreparation | None:
    """Before the rig is built: parse and check the scenario, so that a typo costs no run."""
    faults = scenario(run.faults)
    check_rig(faults, rig)
    _check_needs(faults, run)
    return FaultPreparation(tuple(faults))


class _Attachment:
    def __init__(self, schedule: FaultSchedule, loop: Any) -> None:
        self.schedule, self.loop = schedule, loop

    def close(self) -> None:
        """Nothing to release (the emulators' faults end with the run)."""

    def add_to_summary(self, summary: dict[str, Any]) -> None:
        summary["injected_faults"] = [f.as_dict() for f in self.schedule.faults]
        summary["stop"] = stop_report(self.loop, self.schedule.first_tick, self.schedule.joint)


def attach(run: RunNeeds, system: Any, loop: Any, runner: Any,
           prepared: FaultPreparation | None = None) -> _Attachment | None:
    faults = list(prepared.faults) if prepared is not None else []
    if not faults:
        return None
    schedule = FaultSchedule(faults, FaultContext(system, loop, run.seed))
    schedule.attach(runner)
    for f in faults:
        print(announcement(f))
    return _Attachment(schedule, loop)
