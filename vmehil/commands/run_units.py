"""``vmehil run --units parallel``: the rig's unit controllers in parallel (docs/melmalec.md).

One controller per ``[[rig.unit]]`` (a thread each in this process), each with its own emulated
boards, drivers, 125 Hz loop and runner; the coordinator's global motion split into the units'
segments; one plant for every joint (in-process, or the CAN plant node with ``--plant can``)
stepped in lockstep once every unit's commands for the tick are in. ``--units single`` (the
default) is the one controller of every joint.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from servo.interrupts import Terminated, interrupt_exit_status, interrupt_name
from vmehil.exit_status import EXIT_FAULT, EXIT_STOP_INCOMPLETE
from vmehil.writers.files import write_json

if TYPE_CHECKING:
    from vmehil.commands.run_options import RunOptions

UNIT_MODES = ("single", "parallel")

#: options of `vmehil run` a parallel run does not take (whether given, the flag), why, and what
#: to do instead (docs/melmalec.md, "Options with --units parallel")
_NOT_WITH_UNITS: tuple[tuple[Callable[[RunOptions], object], str, str], ...] = (
    (lambda o: o.mavlink.url, "--mavlink",
     "live tuning talks to one servo loop and there are five; tune with --units single --mavlink, then give the "
     "gains to every unit with --gains"),
    (lambda o: o.console.port, "--console",
     "the operator console drives one servo loop (its motions, calibration, stops); use it with --units single"),
    (lambda o: o.scope.live, "--live",
     "the live view serves one servo loop's channels; watch a unit's joints with --units single --live"),
    (lambda o: o.vision.mode, "--vision",
     "the visual servo commands one loop's joints over one BIT3 window; run it with --units single"),
    (lambda o: o.trace.wanted, "--trace",
     "a trace follows one loop; trace a unit with `vmehil unit --trace`, or run with --units single"),
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from vmehil.option_groups.cli_types import bounded_float
    from vmehil.unit_controllers.hub import UNIT_TIMEOUT_S

    p.add_argument("--units", choices=UNIT_MODES, default="single",
                   help="single (default): one controller of every joint; parallel: one controller per "
                        "[[rig.unit]] with its own boards, coordinated in lockstep (docs/melmalec.md)")
    p.add_argument("--unit-timeout", type=bounded_float(0.001, 3600.0, what="a timeout (s)"), default=UNIT_TIMEOUT_S,
                   help=f"--units parallel: wall seconds without a unit's commands before it is declared lost "
                        f"and every unit stops ({UNIT_TIMEOUT_S:g})")


def refused_options(opts: RunOptions) -> list[str]:
    """Why each option given cannot go with a parallel run (one line each, with what to do)."""
    out = [f"{flag}: {why}" for given, flag, why in _NOT_WITH_UNITS if given(opts)]
    if opts.bus != "emulated":
        out.append("--bus: the unit controllers run on emulated boards of their own; a real crate runs one "
                   "controller of every joint (--units single --bus ...)")
    return out


def run_parallel(opts: RunOptions, rig: Any, gains: dict[str, float], motion: Any, n_ticks: int,
                 make_link: Callable[[], Any], calibration: Any = None, faults: list | None = None) -> int:
    """Run the units; the same summary, table, JSON and report as the single run (from the units'
    loops merged in joint order, :class:`vmehil.unit_controllers.options.MergedUnits`) plus each unit's.
    ``make_link()``: the plant link ``--plant can`` asks for, else None (called once the faults
    are routed: a refused fault opens no link). ``faults``: the run's scenario, checked
    (:func:`vmehil.fault_scenarios.options.prepare`)."""
    from typing import cast

    from servo.joint_groups import rig_units
    from servo.loop import ServoLoop
    from vmehil.fault_scenarios.injection import announcement, first_joint, first_tick, stop_report
    from vmehil.reports.run_report import final_stop_line, summarize, table, units_section, write_report
    from vmehil.unit_controllers.coordinator import plant_link_for, run_units
    from vmehil.unit_controllers.options import MergedUnits, fault_hook, route_faults

    faults = list(faults or [])
    routed = route_faults(faults, rig, rig_units(rig)) if faults else {}
    link = make_link()
    if link is None:
        link = plant_link_for(rig, opts.seed)  # made here: a plant fault goes to this plant
    before_run, _ = fault_hook(routed, link, opts.seed)
    run = None
    try:
        run = run_units(rig, seed=opts.seed, n_ticks=n_ticks, motion=motion, gains=gains,
                        switch_off=opts.integrator_switch_off, link=link,
                        realtime=opts.realtime, realtime_options=opts.pacing.runner_options(),
                        timeout_s=opts.unit_timeout_s, calibration=calibration, before_run=before_run)
    except (KeyboardInterrupt, Terminated) as e:
        # run_units has stopped every unit (each one's armed() block: enables low, 0 V) first
        print(f"run: interrupted ({interrupt_name(e)}); every unit safe-stopped", file=sys.stderr)
        return interrupt_exit_status(e)
    finally:
        if run is None:  # run_units never returned: the plant link (a CAN node thread) is ours to close
            link.close()
    status = 0
    units: dict[str, Any] = {}
    for u in run.units:
        loop, runner = u.loop, u.runner
        if loop is None or runner is None:
            units[u.unit.name] = {"error": f"{type(u.error).__name__}: {u.error}"}
            status = max(status, EXIT_FAULT)
            continue
        timing = runner.timing.summary(rig.period_s) if hasattr(runner, "timing") else None
        s = summarize(loop, rig=rig.name, seed=opts.seed, realtime=opts.realtime, overruns=runner.overruns,
                      timing=timing)
        s["unit"] = u.unit.name
        units[u.unit.name] = s
        if loop.stop_incomplete:
            status = EXIT_STOP_INCOMPLETE
        elif loop.fault is not None:
            status = max(status, EXIT_FAULT) if status != EXIT_STOP_INCOMPLETE else status
    hub_stop = run.hub.stop
    stop: dict[str, Any] | None = (None if hub_stop is None else
                                   {"unit": hub_stop.unit, "exchange": hub_stop.exchange, "what": hub_stop.what})
    merged = cast(ServoLoop, MergedUnits(run)) if all(u.loop is not None for u in run.units) else None
    if merged is not None:  # the single run's summary, of every joint (the units' loops merged)
        summary = summarize(merged, rig=rig.name, seed=opts.seed, realtime=opts.realtime,
                            overruns=max((int(x.get("overruns", 0)) for x in units.values()), default=0))
    else:
        summary = {"rig": rig.name, "seed": opts.seed, "joints": []}
    if faults:
        summary["injected_faults"] = [{**f.as_dict(), "unit": next(n for n, fs in routed.items() if f in fs)}
                                      for f in faults]
        if merged is not None:  # how the run ended, as the single run says it, with the units' stop
            stop = {**stop_report(merged, first_tick(faults), first_joint(faults)), **(stop or {})}
        for f in faults:
            print(announcement(f))
    summary.update({"units_mode": "parallel", "ticks_planned": n_ticks, "plant_steps": run.hub.exchanges,
                    "stop": stop,
                    "hub_events": [{"exchange": e.exchange, "unit": e.unit, "what": e.what} for e in run.hub.events],
                    "units": units})
    _save_blackboxes(opts, rig.name, run, units, summary)
    print(table(summary) if merged is not None else "\n".join(units_section(summary)))
    stop_line = final_stop_line(summary.get("final_stop"))
    if stop_line is not None:  # each unit's category-1 end and the 2 s after it, as the single run's
        print(stop_line)
    if opts.json:
        write_json(opts.json, summary)
    if opts.report and merged is not None:
        files = write_report(merged, summary, opts.report)
        print(f"report: {len(files)} files in {opts.report}")
    run.close()
    return status


def _save_blackboxes(opts: RunOptions, rig: str, run: Any, units: dict[str, Any], summary: dict[str, Any]) -> None:
    """Each unit's black box into ``<folder>/<unit>/`` (docs/scope.md, "Black box"), named in its
    ``units.<unit>.final_stop.blackbox``; the run's ``final_stop.blackbox`` is the box of the unit
    whose stop the run reports (``final_stop.unit``)."""
    from vmehil.reports.blackbox import blackbox_folder, save_blackbox

    folder = blackbox_folder(opts.scope.blackbox, opts.report, rig)
    if folder is None:
        return
    boxes = {}
    for u in run.units:
        if u.loop is None:
            continue
        stop = units.get(u.unit.name, {}).get("final_stop")
        boxes[u.unit.name] = save_blackbox(u.loop, rig=f"{rig} unit {u.unit.name}", choice=None, report=None,
                                           final_stop=stop, folder=folder / u.unit.name)
    top = summary.get("final_stop")
    if isinstance(top, dict) and boxes.get(top.get("unit")) is not None:
        top["blackbox"] = str(boxes[top["unit"]])
