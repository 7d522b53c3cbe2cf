"""``vmehil calibrate``: calibration procedures that write the rig's calibration file.

    vmehil calibrate adc|dac|encoder|amplifier|pot|all [--rig NAME|PATH] [--seed N]
                     [--joint N ...] [--auto] [--calibration CAL.toml] [--json PATH] [--report DIR]
                     [--write-on-fail] [--points 9] [--verify-per-segment 1] [--quiet]

Progress is a bar on stderr (:mod:`vmehil.writers.progress`) when it is a terminal and ``--quiet`` is
not given; the procedures' lines and prompts are printed above it, never onto it.

Procedures come from :data:`vmehil.calibration.procedures.PROCEDURES`: the built-in ones and
the entry points of group ``vmehil.calibration_procedures`` (the plant's ``friction`` among them).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from vmehil.calibration.base import Procedure
from vmehil.calibration.procedures import ALL, procedures_in_order
from vmehil.commands import refuse_without
from vmehil.commands.errors import CliError
from vmehil.option_groups.cli_types import bounded_int, joint_number, seed
from vmehil.writers.files import write_atomic, write_json


def register(sub: argparse._SubParsersAction) -> None:
    specs = procedures_in_order()
    lines = "\n".join(f"  {spec.name:<10s} {spec.help}" for spec in specs)
    p = sub.add_parser(
        "calibrate", help="run calibration procedures and write the rig's calibration file",
        description=f"Calibration procedures (order of `{ALL}`: "
                    + ", ".join(spec.name for spec in specs if spec.in_all) + ").\n" + lines,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("procedure", choices=[*(spec.name for spec in specs), ALL], help="what to calibrate")
    p.add_argument("--rig", metavar="NAME|PATH", default=None, help="rig preset name or TOML path (default jpl-arm)")
    p.add_argument("--seed", metavar="N", type=seed, default=0, help="seed of the emulated rig's noise (default 0)")
    p.add_argument("--joint", type=joint_number, action="append", default=None,
                   help="joint number (1-based) to calibrate; repeat for several (default: all)")
    p.add_argument("--auto", action="store_true",
                   help="use the rig's reference fixture instead of prompting the operator for angles")
    p.add_argument("--calibration", "--out", dest="out", default=None, metavar="PATH",
                   help="calibration file to read and write, as run's and console's --calibration "
                        "(default $VMEHIL_CALIBRATION_DIR or ./calibration, /<rig>.toml)")
    p.add_argument("--json", metavar="PATH", default=None, help="write the machine-readable results here")
    p.add_argument("--report", metavar="DIR", default=None,
                   help="write results.txt, results.json and plots into this folder")
    p.add_argument("--write-on-fail", action="store_true", help="write the file even if a check failed")
    p.add_argument("--points", type=bounded_int(3, 64, what="a number of pot calibration points"), default=9,
                   help="pot: calibration points (default 9, the paper's)")
    p.add_argument("--verify-per-segment", type=bounded_int(0, 16, what="a number of verification points"), default=1,
                   help="pot: verification stops per segment")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run, options=CalibrateOptions.from_args)


@dataclass(frozen=True)
class CalibrateOptions:
    """``vmehil calibrate``'s options (``out``: ``--calibration``/``--out``, the file to read and write;
    ``joints``: 1-based joint numbers, empty = all)."""

    procedure: str
    rig: str | None = None
    seed: int = 0
    joints: tuple[int, ...] = ()
    auto: bool = False
    out: str | None = None
    json: str | None = None
    report: str | None = None
    write_on_fail: bool = False
    points: int = 9
    verify_per_segment: int = 1
    quiet: bool = False

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> CalibrateOptions:
        return cls(procedure=args.procedure, rig=args.rig, seed=args.seed, joints=tuple(args.joint or ()),
                   auto=args.auto, out=args.out, json=args.json, report=args.report,
                   write_on_fail=args.write_on_fail, points=args.points, verify_per_segment=args.verify_per_segment,
                   quiet=args.quiet)


def run(opts: CalibrateOptions) -> int:
    if opts.procedure == "friction" and refuse_without("vmehil calibrate friction", "tune"):
        return 2
    if opts.report and refuse_without("vmehil calibrate --report", "plots"):
        return 2
    from emulators.presets import resolve_rig
    from servo.rig import load_rig
    from vmehil.calibration.base import CalibrationContext
    from vmehil.calibration.pot import PotProcedure
    from vmehil.calibration.procedure_runner import procedure_results_table, resolve_procedure_names, run_procedures
    from vmehil.calibration.procedures import PROCEDURES
    from vmehil.calibration.store import CalibrationStore, default_store_path, load_store
    from vmehil.rig_setup.emulated_calibration import EmulatedFixture, EmulatedPositioner
    from vmehil.rig_setup.system import build_emulated_rig
    from vmehil.writers.progress import PhaseProgress

    rig = load_rig(resolve_rig(opts.rig))
    names = resolve_procedure_names(opts.procedure)
    asking = [n for n in names if PROCEDURES[n].asks_operator]
    if asking and not opts.auto and not sys.stdin.isatty():
        # it would fail at its first prompt (EOFError) with the rig built and the loop running
        raise CliError(f"{', '.join(asking)} asks the operator for joint angles and standard input is not a "
                       "terminal: run it from a terminal, or with --auto (the rig's reference fixture)")
    out = Path(opts.out) if opts.out else default_store_path(rig)
    if out.exists():
        store = load_store(out, rig)  # a foreign or malformed file is refused here, before anything runs
        print(f"calibration in force: {out} (written {store.written})")
    else:
        store = CalibrationStore.empty(rig)
        print(f"no calibration file {out} yet: starting from nominal values")
    joints = None
    if opts.joints:
        joints = [rig.joint(n).index for n in opts.joints]
    factories: dict[str, Callable[[], Procedure]] = {}
    if "pot" in names and (opts.points != 9 or opts.verify_per_segment != 1):
        factories["pot"] = lambda: PotProcedure(points=opts.points, verify_per_segment=opts.verify_per_segment)
    system = build_emulated_rig(rig, seed=opts.seed, calibration=store)
    progress = PhaseProgress(quiet=opts.quiet)
    ctx = CalibrationContext(
        rig=rig, bus=system.crate, store=store, auto=opts.auto,
        fixture=EmulatedFixture(system) if opts.auto else None,
        positioner_factory=lambda st: EmulatedPositioner(system, st),
        joints=joints, prompt=progress.ask, say=progress.say, progress=progress, options={"report": opts.report},
    )
    print(f"calibrating {', '.join(names)} on rig {rig.name}" + (" (auto: reference fixture)" if opts.auto else ""))
    try:
        with progress:
            outcome = run_procedures(ctx, names, out_path=out, write_on_fail=opts.write_on_fail,
                                     factories=factories)
    finally:
        # Procedures drive amplifiers (positioners, amplifier and friction tests): however they
        # end — done, failed, Ctrl-C, SIGTERM — the rig ends disabled, at 0 V, PWM off.
        unconfirmed = system.io.safe_stop()
        for line in unconfirmed:
            print(f"calibrate: SAFE STOP INCOMPLETE: {line}", file=sys.stderr)
        system.close()
    summary = {"rig": rig.name, "seed": opts.seed, "auto": opts.auto, **outcome.as_dict()}
    _flatten_single_joint(summary)
    if opts.json:
        write_json(opts.json, summary)
    if opts.report:
        _write_report(Path(opts.report), summary, procedure_results_table(outcome.results), outcome)
        print(f"report: {opts.report}")
    if outcome.error:
        raise CliError(outcome.error)
    return 0 if outcome.passed else 1


def _flatten_single_joint(summary: dict) -> None:
    """A run of one procedure on one joint (``vmehil calibrate friction --joint 1``) also puts
    that joint's figures at the top level of the JSON (``running_torque_oz_in.mean``, …), the
    keys users' scripts read; the nested ``procedures.<name>.joints.<joint>`` copy stays."""
    procs = summary.get("procedures") or {}
    if len(procs) != 1:
        return
    joints = next(iter(procs.values())).get("joints") or {}
    if len(joints) == 1:
        for key, value in next(iter(joints.values())).items():
            summary.setdefault(key, value)


def _write_report(folder: Path, summary: dict, table: str, outcome) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / "results.json", summary)
    write_atomic(folder / "results.txt", table + "\n")
    pot = next((r for r in outcome.results if r.procedure == "pot"), None)
    if pot is None or "joints" not in pot.data:
        return
    fig = pot_residuals_figure(pot.data["joints"], f"{summary['rig']} (seed {summary['seed']})")
    import matplotlib.pyplot as plt

    from vmehil.writers.files import save_figure

    save_figure(fig, folder / "pot_residuals", ("png",))
    plt.close(fig)


def pot_residuals_figure(joints: dict, rig: str):
    """``pot_residuals.png``: the pot error at the verification points before (nominal scaling) and
    after the calibration, one colour per joint, the legends beside the axes (never over data)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cmap = plt.get_cmap("tab10" if len(joints) <= 10 else "tab20")
    colours = [cmap(k % cmap.N) for k in range(cmap.N)]  # one colour per joint (qualitative map)
    fig, (before, after) = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    for k, (name, d) in enumerate(joints.items()):
        ver = d["verification"]
        angles = [p["angle_deg"] for p in ver]
        col = colours[k % len(colours)]
        before.plot(angles, [p["before_arcmin"] for p in ver], "x--", color=col, label=name)
        after.plot(angles, [p["residual_arcmin"] for p in ver], "o-", color=col, label=name)
    after.axhspan(-3, 3, color="0.9", zorder=0, label="±3 arcmin (≈ 1 mm at full reach)")
    before.set_title("nominal pot scaling (before)", fontsize=10)
    after.set_title("after the calibration: eight linear segments", fontsize=10)
    before.set_ylabel("pot error (arcmin)")
    after.set_ylabel("pot error (arcmin)")
    after.set_xlabel("joint angle at the verification point (deg)")
    for a in (before, after):
        a.grid(True, alpha=0.3)
    after.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    before.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, title="joint")
    fig.suptitle(f"Pot calibration of rig {rig}: error at the verification points, between the calibration points")
    fig.tight_layout()
    return fig
