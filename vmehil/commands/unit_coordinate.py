"""``vmehil unit`` and ``vmehil coordinate``: the rig's unit controllers as separate processes.

    vmehil coordinate --rig melmalec-16 [--seed N] [--duration S] [--motion PATH] [--gains ..]
                      [--interface udp_multicast] [--channel GROUP] [--unit-timeout S] [--json PATH]
    vmehil unit --rig melmalec-16 --unit leg1 [--motion PATH] [--interface udp_multicast]
                [--channel GROUP] [--unit-timeout S] [--realtime] [--json PATH] [--record PATH.npz]

One ``vmehil unit`` per ``[[rig.unit]]`` of the rig file (on this host or on others on a real
bus) and one ``vmehil coordinate``; they meet on the unit bus (default channel: ``vmehil-units``
on ``virtual``, ``239.74.163.3`` on ``udp_multicast``, ``vcan1`` on ``socketcan``), see
docs/melmalec.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from dataclasses import dataclass
from typing import Any

from servo.control.gains import parse_gains
from vmehil.errors import CliError
from vmehil.exit_status import EXIT_FAULT, EXIT_STOP_INCOMPLETE, EXIT_USAGE
from vmehil.fault_scenarios import options as fault_options
from vmehil.fault_scenarios.options import FaultOptions
from vmehil.option_groups import trace_options
from vmehil.option_groups.cli_types import bounded_float, bounded_int, duration_s
from vmehil.option_groups.trace_options import TraceOptions
from vmehil.writers.files import write_json

EXIT_REFUSED = 2


def _bus_args(p: argparse.ArgumentParser) -> None:
    from vmehil.unit_controllers.hub import UNIT_TIMEOUT_S
    from vmehil.unit_controllers.remote import START_TIMEOUT_S

    p.add_argument("--interface", default=None, help="python-can interface of the unit bus (virtual, socketcan, "
                                                     "udp_multicast)")
    p.add_argument("--channel", default=None,
                   help="the unit bus's channel (default vmehil-units / vcan1 / 239.74.163.3: never the plant bus's)")
    p.add_argument("--can-log", default=None, metavar="PATH", help="record the unit bus from this side")
    p.add_argument("--unit-timeout", type=bounded_float(0.001, 3600.0, what="a timeout (s)"), default=UNIT_TIMEOUT_S,
                   help=f"wall seconds without an answer (unit) or a unit's commands (coordinator) before a safe "
                        f"stop ({UNIT_TIMEOUT_S:g})")
    p.add_argument("--start-timeout", type=bounded_float(0.001, 3600.0, what="a timeout (s)"), default=START_TIMEOUT_S,
                   help=f"wall seconds to wait for the run to start ({START_TIMEOUT_S:g})")
    p.add_argument("--motion", default=None, help="motion file (the same on every unit and the coordinator)")
    p.add_argument("--json", default=None, help="write the summary here")
    trace_options.add_arguments(p)


def _plant_args(p: argparse.ArgumentParser) -> None:
    """Where the coordinator's plant runs: ``--plant inprocess|can`` as ``vmehil run`` spells it;
    the plant bus is its own (``--plant-interface``, ``--plant-channel``: never the unit bus)."""
    from vmehil.option_groups.can_options import PLANT_MODES
    from vmehil.unit_controllers.remote import FREE_STALE_TICKS

    g = p.add_argument_group("the plant (docs/melmalec.md)")
    g.add_argument("--plant", choices=("inprocess", "can"), default="inprocess",
                   help="step the plant of every joint in this process (default) or talk to `vmehil plant-node` "
                        "on the plant bus")
    g.add_argument("--plant-interface", default=None, metavar="NAME",
                   help="--plant can: the plant bus's python-can interface (default: the unit bus's)")
    g.add_argument("--plant-channel", default=None, metavar="NAME",
                   help="--plant can: the plant bus's channel (default: the interface's plant channel, vmehil / "
                        "vcan0 / 239.74.163.2 — the plant node's default)")
    g.add_argument("--plant-mode", choices=PLANT_MODES, default="lockstep",
                   help="lockstep (default): the plant steps once every unit's commands for the tick are in; "
                        "free-running: the units and the plant step on the wall clock (docs/melmalec.md)")
    g.add_argument("--can-timeout", type=bounded_float(0.001, 3600.0, what="a timeout (s)"), default=1.0,
                   metavar="S", help="--plant can: answer / heartbeat timeout of the plant node in seconds (1.0)")
    g.add_argument("--stale-ticks", type=bounded_int(1, 255, what="a number of periods"), default=None, metavar="N",
                   help=f"free-running: periods without a unit's commands before it is lost (coordinator) and "
                        f"exchanges without a fresh answer before a unit stops ({FREE_STALE_TICKS}); with --plant "
                        f"can also the plant link's (as `vmehil run`'s)")


@dataclass(frozen=True)
class UnitBusOptions:
    """The unit bus and the run's timing, as ``vmehil unit`` and ``vmehil coordinate`` share them."""

    interface: str | None
    channel: str | None
    can_log: str | None
    unit_timeout_s: float
    start_timeout_s: float
    motion: str | None
    json: str | None
    trace: TraceOptions = dataclasses.field(default_factory=TraceOptions)

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> UnitBusOptions:
        return cls(interface=args.interface, channel=args.channel, can_log=args.can_log,
                   unit_timeout_s=args.unit_timeout, start_timeout_s=args.start_timeout, motion=args.motion,
                   json=args.json, trace=TraceOptions.from_args(args))


@dataclass(frozen=True)
class UnitOptions:
    """``vmehil unit``'s options."""

    unit: str
    bus: UnitBusOptions
    rig: str | None = None
    realtime: bool = False
    record: str | None = None
    calibration: str | None = None
    faults: FaultOptions = dataclasses.field(default_factory=FaultOptions)

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> UnitOptions:
        return cls(unit=args.unit, bus=UnitBusOptions.from_args(args), rig=args.rig, realtime=args.realtime,
                   record=args.record, calibration=args.calibration, faults=FaultOptions.from_args(args))


@dataclass(frozen=True)
class CoordinatorOptions:
    """``vmehil coordinate``'s options. ``gains``: ``--gains`` parsed (checked by the command);
    ``integrator_switch_off``: False with ``--no-integrator-switch-off``, else None (the rig's)."""

    bus: UnitBusOptions
    rig: str | None = None
    seed: int = 0
    duration_s: float = 8.0
    gains: dict[str, float] = dataclasses.field(default_factory=dict)
    integrator_switch_off: bool | None = None
    plant: str = "inprocess"
    plant_interface: str | None = None
    plant_channel: str | None = None
    plant_mode: str = "lockstep"
    can_timeout_s: float = 1.0
    stale_ticks: int | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> CoordinatorOptions:
        return cls(bus=UnitBusOptions.from_args(args), rig=args.rig, seed=args.seed, duration_s=args.duration,
                   gains=parse_gains(args.gains, what="--gains"),
                   integrator_switch_off=False if args.no_integrator_switch_off else None, plant=args.plant,
                   plant_interface=args.plant_interface, plant_channel=args.plant_channel,
                   plant_mode=args.plant_mode, can_timeout_s=args.can_timeout, stale_ticks=args.stale_ticks)


def plant_options(opts: CoordinatorOptions):
    """The plant bus's :class:`~vmehil.option_groups.can_options.CanPlantOptions` for ``--plant can`` (None:
    in-process). Refuses the unit bus's own channel: both buses carry CMD/SENS frames."""
    from vmehil.option_groups.can_options import CanPlantOptions
    from vmehil.unit_controllers.remote import unit_channel

    if opts.plant != "can":
        return None
    iface = opts.plant_interface or opts.bus.interface
    plant = CanPlantOptions(interface=iface, channel=opts.plant_channel, plant_mode=opts.plant_mode,
                            can_timeout_s=opts.can_timeout_s, stale_ticks=opts.stale_ticks)
    p_iface, p_chan = plant.resolved()
    u_iface, u_chan = unit_channel(opts.bus.interface, opts.bus.channel)
    if (p_iface, p_chan) == (u_iface, u_chan):
        raise CliError(f"--plant can: the plant bus ({p_iface} {p_chan}) is the unit bus: give the plant node "
                         f"and the units channels of their own (--plant-channel, --channel)")
    return plant


def register(sub: argparse._SubParsersAction) -> None:
    from vmehil.commands.run import add_rig_args

    p = sub.add_parser("unit", help="run one unit controller of the rig (its own boards) on the unit bus")
    add_rig_args(p)
    p.add_argument("--unit", required=True, help="the unit's name ([[rig.unit]] name)")
    p.add_argument("--realtime", action="store_true", help="pace the unit's ticks by the wall clock")
    p.add_argument("--record", default=None, metavar="PATH.npz", help="write the unit's recorded arrays here")
    p.add_argument("--calibration", metavar="PATH", default=None,
                   help="the rig's calibration file for the drivers (default: calibration/<rig>.toml if it exists, "
                        "as vmehil run); the unit applies its own boards' and joints' entries")
    fault_options.add_arguments(p)
    _bus_args(p)
    p.set_defaults(func=run_unit_command, options=UnitOptions.from_args)

    c = sub.add_parser("coordinate", help="coordinate the rig's unit controllers and serve them the plant")
    add_rig_args(c)
    c.add_argument("--duration", type=duration_s, default=8.0, help="seconds to run (default 8)")
    c.add_argument("--gains", default=None, help="every joint's gains kp=..,kpi=..,kv=..,kvi=.. (to every unit)")
    c.add_argument("--no-integrator-switch-off", action="store_true", help="keep the integrators fed at rest")
    _bus_args(c)
    _plant_args(c)
    c.set_defaults(func=run_coordinator_command, options=CoordinatorOptions.from_args)


def _load(rig: str | None):
    from emulators.presets import resolve_rig
    from servo.rig import load_rig

    return load_rig(resolve_rig(rig))


def run_unit_command(opts: UnitOptions) -> int:
    import numpy as np

    from emulators.plant_link import PlantLinkError
    from servo.runner import RealtimeRunner
    from vmehil.calibration.store import load_store_or_nominal
    from vmehil.commands import refuse_without
    from vmehil.commands.calibration_file import calibrated
    from vmehil.fault_scenarios.injection import first_joint, first_tick, stop_report
    from vmehil.reports.run_report import summarize
    from vmehil.unit_controllers.processes import run_unit
    from vmehil.unit_controllers.remote import UnitRefused, unit_bus

    if opts.faults.wants_list:
        return fault_options.list_faults()
    if opts.bus.trace.wanted and refuse_without(f"vmehil unit --unit {opts.unit} --trace", "trace"):
        return EXIT_USAGE
    spec = _load(opts.rig)
    if opts.bus.trace.wants_list:
        return _list_unit_signals(spec, opts.unit)
    try:  # before joining the run: a fault this unit cannot take costs no run
        faults_before_run, faults = unit_faults(opts.unit, opts.faults, spec)
    except ValueError as e:
        print(f"vmehil unit {opts.unit}: {e}", file=sys.stderr)
        return EXIT_USAGE
    traces: list[Any] = []

    def before_run(run: Any) -> None:
        if faults_before_run is not None:
            faults_before_run(run)
        # the unit's loop and its boards; the plant (and its truth) is the coordinator's
        trace = opts.bus.trace.start(run.system, run.loop, run.runner, rig=f"{spec.name}:{opts.unit}", seed=run.seed)
        if trace is not None:
            traces.append(trace)
    store = calibrated(opts.calibration, spec, lambda cal: load_store_or_nominal(cal, spec))
    bus = unit_bus(opts.bus.interface, opts.bus.channel, opts.bus.can_log)
    try:
        out = run_unit(spec, opts.unit, bus, timeout_s=opts.bus.unit_timeout_s,
                       start_timeout_s=opts.bus.start_timeout_s, motion_path=opts.bus.motion, realtime=opts.realtime,
                       # no spinning to the deadline (the single run spins its last 0.5 ms): five units
                       # and the coordinator share the cores, and five spins cost 2.5 ms of CPU a
                       # period; with them no free-running run went 10 s at rest, without them two did
                       realtime_options={"overrun": "warn", "max_lateness_periods": 5.0, "spin_s": 0.0},
                       calibration=store, before_run=before_run)
    except UnitRefused as e:
        print(f"vmehil unit {opts.unit}: refused: {e}", file=sys.stderr)
        return EXIT_REFUSED
    except PlantLinkError as e:  # before its loop (the power-up exchange): its boards safe-stopped
        print(f"vmehil unit {opts.unit}: stopped before its loop ran: {e.cause}: {e}", file=sys.stderr)
        return EXIT_FAULT
    finally:
        bus.close()
        for trace in traces:
            trace.close()
    loop, runner = out.loop, out.runner
    assert loop is not None and runner is not None
    realtime = isinstance(runner, RealtimeRunner)  # --realtime, or a free-running run
    timing = runner.timing.summary(spec.period_s) if isinstance(runner, RealtimeRunner) else None
    summary = summarize(loop, rig=spec.name, seed=out.seed, realtime=realtime, overruns=runner.overruns,
                        timing=timing)
    summary.update(unit=opts.unit, completed=out.completed, ended=out.ended,
                   plant_mode="free-running" if out.free_running else "lockstep")
    if out.free_running:
        summary["answers"] = {"stale_exchanges": out.stale, "incomplete": out.incomplete}
    if faults:
        summary["injected_faults"] = [f.as_dict() for f in faults]
        summary["stop"] = stop_report(loop, first_tick(faults), first_joint(faults))
    for trace in traces:
        summary["trace"] = trace.summary()
    fault = loop.fault
    print(f"unit {opts.unit}: {out.completed} ticks; " + ("ran to the end" if fault is None else
          f"stopped: {fault.cause} at tick {fault.tick}: {fault.detail}") +
          f"; final stop {'verified' if not loop.stop_incomplete else 'INCOMPLETE'}", file=sys.stderr)
    if timing:
        print(f"unit {opts.unit}: {timing_line(timing)}", file=sys.stderr)
    if opts.bus.json:
        write_json(opts.bus.json, summary)
    if opts.record:
        rec = loop.recorder.trimmed() if loop.recorder is not None else {}
        np.savez(opts.record, **rec)  # type: ignore[arg-type]  # (numpy stubs: **kwds vs allow_pickle)
    if out.system is not None:
        out.system.close()
    if loop.stop_incomplete:
        return EXIT_STOP_INCOMPLETE
    return EXIT_FAULT if fault is not None else 0


def _list_unit_signals(spec: Any, unit: str) -> int:
    """``vmehil unit --trace list``: the unit's own joints and boards (no truth: the plant is the
    coordinator's)."""
    from servo.joint_groups import rig_units, unit_named, unit_rig
    from vmehil.rig_setup.system import build_emulated_rig

    sub = unit_rig(spec, unit_named(rig_units(spec), unit, str(spec.path)))
    system = build_emulated_rig(sub)
    try:
        return trace_options.list_signals(system, [j.name for j in sub.joints], truth=False)
    finally:
        system.close()


def unit_faults(unit: str, options: FaultOptions, spec) -> tuple[Any, list]:
    """Unit ``unit``'s faults of ``--fault``/``--faults`` (checked against the rig, each routed to
    the unit that owns its joint or board, as ``--units parallel`` does) and the hook that
    attaches their schedule to its runner. Raises ValueError, saying which unit to give it to,
    for a fault of another unit's joints or boards, and for a fault of the plant (the
    coordinator's: this process has no plant)."""
    from servo.joint_groups import rig_units
    from vmehil.fault_scenarios.injection import FaultSchedule, announcement, check_rig, on_the_plant
    from vmehil.unit_controllers.options import UnitFaultContext, route_faults

    faults = fault_options.scenario(options)
    if not faults:
        return None, []
    check_rig(faults, spec)
    for f in faults:
        if on_the_plant(f.kind):
            raise CliError(f"{f.source}: {f.kind.name} is a fault of the plant, which runs in the coordinator "
                             "(or the plant node): a unit controller has its boards only")
    routed = route_faults(faults, spec, rig_units(spec))
    for name, theirs in routed.items():
        if name != unit and theirs:
            raise CliError(f"{theirs[0].source}: not a fault of unit {unit}'s joints or boards: "
                             f"give it to `vmehil unit --unit {name}`")
    mine = routed.get(unit, [])

    def before_run(run: Any) -> None:
        FaultSchedule(mine, UnitFaultContext(run.system, run.loop, run.seed)).attach(run.runner)
        for f in mine:
            print(announcement(f), file=sys.stderr)

    return before_run, mine


def timing_line(t: dict) -> str:
    """One line of real-time figures (a runner's timing summary, or a unit's UNIT_TIMING)."""
    return (f"compute p50 {t['compute_p50_ms']:.2f} ms p99 {t['compute_p99_ms']:.2f} ms max "
            f"{t['compute_max_ms']:.2f} ms; lateness p50 {t['lateness_p50_ms']:.2f} ms p99 "
            f"{t['lateness_p99_ms']:.2f} ms max {t['lateness_max_ms']:.2f} ms; "
            f"overruns {t['overruns']} of {t.get('ticks', '?')} ticks")


def run_coordinator_command(opts: CoordinatorOptions) -> int:
    from servo.gain_guard import check_values
    from vmehil.commands import refuse_without
    from vmehil.scope.sources import plant_catalog
    from vmehil.unit_controllers.coordinator import plant_link_for
    from vmehil.unit_controllers.processes import run_coordinator
    from vmehil.unit_controllers.remote import FREE_STALE_TICKS, UnitRefused, unit_bus

    if opts.bus.trace.wanted and refuse_without("vmehil coordinate --trace", "trace"):
        return EXIT_USAGE
    spec = _load(opts.rig)
    if opts.bus.trace.wants_list:
        print(plant_catalog(spec).listing())
        return 0
    gains = check_values(opts.gains)
    n_ticks = round(opts.duration_s * spec.servo_rate_hz)
    plant = plant_options(opts)
    # the plant node first: no node (or another rig, or mode) is an error before any unit waits
    link = plant.open_link(spec, opts.seed) if plant is not None else None
    trace = None
    try:
        if opts.bus.trace.wanted:  # the plant's exchanges, traced: the link made here to tap it
            link = link if link is not None else plant_link_for(spec, opts.seed)
            trace = trace_options.start_on_plant(opts.bus.trace, link, spec, seed=opts.seed)
        bus = unit_bus(opts.bus.interface, opts.bus.channel, opts.bus.can_log)
    except BaseException:
        if trace is not None:
            trace.close()
        if link is not None:
            link.close()
        raise
    if plant is not None:  # (a link of its own is also made here for a trace of the in-process plant)
        iface, chan = plant.resolved()
        print(f"coordinate: the plant node on {iface} {chan}", file=sys.stderr)
    try:
        out = run_coordinator(spec, bus, seed=opts.seed, n_ticks=n_ticks, timeout_s=opts.bus.unit_timeout_s,
                              start_timeout_s=opts.bus.start_timeout_s, motion_path=opts.bus.motion, gains=gains,
                              switch_off=opts.integrator_switch_off, plant_link=link,
                              free_running=opts.plant_mode == "free-running",
                              stale_ticks=opts.stale_ticks or FREE_STALE_TICKS)
    except UnitRefused as e:
        print(f"vmehil coordinate: {e}", file=sys.stderr)
        return EXIT_REFUSED
    finally:
        bus.close()
        if trace is not None:
            trace.close()
    stop = out.stop
    print(f"coordinate: {out.exchanges} plant steps; " +
          ("every unit ran to the end" if stop is None else f"stop: unit {stop.unit} at exchange {stop.exchange}: "
                                                            f"{stop.what}"), file=sys.stderr)
    for note in out.refused:
        print(f"coordinate: {note}", file=sys.stderr)
    if out.other_session:
        print(f"coordinate: {out.other_session} frames of another session dropped (boot ids the run did not "
              "start with)", file=sys.stderr)
    figures = out.timing.figures(spec.period_s)
    if "compute_p50_ms" in figures:
        print(f"coordinate: steps: {timing_line(figures)}", file=sys.stderr)
    for name, fig in out.unit_timing.items():
        if fig.get("realtime"):
            print(f"coordinate: unit {name}: {timing_line(fig)}", file=sys.stderr)
    if opts.bus.json:
        write_json(opts.bus.json, {
            "rig": spec.name, "seed": opts.seed, "ticks": n_ticks, "plant": opts.plant, "plant_mode": opts.plant_mode,
            "plant_steps": out.exchanges,
            "stop": None if stop is None else {"unit": stop.unit, "exchange": stop.exchange, "what": stop.what},
            "events": [{"exchange": e.exchange, "unit": e.unit, "what": e.what} for e in out.events],
            "amps_on": out.amps_on, "refused": out.refused, "missing_cmd": out.missing_cmd,
            "other_session": out.other_session,
            "timing": figures, "units": out.unit_timing,
            # --plant can: the link's counts (answers, stale, incomplete…), as the plant node's own
            "plant_link": dataclasses.asdict(link.counters) if plant is not None and link is not None else None,
            **({"trace": trace.summary()} if trace is not None else {})})
    return 0 if stop is None else EXIT_FAULT
