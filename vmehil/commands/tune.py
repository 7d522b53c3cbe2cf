"""``vmehil tune``: gain-tuning analyses of a rig's joint servo.

Examples::

    vmehil tune bode                                  # jpl-arm joint 1 with the rig's gains
    vmehil tune bode --gains kp=200,kv=60 --json bode.json --report out/bode
    vmehil tune limit-cycle --report out/lc           # predicted and simulated, ± switch-off
    vmehil tune sweep --grid kp=80:140:4,kv=30:70:5 --out out/sweep --jobs 2
    vmehil tune sweep --engine dask --jobs 2 --out out/sweep  # a Dask LocalCluster (docs/sweeps.md)
    vmehil tune sweep --resume out/sweep                      # only the points an interruption left
    vmehil tune sweep --vary coulomb=±20% --vary tach_brush_drop=±30% --samples 40 \
        --switch-off both --threshold lc_amp_deg=0.5 --report out/tolerance
    vmehil tune step --step-deg 2 --report out/step
    vmehil tune step --plant can --interface virtual  # the plant as a CAN node (docs/can.md)

``limit-cycle``, ``step`` and ``sweep`` take the CAN plant options of ``vmehil run``
(:mod:`vmehil.option_groups.can_options`): every simulated run opens a fresh link that RESETs the plant
with the run's seed; on ``virtual`` each run starts its own in-process plant node thread on a
channel of its own, on ``socketcan``/``udp_multicast`` the runs talk to one external
``vmehil plant-node`` in turn (so ``sweep`` runs them with one worker).

Gains (``--gains`` over the rig's) are judged by :mod:`servo.gain_guard`, the servo's own check:
``bode`` analyses and reports a set it refuses, ``limit-cycle`` and ``step`` refuse to simulate it
(with the guard's reason), ``sweep`` classifies each point (``stable``, ``unstable_reason``).

Exit status: 0 on success, 1 when the gain set is refused by the guard or gives an unstable
sampled loop (``bode``, and ``limit-cycle``/``step`` refuse it), or a simulation was stopped by the
watchdog (``limit-cycle``, ``step``), 2 for bad arguments (negative/NaN/subnormal/over-limit/unknown
gains, malformed ``--gains`` text, bad rig file, a ``--vary`` spread, a Dask cluster that cannot be
reached or runs other code, ``--resume`` of another sweep), 130 when a sweep is interrupted (its
files then hold every completed point).
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hal.config import read_limited
from servo.control.gains import parse_gains
from vmehil.commands import needs_extra
from vmehil.errors import CliError
from vmehil.option_groups.can_options import CanPlantOptions
from vmehil.option_groups.cli_types import bounded_float, bounded_int, joint_number, nonzero_float, positive_float, seed
from vmehil.writers.files import write_atomic, write_json

if TYPE_CHECKING:  # the analysis needs the 'tune' extra: imported when a tune command runs
    from vmehil.analysis.rigparams import JointParams


def _common() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--rig", metavar="NAME|PATH", default=None, help="rig preset name or TOML path (default jpl-arm)")
    p.add_argument("--joint", type=joint_number, default=1, help="joint number, 1-based (default 1)")
    p.add_argument("--gains", default=None, metavar="kp=..,kpi=..,kv=..,kvi=..",
                   help="override some or all of the joint's gains (this joint only)")
    p.add_argument("--velocity-filter-hz", type=bounded_float(0.0, 1e4, what="a cutoff in Hz (0: off)"),
                   default=None, metavar="HZ",
                   help="the velocity filter alternative to KvI on this joint: KvI acts on the position error "
                        "low-passed at HZ instead of the integral of the velocity error (0: off; default: as the "
                        "rig's [joint.servo.velocity_filter]); in the model and the simulated runs alike")
    p.add_argument("--json", dest="json_path", default=None, metavar="PATH", help="write the results as JSON")
    p.add_argument("--report", default=None, metavar="DIR", help="write PNG/SVG plots and a markdown summary")
    return p


def _sim_args(p: argparse.ArgumentParser, hold: float, band: float) -> None:
    p.add_argument("--seed", metavar="N", type=seed, default=0,
                   help="seed of every noise source of the emulated rig (default 0)")
    p.add_argument("--motion", choices=("joint", "demo"), default="joint",
                   help="joint: a quintic move of this joint only (default); demo: the demo move of every joint")
    p.add_argument("--move-deg", type=nonzero_float, default=None,
                   help="size of the move (default: the demo's delta for the joint, 20° for joint 1)")
    p.add_argument("--hold", type=positive_float, default=hold, help=f"hold after the move, s (default {hold:g})")
    p.add_argument("--settle-band-deg", type=positive_float, default=band,
                   help=f"settling: into the steady-state envelope (last 2 s) ± this, deg (default {band:g})")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--calibration", default=None, metavar="PATH",
                   help="the drivers' calibration file, as vmehil run loads it (default: calibration/<rig>.toml or "
                        "$VMEHIL_CALIBRATION_DIR/<rig>.toml; none: nominal values, said); shipped with every run")
    from vmehil.option_groups.can_options import add_plant_arguments

    add_plant_arguments(p)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tune", help="gain-tuning analyses: Bode/margins, limit cycles, sweeps, step responses")
    tsub = p.add_subparsers(dest="tune_cmd", metavar="ANALYSIS")
    tsub.required = True
    common = _common()
    b = tsub.add_parser("bode", parents=[common],
                        help="margins, crossover, bandwidth; open/closed-loop and disturbance responses")
    b.set_defaults(func=run_bode, options=TuneOptions.from_args)
    lc = tsub.add_parser("limit-cycle", parents=[common],
                         help="limit cycles predicted (describing function) and simulated (full stack), "
                              "with and without integrator switch-off")
    lc.add_argument("--predict-only", action="store_true",
                    help="only the describing-function prediction (no full-stack simulation)")
    lc.add_argument("--switch-off-kp", type=positive_float, default=None,
                    help="position gain while the integrators are switched off in the prediction "
                         "(default: what the control law uses, PidLaw.kp_off)")
    _sim_args(lc, 8.0, 0.1)
    _jobs_arg(lc, "the two runs (integrators on, switch-off)")
    lc.set_defaults(func=run_limit_cycle, options=TuneOptions.from_args)
    sw = tsub.add_parser("sweep", parents=[common],
                         help="many gain sets: margins, simulated limit cycle, tracking and settling; "
                              "parallel, CSV/JSON, heat maps")
    sw.add_argument("--grid", action="append", default=None, metavar="kp=80:140:4,kv=30:70:5",
                    help=f"grid axes gain=start:stop:count or gain=v1;v2;… (repeatable; default {_default_grid()})")
    sw.add_argument("--set", dest="grid", action="append", metavar="kp=80:140:4", help="same as --grid")
    sw.add_argument("--gains-file", default=None, metavar="PATH",
                    help="a list of gain sets instead of a grid: CSV (header kp,kpi,kv,kvi) or TOML [[gains]]")
    sw.add_argument("--jobs", type=bounded_int(1, 256, what="a number of worker processes"), default=None,
                    help="worker processes of the local pool or of the Dask LocalCluster (default: os.cpu_count())")
    sw.add_argument("--engine", choices=("local", "dask"), default=None,
                    help="local: a process pool (default); dask: Dask distributed, a LocalCluster on 127.0.0.1 "
                         "or the cluster of --scheduler (docs/sweeps.md)")
    sw.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                    help="a running Dask scheduler to send the points to (implies --engine dask)")
    sw.add_argument("--resume", default=None, metavar="DIR",
                    help="continue the interrupted sweep whose sweep.json is in DIR (same options): only the "
                         "missing points are computed")
    sw.add_argument("--vary", action="append", default=None, metavar="PARAM=SPREAD",
                    help="tolerance study: vary a plant parameter (repeatable), e.g. coulomb=±20%%, "
                         "tach_brush_drop=normal:30%%, inertia=uniform:0.5 (absolute, SI); parameters: "
                         "coulomb, viscous, ripple, tach_brush_drop, inertia, gear_ratio, adc_noise")
    sw.add_argument("--samples", type=bounded_int(1, 100_000, what="a number of samples"), default=None,
                    help="tolerance study: samples per gain set (default 20 with --vary), drawn from --seed")
    sw.add_argument("--threshold", action="append", default=None, metavar="METRIC=VALUE",
                    help="tolerance study: report the fraction of samples over VALUE, e.g. lc_amp_deg=0.5 "
                         "(repeatable)")
    sw.add_argument("--switch-off", choices=("off", "on", "both"), default="off",
                    help="integrator switch-off in the simulated runs: off (default), on, or both (every point "
                         "twice)")
    sw.add_argument("--x", default=None, help="heat-map x gain (default: the first gain that varies)")
    sw.add_argument("--y", default=None, help="heat-map y gain (default: the second gain that varies)")
    sw.add_argument("--out", default=None, metavar="DIR",
                    help="write sweep.csv and sweep.json here (default: the --report folder, else ./sweep-out)")
    sw.add_argument("--margins-only", action="store_true", help="no simulations: margins only (fast)")
    sw.add_argument("--batch", default="auto", metavar="N|auto",
                    help="points per worker task, their full-stack runs stepped in lockstep in one process as one "
                         "rig of lanes (8 or more; bit-identical rows); auto (default): sized by the points, workers "
                         "and free memory; 1: one point per task (docs/sweeps.md, \"Batched lockstep\")")
    _sim_args(sw, 8.0, 0.1)
    sw.set_defaults(func=run_sweep, options=TuneOptions.from_args)
    st = tsub.add_parser("step", parents=[common],
                         help="step and quintic-move responses through the full stack, over the linear prediction")
    st.add_argument("--step-deg", type=nonzero_float, default=2.0, help="step size, deg (default 2)")
    st.add_argument("--switch-off", choices=("rig", "on", "off"), default="rig",
                    help="integrator switch-off: as the rig says (default), forced on, or off")
    _sim_args(st, 4.0, 0.1)
    _jobs_arg(st, "the two runs (step, quintic move)")
    st.set_defaults(func=run_step, options=TuneOptions.from_args)


@dataclass(frozen=True)
class TuneOptions:
    """The options of every ``vmehil tune`` analysis (``tune_cmd``); an option an analysis does not
    take holds its default. ``gains``: ``--gains`` parsed (this joint's, over the rig's);
    ``plant``: ``--plant can``'s options, None for the in-process plant."""

    tune_cmd: str
    rig: str | None = None
    joint: int = 1
    gains: dict[str, float] = field(default_factory=dict)
    json_path: str | None = None
    report: str | None = None
    # the simulating analyses (limit-cycle, sweep, step)
    seed: int = 0
    motion: str = "joint"
    move_deg: float | None = None
    hold: float = 8.0
    settle_band_deg: float = 0.1
    quiet: bool = False
    calibration: str | None = None
    plant: CanPlantOptions | None = None
    jobs: int | None = None
    # limit-cycle
    predict_only: bool = False
    switch_off_kp: float | None = None
    #: --velocity-filter-hz (None: the rig's; 0: off)
    velocity_filter_hz: float | None = None
    # sweep
    grid: tuple[str, ...] = ()
    gains_file: str | None = None
    engine: str | None = None
    scheduler: str | None = None
    resume: str | None = None
    vary: tuple[str, ...] = ()
    samples: int | None = None
    threshold: tuple[str, ...] = ()
    x: str | None = None
    y: str | None = None
    out: str | None = None
    margins_only: bool = False
    batch: str = "auto"
    # sweep (off|on|both) and step (rig|on|off)
    switch_off: str = "off"
    # step
    step_deg: float = 2.0

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> TuneOptions:
        def given(name: str, default: Any = None) -> Any:  # an option of some analyses only
            return getattr(args, name, default)

        return cls(tune_cmd=args.tune_cmd, rig=args.rig, joint=args.joint,
                   gains=parse_gains(args.gains, what="--gains"), json_path=args.json_path, report=args.report,
                   seed=given("seed", 0), motion=given("motion", "joint"), move_deg=given("move_deg"),
                   hold=given("hold", 8.0), settle_band_deg=given("settle_band_deg", 0.1), quiet=given("quiet", False),
                   calibration=given("calibration"),
                   plant=CanPlantOptions.from_args(args) if hasattr(args, "plant") else None, jobs=given("jobs"),
                   predict_only=given("predict_only", False), switch_off_kp=given("switch_off_kp"),
                   velocity_filter_hz=given("velocity_filter_hz"),
                   grid=tuple(given("grid") or ()), gains_file=given("gains_file"), engine=given("engine"),
                   scheduler=given("scheduler"), resume=given("resume"), vary=tuple(given("vary") or ()),
                   samples=given("samples"), threshold=tuple(given("threshold") or ()), x=given("x"), y=given("y"),
                   out=given("out"), margins_only=given("margins_only", False), batch=given("batch", "auto"),
                   switch_off=given("switch_off", "off"), step_deg=given("step_deg", 2.0))


def _jobs_arg(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--jobs", type=bounded_int(1, 256, what="a number of worker processes"), default=None,
                   help=f"worker processes for {what}: side by side, one per core (default: os.cpu_count()); "
                        "1: one after the other in this process, with a bar per run")


def _simulate_runs(opts: TuneOptions, jobs: list, labels: list[str], links,
                   meanwhile: Callable[[], None] | None = None) -> list[dict[str, Any]]:
    """The full-stack runs ``jobs`` (:class:`~vmehil.analysis.simulate.SimJob`), side by side in
    worker processes (one per core, ``--jobs``), each a complete safe-stopping run, or one after
    the other here (``--jobs 1``, or a CAN plant that serves one run at a time). Results in order;
    Ctrl-C stops every run (amplifiers safe) and raises KeyboardInterrupt (exit status 130).
    ``meanwhile()``: this process's own work, done while the workers run (with ``--jobs 1``: first)."""
    import os

    from vmehil.analysis.parallel import ParallelInterrupted, run_parallel
    from vmehil.analysis.simulate import run_job, simulate
    from vmehil.writers.progress import TickProgress, progress_bar

    n = min(len(jobs), opts.jobs or os.cpu_count() or 1)
    if links is not None and not links.shareable:
        n = 1
    if n <= 1:
        if meanwhile is not None:
            meanwhile()
        out = []
        for job, label in zip(jobs, labels, strict=True):
            with TickProgress(f"simulating ({label})", quiet=opts.quiet) as progress:
                out.append(simulate(job.jp, switch_off=job.switch_off, settings=job.settings, step_deg=job.step_deg,
                                    traces=job.traces, progress=progress, link_factory=job.link_factory))
        return out
    with progress_bar(f"simulating ({', '.join(labels)})", len(jobs), quiet=opts.quiet, unit="run") as bar:
        try:
            return run_parallel(run_job, jobs, jobs=n, on_result=lambda _i, _r: bar.update(1),
                                finished=lambda r: r is not None, meanwhile=meanwhile)
        except ParallelInterrupted:
            raise KeyboardInterrupt from None


def _default_grid() -> str:
    try:
        from vmehil.analysis.sweep import DEFAULT_GRID
    except ImportError:  # without the 'tune' extra the parser is still built; `vmehil tune` says what is missing
        return "see vmehil.analysis.sweep"
    return DEFAULT_GRID


def _command_line(opts: TuneOptions) -> str:
    argv = sys.argv[1:] if sys.argv and Path(sys.argv[0]).name in ("vmehil", "__main__.py") else None
    if argv:
        return "vmehil " + " ".join(shlex.quote(a) for a in argv)
    return f"vmehil tune {opts.tune_cmd}"


def _load(opts: TuneOptions) -> JointParams:
    from vmehil.analysis.rigparams import load_joint

    return load_joint(opts.rig, opts.joint, gains=opts.gains, switch_off_kp=opts.switch_off_kp,
                      velocity_filter_hz=opts.velocity_filter_hz)


def _link_factory(opts: TuneOptions):
    """``--plant can``: a :class:`~vmehil.option_groups.can_options.CanLinkFactory`; else None (in-process)."""
    from vmehil.option_groups.can_options import link_factory

    return link_factory(opts.plant)


def _tagged(factory, tag: str):
    return None if factory is None else factory.tagged(tag)


def _sim_settings(opts: TuneOptions, jp, allow_short: bool = False):
    """The simulations' settings, with the drivers' calibration loaded here once, as `vmehil run`
    loads it (it was ignored: 1.14° of static error on the true angle in a calibrated directory),
    and said on stderr; it travels with every run (worker processes, Dask) as data."""
    from servo.rig import load_rig
    from vmehil.analysis.simulate import SimSettings
    from vmehil.calibration.store import load_store_or_nominal
    from vmehil.commands.calibration_file import calibrated

    rig = jp.spec if jp.spec is not None else load_rig(jp.rig_path)
    store = calibrated(opts.calibration, rig, lambda cal: load_store_or_nominal(cal, rig))
    return SimSettings(seed=opts.seed, motion=opts.motion, move_deg=opts.move_deg, hold_s=opts.hold,
                       settle_band_deg=opts.settle_band_deg, allow_short=allow_short, calibration=store)


# ------------------------------------------------------------------------------- bode


@needs_extra("tune", "vmehil tune")
def run_bode(opts: TuneOptions) -> int:
    from vmehil.analysis import report
    from vmehil.analysis.tuning import bode_analysis

    jp = _load(opts)
    verdict = _guard(jp)  # an unstable set is analysed and reported, not hidden (exit status 1)
    result = bode_analysis(jp)
    text = report.bode_text(result)
    print("vmehil tune bode — open loop broken at the plant input")
    print(text)
    files: list[Path] = []
    if opts.report:
        d = Path(opts.report)
        imgs = []
        files += report.save_figure_both(report.bode_figure(jp.cfg, result), d, "bode_open_loop")
        imgs.append("bode_open_loop.png")
        files += report.save_figure_both(report.responses_figure(jp.cfg, result, jp.inertia_kg_m2), d,
                                         "closed_loop_and_disturbance")
        imgs.append("closed_loop_and_disturbance.png")
        md = report.markdown(f"Bode analysis — {jp.rig} joint {jp.joint}", _command_line(opts), text, imgs)
        files.append(write_atomic(d / "summary.md", md))
        result["report_files"] = [str(f) for f in files]
    if opts.json_path:
        files.append(write_json(opts.json_path, result))
    for f in files:
        print(f"wrote {f}")
    if not verdict.ok:
        print(f"vmehil tune bode: gains {jp.cfg.gains} refused by servo.gain_guard (UNSTABLE): {verdict.reason}",
              file=sys.stderr)
    if not result["stable"]:
        print(f"vmehil tune bode: the sampled closed loop is UNSTABLE with gains {jp.cfg.gains}", file=sys.stderr)
    return 0 if verdict.ok and result["stable"] else 1


# ------------------------------------------------------------------------ limit cycle


def _unstable_message(jp: JointParams, switch_off: bool | None) -> str | None:
    """Why the joint's gains may not be simulated, or None: refused by :mod:`servo.gain_guard` (the
    servo's own check, the reason every entry point gives), or unstable in the sampled linear model
    with the rig's sensor and amplifier lags. ``switch_off``: judge the switched-off loop too (None:
    as the rig says). A value no gain may have is a :class:`GainRejected` (exit status 2)."""
    from vmehil.analysis.loop_model import is_stable

    verdict = _guard(jp, switch_off)
    if not verdict.ok:
        return f"gains {jp.cfg.gains} refused by servo.gain_guard (UNSTABLE): {verdict.reason}"
    if is_stable(jp.cfg, sampled=True):
        return None
    return (f"the sampled linear loop is UNSTABLE with gains {jp.cfg.gains}: a limit-cycle analysis needs a "
            f"stable loop (see `vmehil tune bode`); lower the gains or raise Kv")


def _guard(jp: JointParams, switch_off: bool | None = None):
    """:meth:`JointParams.verdict`; raises :class:`GainRejected` for an invalid value (not unstable)."""
    from servo.gain_guard import GainRejected

    verdict = jp.verdict(switch_off)
    if verdict.kind == "invalid":
        raise GainRejected(str(jp.cfg.gains), None, verdict.reason)
    return verdict


@needs_extra("tune", "vmehil tune")
def run_limit_cycle(opts: TuneOptions) -> int:
    from vmehil.analysis import report
    from vmehil.analysis.simulate import SimJob, strip_traces
    from vmehil.analysis.tuning import add_simulations, limit_cycle_prediction

    jp = _load(opts)
    bad = _unstable_message(jp, switch_off=True)  # it simulates the switched-off loop as well
    if bad:
        print(f"vmehil tune limit-cycle: {bad}", file=sys.stderr)
        return 1
    predicted: list[dict[str, Any]] = []

    def predict() -> None:
        predicted.append(limit_cycle_prediction(jp, with_traces=bool(opts.report)))

    if opts.predict_only:
        predict()
        result = predicted[0]
    else:
        # The two full-stack runs start first, in worker processes (--jobs); this process computes
        # the describing-function prediction while they run (same figures as one after the other).
        settings = _sim_settings(opts, jp)
        links = _link_factory(opts)
        modes = (False, True)
        labels = ["integrators on", "switch-off"]
        jobs = [SimJob(jp, mode, settings, _tagged(links, label.replace(" ", "-")))
                for mode, label in zip(modes, labels, strict=True)]
        runs = dict(zip(modes, _simulate_runs(opts, jobs, labels, links, meanwhile=predict), strict=True))
        result = add_simulations(predicted[0], jp, lambda _jp, switch_off: runs[switch_off])
    text = report.limit_cycle_text(result)
    print("vmehil tune limit-cycle — describing-function prediction of the sampled loop"
          + ("" if opts.predict_only else " and the full-stack simulation"))
    print(text)
    files: list[Path] = []
    if opts.report:
        d = Path(opts.report)
        imgs = []
        views = (("df_nyquist", jp.cfg, result["predicted"], "integrators on"),
                 ("df_nyquist_switch_off", jp.switch_off_cfg(), result["switch_off"]["predicted"],
                  "integrators switched off"))
        for stem, cfg, block, label in views:
            nl, cfg_plot, cyc, what = _df_view(jp, cfg, block)
            if nl is None:
                continue
            title = f"{what} — {label}\n({report._gain_text(cfg)})"
            fig = report.nyquist_df_figure(cfg_plot, nl, cyc, title=title)
            files += report.save_figure_both(fig, d, stem)
            imgs.append(f"{stem}.png")
        sim_fig = report.limit_cycle_sim_figure(result.get("simulated"), result["switch_off"].get("simulated"),
                                                result["predicted"],
                                                f"Full-stack simulation, {jp.rig} joint {jp.joint} ({jp.name}), "
                                                f"{report._gain_text(jp.cfg)}")
        if sim_fig is not None:
            files += report.save_figure_both(sim_fig, d, "cycle_simulated")
            imgs.append("cycle_simulated.png")
        traces = [("integrators on: reduced nonlinear joint", result.get("model_check")),
                  ("switched off: reduced nonlinear joint", result["switch_off"].get("model_check"))]
        check_fig = report.cycle_time_figure(traces, f"Reduced-model check, {jp.rig} joint {jp.joint}")
        if check_fig is not None:
            files += report.save_figure_both(check_fig, d, "cycle_model_check")
            imgs.append("cycle_model_check.png")
        md = report.markdown(f"Limit cycles — {jp.rig} joint {jp.joint}", _command_line(opts), text, imgs)
        files.append(write_atomic(d / "summary.md", md))
        result["report_files"] = [str(f) for f in files]
    out = _strip_model_traces(result)
    out["simulated"] = strip_traces(out.get("simulated"))
    out["switch_off"]["simulated"] = strip_traces(out["switch_off"].get("simulated"))
    if opts.json_path:
        files.append(write_json(opts.json_path, out))
    for f in files:
        print(f"wrote {f}")
    faults = [s["fault"] for s in (result.get("simulated"), result["switch_off"].get("simulated")) if s and s["fault"]]
    if faults:
        print(f"vmehil tune limit-cycle: the watchdog stopped a simulation: {faults[0]['cause']} "
              f"({faults[0]['detail']})", file=sys.stderr)
        return 1
    return 0


def _df_view(jp: JointParams, cfg, block: dict):
    """What the Nyquist/DF plot shows: for a combined dead-band + friction cycle, the dead band's
    G with the friction replaced by its equivalent damping at the cycle's velocity amplitude (so
    the intersection is the predicted cycle); otherwise the headline (or tach) nonlinearity alone."""
    from vmehil.analysis.describing import predict_cycles

    nls = jp.nonlinearities()
    h = next((c for c in block.get("combined_cycles", []) if c["stable"]
              and c["amplitude_deg"] == block.get("amplitude_deg")), None)
    dz = next((n for n in nls if n.location == "velocity_sensor"), None)
    fr = next((n for n in nls if n.location == "friction"), None)
    if h is not None and dz is not None and fr is not None:
        cfg_eq = cfg.replace(viscous_damping=cfg.viscous_damping + fr.df(h["amplitude_x"]))
        cyc = [c.as_dict() for c in predict_cycles(cfg_eq, dz, sampled=True)]
        return dz, cfg_eq, cyc, f"{dz.name}; Coulomb friction as its equivalent damping at the cycle"
    nl = _headline_nl(jp, block)
    if nl is None:
        return None, cfg, [], ""
    return nl, cfg, [c for c in block["cycles"] if c["nonlinearity"] == nl.name], f"{nl.name} alone"


def _headline_nl(jp: JointParams, block: dict):
    """The nonlinearity whose Nyquist/DF picture is drawn: the headline one when it is a single
    nonlinearity, else the tach dead band (the mechanism of the JPL cycle), else the first."""
    nls = jp.nonlinearities()
    name = block.get("nonlinearity")
    match = next((n for n in nls if n.name == name), None)
    if match is not None:
        return match
    return next((n for n in nls if n.location == "velocity_sensor"), nls[0] if nls else None)


def _strip_model_traces(result: dict) -> dict:
    """JSON keeps figures, not sample-by-sample traces of the model check."""
    out = dict(result)
    if out.get("model_check"):
        out["model_check"] = {k: v for k, v in out["model_check"].items() if k not in ("t_s", "theta_deg")}
    so = dict(out["switch_off"])
    if so.get("model_check"):
        so["model_check"] = {k: v for k, v in so["model_check"].items() if k not in ("t_s", "theta_deg")}
    out["switch_off"] = so
    return out


# ------------------------------------------------------------------------------ sweep


@needs_extra("tune", "vmehil tune")
def run_sweep(opts: TuneOptions) -> int:
    import tomllib

    from servo.control.gains import GAIN_NAMES
    from vmehil.analysis import report
    from vmehil.analysis.parallel import EngineError
    from vmehil.analysis.sweep import (
        DEFAULT_GRID,
        BatchedWrites,
        SweepInterrupted,
        SweepTask,
        check_sweep_size,
        evaluate_points,
        grid_points,
        load_gains_file,
        parse_grid,
        rig_text,
        rows_csv,
        task_rig,
        text_sha256,
    )
    from vmehil.analysis.tolerance import draw_samples, nominal_values, parse_varies
    from vmehil.analysis.tolerance_report import parse_thresholds
    from vmehil.writers.progress import progress_bar

    jp = _load(opts)
    base = jp.cfg.gains
    if opts.gains_file and opts.grid:
        raise CliError("give either --grid/--set or --gains-file, not both")
    spreads = parse_varies(opts.vary or [])
    thresholds = parse_thresholds(opts.threshold or [])
    if opts.samples is not None and not spreads:
        raise CliError("--samples needs --vary: the samples of a tolerance study differ by the varied plant values")
    if thresholds and not spreads:
        raise CliError("--threshold reports over the samples of a tolerance study: give --vary too")
    if spreads and opts.margins_only:
        raise CliError("--vary with --margins-only: a tolerance study simulates every sample; drop one of them")
    if opts.gains_file:
        points = load_gains_file(opts.gains_file, base)
        axes_names = [k for k in GAIN_NAMES if len({p[k] for p in points}) > 1]
        grid_text = None
    elif spreads and not opts.grid:  # a tolerance study of the rig's gains (or --gains)
        points = [base.as_dict()]
        axes_names = []
        grid_text = None
    else:
        grid_text = ",".join(opts.grid) if opts.grid else DEFAULT_GRID
        axes = parse_grid(grid_text)
        points = grid_points(axes, base)
        axes_names = [k for k in axes if len(axes[k]) > 1]
    if opts.jobs is not None and opts.jobs < 1:
        raise CliError(f"--jobs {opts.jobs} must be at least 1")
    engine_name = "dask" if opts.scheduler else (opts.engine or "local")
    if opts.scheduler and opts.engine == "local":
        raise CliError("--scheduler sends the points to a Dask cluster: it needs --engine dask (or no --engine)")
    if engine_name == "dask":
        from vmehil.commands import refuse_without

        if refuse_without("vmehil tune sweep --engine dask", "dask"):
            return 2
    if opts.scheduler and opts.jobs is not None:
        print(f"note: --jobs {opts.jobs} is ignored with --scheduler: the cluster's workers are what it has",
              file=sys.stderr)
    links = None if opts.margins_only else _link_factory(opts)
    jobs = opts.jobs
    if links is not None and not links.shareable:
        iface, chan = links.options.resolved()
        if engine_name == "dask":
            raise CliError(f"--engine dask with --plant can on {iface} {chan}: the one external plant node serves "
                             "one run at a time; use the local engine with --jobs 1, or --interface virtual")
        if jobs is not None and jobs > 1:
            raise CliError(f"--jobs {jobs} with --plant can on {iface} {chan}: the one external plant node serves "
                             "one run at a time; use --jobs 1, or --interface virtual (each worker then runs its "
                             "own in-process plant node)")
        jobs = 1
    from vmehil.analysis.batch import parse_batch

    batch_req = parse_batch(opts.batch)
    if batch_req is not None and batch_req > 1 and links is not None:
        raise CliError(f"--batch {batch_req} with --plant can: a batch runs its plants in-process; use --batch 1")
    x = opts.x or (axes_names[0] if axes_names else "kp")
    y = opts.y or (axes_names[1] if len(axes_names) > 1 else next(k for k in GAIN_NAMES if k != x))
    for name, v in (("--x", x), ("--y", y)):
        if v not in GAIN_NAMES:
            raise CliError(f"{name} {v!r} must be one of {', '.join(GAIN_NAMES)}")
    n_samples = (opts.samples or 20) if spreads else 1
    modes = {"off": [False], "on": [True], "both": [False, True]}[opts.switch_off]
    check_sweep_size(len(points), len(modes), n_samples)  # before anything is loaded, drawn or made
    settings = _sim_settings(opts, jp, allow_short=True)
    if settings.hold_s < 8.0 and not opts.margins_only:
        print(f"note: a {settings.hold_s:g} s hold is too short for a reliable limit-cycle figure (use ≥ 8 s)",
              file=sys.stderr)
    # The rig travels parsed (its plant values drawn) with the servo's typed settings in every task:
    # no worker reads this machine's disk, nothing is parsed again per point.
    text = rig_text(jp.rig_path)
    draws: list[dict[str, float]] = [{}]
    if spreads:
        draws = draw_samples(spreads, nominal_values(tomllib.loads(text), jp.joint, str(jp.rig_path)),
                             n_samples, opts.seed)
    rigs = [task_rig(text, jp.rig_path, jp.joint, plant) for plant in draws]
    tasks: list[SweepTask] = []
    for g in points:
        for so in modes:
            for k, plant in enumerate(draws):
                i = len(tasks)
                tasks.append(SweepTask(i, jp.rig_path, jp.joint, g, settings, simulate=not opts.margins_only,
                                       link_factory=_tagged(links, f"p{i}"), rig=rigs[k], servo=jp.servo,
                                       switch_off=so, plant=plant, sample=k if spreads else None))
    # --batch: refused here, before any file is written, for a rig with a board type that cannot batch
    batch_size, batch_note = 1, None
    if not opts.margins_only and links is None:
        from vmehil.analysis.batch import choose_batch, cpu_workers

        batch_size, batch_note = choose_batch(batch_req, len(tasks), cpu_workers(jobs), rigs[0])
    if batch_note:
        print(f"note: {batch_note}", file=sys.stderr)
    out_dir = Path(opts.resume or opts.out or opts.report or "sweep-out")
    csv_path, json_path = out_dir / "sweep.csv", Path(opts.json_path) if opts.json_path else out_dir / "sweep.json"
    # What makes two runs the same sweep (checked by --resume): the points, the rig's content, the
    # simulation and its seed, the study.
    identity = {"rig_sha256": text_sha256(text), "joint": jp.joint,
                "points_sha256": text_sha256(repr(points)), "points": len(tasks),
                "simulation": None if opts.margins_only else _settings_meta(settings),
                "switch_off": opts.switch_off, "vary": [s.text() for s in spreads],
                "samples": n_samples if spreads else None}
    meta: dict[str, Any] = {
        "command": "tune sweep", "rig": jp.rig, "joint": jp.joint, "joint_name": jp.name,
        "base_gains": base.as_dict(), "grid": grid_text, "gains_file": opts.gains_file,
        "simulation": None if opts.margins_only else {
            **_settings_meta(settings),  # switch_off: false as before; true (--switch-off on) or "both"
            "switch_off": {"off": False, "on": True}.get(opts.switch_off, opts.switch_off)},
        "points_total": len(tasks), "heatmap_axes": [x, y], "engine": engine_name, "identity": identity,
    }
    if spreads:
        meta["tolerance"] = {"vary": [s.text() for s in spreads], "samples": n_samples, "seed": opts.seed,
                             "thresholds": thresholds}
    done_rows = _resumed_rows(json_path, identity) if opts.resume else []

    def write(rows: list[dict[str, Any]], done: bool, interrupted: bool = False) -> None:
        write_atomic(csv_path, rows_csv(rows))
        write_json(json_path, {**meta, "completed": len(rows), "finished": done,
                               "interrupted": interrupted, "rows": rows})

    write(done_rows, False)
    engine = None
    if engine_name == "dask":
        from vmehil.analysis.dask_engine import DaskEngine

        try:
            engine = DaskEngine(opts.scheduler, jobs).open()
        except EngineError as e:
            print(f"vmehil tune sweep: {e}", file=sys.stderr)
            return 2
        where = engine.describe()
    else:
        where = f"{jobs or 'all'} worker(s)"
    todo = len(tasks) - len(done_rows)
    if batch_size > 1:
        where += f", batches of {batch_size} in lockstep"
    what = f"{len(points)} gain sets" + (f" × {n_samples} samples" if spreads else "") + \
        (" × switch-off on/off" if len(modes) > 1 else "")
    print(f"vmehil tune sweep — {jp.rig} joint {jp.joint} ({jp.name}): {what} = {len(tasks)} points"
          + (f" ({len(done_rows)} done before, {todo} to go)" if opts.resume else "")
          + f", {where}; writing {csv_path} and {json_path}")
    # sweep.csv/.json at most once a second (every completed row is on disk within ~1 s), and
    # with every row at the end, on interruption and on an error
    batch = BatchedWrites(lambda rows: write(rows, False))
    try:
        with progress_bar("sweep", len(tasks), quiet=opts.quiet, unit="point", initial=len(done_rows)) as bar:

            def on_result(row: dict[str, Any], rows: list[dict[str, Any]]) -> None:
                batch.result(rows)
                bar.set_postfix_str(f"last: {_point_text(row)}", refresh=False)
                bar.update(1)

            rows = evaluate_points(tasks, jobs=jobs, engine=engine, done=done_rows, on_result=on_result,
                                   on_idle=batch.idle, batch=batch_size)
    except SweepInterrupted as e:
        write(e.rows, False, interrupted=True)
        print(f"vmehil tune sweep: interrupted; {len(e.rows)} of {len(tasks)} points kept in {csv_path} and "
              f"{json_path} (continue with --resume {out_dir})", file=sys.stderr)
        return 130
    except EngineError as e:  # a refused result, a point that failed on a Dask worker: keep what finished
        batch.flush()
        print(f"vmehil tune sweep: {e}; the points that finished are kept in {csv_path} and {json_path} "
              f"(--resume {out_dir} runs the rest)", file=sys.stderr)
        return 1
    except BaseException:
        batch.flush()  # the rows computed before the error are kept
        raise
    finally:
        if engine is not None:  # run_parallel closed it; again (a no-op) if it never started
            engine.close()
    # Ctrl-C after the last point (the engine's SIGINT handling has ended): every row is
    # computed; the files are written atomically, so they hold the last complete version
    try:
        write(rows, True)
        files = [csv_path, json_path]
        if spreads:
            files += _tolerance_outputs(opts, jp, rows, spreads, thresholds, meta, write)
        else:
            print(_sweep_table(rows))
        if opts.report and not spreads:
            d = Path(opts.report)
            fig = report.sweep_heatmaps(rows, x, y, f"Gain sweep, {jp.rig} joint {jp.joint} ({jp.name})")
            imgs = []
            if fig is not None:
                files += report.save_figure_both(fig, d, f"heatmap_{x}_{y}")
                imgs.append(f"heatmap_{x}_{y}.png")
            md = report.markdown(f"Gain sweep — {jp.rig} joint {jp.joint}", _command_line(opts),
                                 _sweep_table(rows), imgs)
            files.append(write_atomic(d / "summary.md", md))
        for f in files:
            print(f"wrote {f}")
        return 0
    except KeyboardInterrupt:
        print(f"vmehil tune sweep: interrupted after its last point; the rows are in {csv_path} and "
              f"{json_path} (--resume {out_dir} finishes the files)", file=sys.stderr)
        return 130


def _settings_meta(settings) -> dict[str, Any]:
    cal = settings.calibration
    return {"motion": settings.motion, "move_deg": settings.move_deg, "speed": settings.speed,
            "hold_s": settings.hold_s, "seed": settings.seed, "settle_band_deg": settings.settle_band_deg,
            "calibration": None if cal is None else {"path": str(cal.path), "written": cal.written}}


def _resumed_rows(json_path: Path, identity: dict[str, Any]) -> list[dict[str, Any]]:
    """The rows of the interrupted sweep in ``json_path``, after checking it is this sweep."""
    import json

    if not json_path.exists():
        raise FileNotFoundError(f"--resume: {json_path} does not exist; resume names the folder of an earlier "
                                "sweep (its --out)")
    try:
        # a sweep's JSON holds < 16 KiB a point; the bound keeps a wrong path (a device) from filling memory
        stored = json.loads(read_limited(json_path, (1 << 20) + (16 << 10) * int(identity["points"]), "a sweep's JSON"))
    except ValueError as e:
        raise CliError(f"--resume: {json_path} is not a sweep's JSON ({e})") from None
    theirs = stored.get("identity") if isinstance(stored, dict) else None
    if not isinstance(theirs, dict):
        raise CliError(f"--resume: {json_path} holds no sweep identity (written by an older vmehil?); "
                         "run the sweep again without --resume")
    differ = [k for k in identity if theirs.get(k) != identity[k]]
    if differ:
        detail = "; ".join(f"{k}: stored {theirs.get(k)!r}, now {identity[k]!r}" for k in differ)
        raise CliError(f"--resume: {json_path} is another sweep ({detail}); give the same rig, grid, "
                         "simulation options, seed and study as the interrupted run")
    return [r for r in stored.get("rows", []) if r.get("status") != "interrupted"]


def _tolerance_outputs(opts: TuneOptions, jp: JointParams, rows: list[dict[str, Any]], spreads,
                       thresholds: dict[str, float], meta: dict[str, Any], write) -> list[Path]:
    """A tolerance study's summary (percentiles, fractions over thresholds) into the JSON, printed,
    and with --report its histograms and summary.md."""
    from vmehil.analysis import report
    from vmehil.analysis.tolerance_report import histogram_figure, summarize, summary_text

    summary = summarize(rows, thresholds)
    meta["tolerance"]["summary"] = summary
    write(rows, True)
    title = (f"Tolerance study, {jp.rig} joint {jp.joint} ({jp.name}): "
             + ", ".join(s.text() for s in spreads) + f"; {meta['tolerance']['samples']} samples")
    text = summary_text(summary)
    print(title)
    print(text)
    files: list[Path] = []
    if opts.report:
        d = Path(opts.report)
        files += report.save_figure_both(histogram_figure(rows, thresholds, title), d, "tolerance_histograms")
        md = report.markdown(title, _command_line(opts), text, ["tolerance_histograms.png"])
        files.append(write_atomic(d / "summary.md", md))
    return files


def _point_text(r: dict[str, Any]) -> str:
    from servo.control.gains import GAIN_NAMES

    g = " ".join(f"{k}={r[k]:g}" for k in GAIN_NAMES)
    if r["status"] != "ok":
        return f"{g}: {r['status']}"
    lc = "no cycle" if r["lc_frequency_hz"] is None else f"±{r['lc_amplitude_deg']:.2f}°"
    return f"{g}: {lc}"


def _sweep_table(rows: list[dict[str, Any]]) -> str:
    from servo.control.gains import GAIN_NAMES
    from vmehil.analysis.report import fmt

    head = (*GAIN_NAMES, "PM °", "GM dB", "LC amp °", "LC Hz", "rms track °", "max track °", "settle s", "status")
    lines = [head]
    for r in rows:
        lines.append((*(f"{r[k]:g}" for k in GAIN_NAMES),
                      fmt(r["phase_margin_deg"], ".1f", none="—"), fmt(r["gain_margin_db"], ".1f"),
                      fmt(r["lc_amplitude_deg"], ".3f", none="—"), fmt(r["lc_frequency_hz"], ".2f", none="—"),
                      fmt(r["rms_tracking_error_deg"], ".3f", none="—"),
                      fmt(r["max_tracking_error_deg"], ".3f", none="—"),
                      fmt(r["settling_time_s"], ".2f", none="never" if r["status"] == "ok" else "—"), r["status"]))
    w = [max(len(row[i]) for row in lines) for i in range(len(head))]
    out = ["  ".join(c.rjust(w[i]) for i, c in enumerate(row)) for row in lines]
    out.insert(1, "  ".join("-" * n for n in w))
    return "\n".join(out)


# ------------------------------------------------------------------------------- step


@needs_extra("tune", "vmehil tune")
def run_step(opts: TuneOptions) -> int:
    import numpy as np

    from vmehil.analysis import report
    from vmehil.analysis.simulate import SimJob, linear_prediction, step_metrics, strip_traces

    jp = _load(opts)
    so = {"rig": None, "on": True, "off": False}[opts.switch_off]
    bad = _unstable_message(jp, switch_off=so)
    if bad:
        print(f"vmehil tune step: {bad}", file=sys.stderr)
        return 1
    settings = _sim_settings(opts, jp, allow_short=True)
    links = _link_factory(opts)
    step, move = _simulate_runs(opts, [SimJob(jp, so, settings, _tagged(links, "step"), step_deg=opts.step_deg),
                                       SimJob(jp, so, settings, _tagged(links, "move"))],
                                ["step", "quintic move"], links)
    T = jp.cfg.sample_period_s
    lin = {}
    for name, d in (("step", step), ("move", move)):
        thd = np.radians(d["theta_d_deg"])
        wd = np.radians(d["omega_d_deg_s"])
        ad = np.gradient(wd, T) if name == "move" else np.zeros_like(wd)
        lin[name] = linear_prediction(jp, np.asarray(d["t_s"]), thd, wd, ad, math.radians(d["theta_start_deg"]))
    result: dict[str, Any] = {"command": "tune step", **jp.describe(),
                              "switch_off": opts.switch_off, "step_deg": opts.step_deg}
    for name, d in (("step", step), ("move", move)):
        result[name] = {"simulated": {**strip_traces(d), **step_metrics(d, None, opts.settle_band_deg)},
                        "linear": step_metrics(d, lin[name], opts.settle_band_deg)}
    text = _step_text(result)
    print(f"vmehil tune step — {jp.rig} joint {jp.joint} ({jp.name}), full stack vs the sampled linear loop")
    print(text)
    files: list[Path] = []
    if opts.report:
        out_dir = Path(opts.report)
        fig = report.step_figure(step, lin["step"], move, lin["move"],
                                 f"{jp.rig} joint {jp.joint} ({jp.name}), {report._gain_text(jp.cfg)}, "
                                 f"switch-off: {opts.switch_off}")
        files += report.save_figure_both(fig, out_dir, "step_and_move")
        md = report.markdown(f"Step and move — {jp.rig} joint {jp.joint}", _command_line(opts), text,
                             ["step_and_move.png"])
        files.append(write_atomic(out_dir / "summary.md", md))
    if opts.json_path:
        files.append(write_json(opts.json_path, result))
    for f in files:
        print(f"wrote {f}")
    faults = [s["fault"] for s in (step, move) if s["fault"]]
    if faults:
        print(f"vmehil tune step: the watchdog stopped a simulation: {faults[0]['cause']} ({faults[0]['detail']})",
              file=sys.stderr)
        return 1
    return 0


def _step_text(r: dict[str, Any]) -> str:
    from vmehil.analysis.report import _gains_line, fmt

    g = r["gains"]
    lines = [f"gains {_gains_line(g)} [{r['gains_source']}]; integrator switch-off: {r['switch_off']}", "",
             f"{'':34s}{'simulated':>12s}{'linear':>12s}"]
    rows = (("step", f"step {r['step_deg']:g}°"), ("move", f"quintic move {r['move']['simulated']['move_deg']:g}°"))
    for key, label in rows:
        s, lin = r[key]["simulated"], r[key]["linear"]
        lines.append(label)
        for k, name, spec in (("overshoot_pct", "  overshoot (%)", ".1f"), ("rise_time_s", "  rise 10–90 % (s)", ".3f"),
                              ("max_tracking_error_deg", "  max tracking error (deg)", ".3f"),
                              ("settling_time_s", f"  settling ±{s['settle_band_deg']:g}° (s)", ".2f"),
                              ("final_error_deg", "  final error (deg)", ".3f")):
            lines.append(f"{name:34s}{fmt(s.get(k), spec, none='—'):>12s}{fmt(lin.get(k), spec, none='—'):>12s}")
    lines += ["", "simulated errors are the servo's (pot reading); the true angle adds the uncalibrated pot's "
              "non-linearity (≈1°, see the JSON)"]
    return "\n".join(lines)
