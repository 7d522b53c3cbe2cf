"""``vmehil calibrate friction``: friction identification of one joint (see :mod:`servo.friction_id`).

    vmehil calibrate friction --joint N [--rig NAME|PATH] [--json PATH] [--report DIR] [--seed N]
                              [--ramps 4] [--cycles 1]

Stand-alone until the ``calibrate`` command with its procedure registry is merged: this module
registers ``calibrate`` (with ``friction`` as its only procedure) only if no other module has
registered a ``calibrate`` command before it.
"""

from __future__ import annotations

import argparse

from servo.files import write_json


def add_friction_arguments(p: argparse.ArgumentParser) -> None:
    """The friction procedure's options (shared with a ``calibrate`` registry)."""
    p.add_argument("--joint", type=int, required=True, help="joint number, 1-based as the papers number links")
    p.add_argument("--rig", default=None, help="rig preset name or TOML path (default jpl-arm)")
    p.add_argument("--seed", type=int, default=0, help="seed of the emulated rig's noise (default 0)")
    p.add_argument("--json", default=None, help="write the results (JSON) here")
    p.add_argument("--report", default=None, help="write plots and summary.md into this folder")
    p.add_argument("--ramps", type=int, default=4, help="breakout ramps (default 4)")
    p.add_argument("--cycles", type=float, default=1.0, help="cycles of the 0.06 Hz sinusoid (default 1)")


def register(sub: argparse._SubParsersAction) -> None:
    if "calibrate" in sub.choices:  # the calibration registry is there: it lists friction itself
        return
    p = sub.add_parser("calibrate", help="calibration procedures (friction identification)")
    procs = p.add_subparsers(dest="procedure", metavar="PROCEDURE")
    procs.required = True
    f = procs.add_parser("friction", help="running torque, ripple and breakout of one joint (drivers only)")
    add_friction_arguments(f)
    f.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from servo.friction_id import identify_friction, public_result, write_friction_report
    from servo.system import build_emulated_rig

    system = build_emulated_rig(args.rig, seed=args.seed)
    try:
        result = identify_friction(system, args.joint, ramps=args.ramps, cycles=args.cycles,
                                   keep_records=bool(args.report))
    finally:
        system.close()
    print(format_result(result))
    if args.json:
        write_json(args.json, public_result(result))
    if args.report:
        files = write_friction_report(result, args.report)
        print(f"report: {len(files)} files in {args.report}")
    return 0


def format_result(r: dict) -> str:
    rt = r["running_torque_oz_in"]
    lo, hi = r["breakout_input_range_oz_in"]
    return "\n".join([
        f"{r['rig']} joint {r['joint']} ({r['joint_name']}): friction at the motor shaft",
        f"  running torque     {rt['mean']:7.2f} oz-in  (ripple ±{rt['ripple_amplitude']:.2f} oz-in "
        f"at {r['ripple_frequency_hz']:.2f} Hz)",
        f"  breakout (input)   {r['breakout_input_oz_in']:7.2f} oz-in  (ramps {lo:.2f}–{hi:.2f})",
        f"  breakout (output)  {r['breakout_output_oz_in']:7.1f} oz-in  ({r['breakout_output_method']})",
    ])
