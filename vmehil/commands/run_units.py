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
from typing import Any

from servo.interrupts import Terminated, interrupt_exit_status, interrupt_name
from vmehil.exit_status import EXIT_FAULT, EXIT_STOP_INCOMPLETE
from vmehil.files import write_json

UNIT_MODES = ("single", "parallel")

#: options of `vmehil run` a parallel run does not take (yet): what each needs is one loop
_NOT_WITH_UNITS = (("report", "--report"), ("mavlink", "--mavlink"), ("console", "--console"),
                   ("vision", "--vision"), ("fault", "--fault"), ("faults", "--faults"),
                   ("calibration", "--calibration"))


def add_arguments(p: argparse.ArgumentParser) -> None:
    from vmehil.cli_types import bounded_float
    from vmehil.units.hub import UNIT_TIMEOUT_S

    p.add_argument("--units", choices=UNIT_MODES, default="single",
                   help="single (default): one controller of every joint; parallel: one controller per "
                        "[[rig.unit]] with its own boards, coordinated in lockstep (docs/melmalec.md)")
    p.add_argument("--unit-timeout", type=bounded_float(0.001, 3600.0, what="a timeout (s)"), default=UNIT_TIMEOUT_S,
                   help=f"--units parallel: wall seconds without a unit's commands before it is declared lost "
                        f"and every unit stops ({UNIT_TIMEOUT_S:g})")


def refused_options(args: argparse.Namespace) -> list[str]:
    """The options given that a parallel run does not take."""
    return [flag for attr, flag in _NOT_WITH_UNITS if getattr(args, attr, None)]


def run_parallel(args: argparse.Namespace, rig: Any, gains: dict[str, float], motion: Any, n_ticks: int,
                 link: Any) -> int:
    from vmehil.realtime_options import overrun_options
    from vmehil.run_report import summarize
    from vmehil.units.coordinator import run_units

    run = None
    try:
        run = run_units(rig, seed=args.seed, n_ticks=n_ticks, motion=motion, gains=gains,
                        switch_off=False if args.no_integrator_switch_off else None, link=link,
                        realtime=args.realtime, realtime_options=overrun_options(args),
                        timeout_s=args.unit_timeout)
    except (KeyboardInterrupt, Terminated) as e:
        # run_units has stopped every unit (each one's armed() block: enables low, 0 V) first
        print(f"run: interrupted ({interrupt_name(e)}); every unit safe-stopped", file=sys.stderr)
        return interrupt_exit_status(e)
    status = 0
    units: dict[str, Any] = {}
    lines = [f"{rig.name} · units parallel · {n_ticks} ticks · plant steps {run.hub.exchanges}"]
    for u in run.units:
        loop, runner = u.loop, u.runner
        if loop is None or runner is None:
            units[u.unit.name] = {"error": f"{type(u.error).__name__}: {u.error}"}
            lines.append(f"  {u.unit.name:6s} did not run: {u.error}")
            status = max(status, EXIT_FAULT)
            continue
        timing = runner.timing.summary(rig.period_s) if hasattr(runner, "timing") else None
        s = summarize(loop, rig=rig.name, seed=args.seed, realtime=args.realtime, overruns=runner.overruns,
                      timing=timing)
        s["unit"] = u.unit.name
        units[u.unit.name] = s
        fault = loop.fault
        line = (f"  {u.unit.name:6s} {len(u.unit.joints)} joints  ticks {u.completed}  "
                f"fault {'-' if fault is None else f'{fault.cause} at tick {fault.tick}'}")
        if timing:
            line += (f"  compute p50 {timing['compute_p50_ms']:.2f} ms p99 {timing['compute_p99_ms']:.2f} ms  "
                     f"lateness p99 {timing['lateness_p99_ms']:.2f} ms max {timing['lateness_max_ms']:.2f} ms  "
                     f"overruns {timing['overruns']}")
        lines.append(line)
        if loop.stop_incomplete:
            status = EXIT_STOP_INCOMPLETE
        elif fault is not None:
            status = max(status, EXIT_FAULT) if status != EXIT_STOP_INCOMPLETE else status
    stop = run.hub.stop
    if stop is not None:
        lines.append(f"stop: unit {stop.unit} at exchange {stop.exchange}: {stop.what}")
    print("\n".join(lines))
    if args.json:
        write_json(args.json, {
            "rig": rig.name, "seed": args.seed, "units_mode": "parallel", "ticks": n_ticks,
            "plant_steps": run.hub.exchanges,
            "stop": None if stop is None else {"unit": stop.unit, "exchange": stop.exchange, "what": stop.what},
            "hub_events": [{"exchange": e.exchange, "unit": e.unit, "what": e.what} for e in run.hub.events],
            "units": units})
    run.close()
    return status
