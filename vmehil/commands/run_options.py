"""``vmehil run``'s options, typed: read from the parsed command line once
(:meth:`RunOptions.from_args`, the parser's ``options`` default) and passed on to the run, its
extensions (``RUN_EXTENSIONS``: each reads its own group through a small ``RunNeeds`` protocol),
the real-bus path and the parallel units.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

from servo.control.gains import parse_gains
from vmehil.console.extension import ConsoleOptions
from vmehil.fault_scenarios.options import FaultOptions
from vmehil.mavlink.extension import MavlinkOptions
from vmehil.option_groups.can_options import CanPlantOptions
from vmehil.option_groups.realtime_options import RealtimeOptions
from vmehil.option_groups.trace_options import TraceOptions
from vmehil.option_groups.vision_options import VisionOptions
from vmehil.unit_controllers.hub import UNIT_TIMEOUT_S


@dataclass(frozen=True)
class RunOptions:
    """Every option of ``vmehil run`` (flags in ``--help``; docs/faults.md, docs/melmalec.md, ...).

    ``gains``: ``--gains`` parsed (names and numbers; the guard's checks are the run's);
    ``integrator_switch_off``: False with ``--no-integrator-switch-off``, else None (the rig's);
    ``pacing.realtime``: ``--realtime``/``--lockstep``, by default real time with ``--console``.
    """

    rig: str | None = None
    seed: int = 0
    motion: str | None = None
    duration: float | None = None
    pacing: RealtimeOptions = field(default_factory=RealtimeOptions)
    integrator_switch_off: bool | None = None
    gains: dict[str, float] = field(default_factory=dict)
    json: str | None = None
    report: str | None = None
    calibration: str | None = None
    quiet: bool = False
    bus: str = "emulated"
    enable_amplifiers: bool = False
    units: str = "single"
    unit_timeout_s: float = UNIT_TIMEOUT_S
    mavlink: MavlinkOptions = field(default_factory=MavlinkOptions)
    vision: VisionOptions = field(default_factory=VisionOptions)
    plant: CanPlantOptions | None = None
    console: ConsoleOptions = field(default_factory=ConsoleOptions)
    faults: FaultOptions = field(default_factory=FaultOptions)
    #: ``--scene``: a scene file, ``none``, or ``None`` (the rig's own scene when it has one)
    scene: str | None = None
    trace: TraceOptions = field(default_factory=TraceOptions)

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> RunOptions:
        console = ConsoleOptions.from_args(args)
        # a person at the console needs the loop at the wall clock's pace (a lockstep run would be
        # over before they typed); --lockstep still wins
        return cls(rig=args.rig, seed=args.seed, motion=args.motion, duration=args.duration,
                   pacing=RealtimeOptions.from_args(args, default=bool(console.port)),
                   integrator_switch_off=False if args.no_integrator_switch_off else None,
                   gains=parse_gains(args.gains, what="--gains"), json=args.json, report=args.report,
                   calibration=args.calibration, quiet=args.quiet, bus=args.bus,
                   enable_amplifiers=args.enable_amplifiers, units=args.units, unit_timeout_s=args.unit_timeout,
                   mavlink=MavlinkOptions.from_args(args), vision=VisionOptions.from_args(args),
                   plant=CanPlantOptions.from_args(args), console=console, faults=FaultOptions.from_args(args),
                   scene=args.scene,
                   trace=TraceOptions.from_args(args, report_dir=args.report))

    @property
    def realtime(self) -> bool:
        """Whether the loop is paced by the wall clock."""
        return self.pacing.realtime

    @property
    def plant_over_can(self) -> bool:
        return self.plant is not None

    @property
    def vision_mode(self) -> str | None:
        return self.vision.mode
