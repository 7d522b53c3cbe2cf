"""``vmehil tune``: gain-tuning analyses of a rig's joint servo.

Examples::

    vmehil tune bode                                  # jpl-arm joint 1, the rig's (or paper) gains
    vmehil tune bode --gains kp=200,kv=60 --json bode.json --report out/bode
    vmehil tune limit-cycle --predict-only --report out/lc

Exit status: 0 on success, 1 when the gain set gives an unstable sampled loop (``bode``), 2 for
bad arguments (negative/NaN/unknown gains, bad rig file).
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
from pathlib import Path
from typing import Any

from servo.analysis.rigparams import JointParams, load_joint


def _joint_number(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"joint must be a whole number (1-based), not {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"joints are numbered from 1, not {n}")
    return n


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive finite number")
    return v


def _common() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--rig", default=None, help="rig preset name or TOML path (default jpl-arm)")
    p.add_argument("--joint", type=_joint_number, default=1, help="joint number, 1-based (default 1)")
    p.add_argument("--gains", default=None, metavar="kp=..,kpi=..,kv=..,kvi=..",
                   help="override some or all of the joint's gains")
    p.add_argument("--json", dest="json_path", default=None, metavar="PATH", help="write the results as JSON")
    p.add_argument("--report", default=None, metavar="DIR", help="write PNG/SVG plots and a markdown summary")
    return p


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tune", help="gain-tuning analyses: Bode/margins, limit cycles")
    tsub = p.add_subparsers(dest="tune_cmd", metavar="ANALYSIS")
    tsub.required = True
    common = _common()
    b = tsub.add_parser("bode", parents=[common],
                        help="margins, crossover, bandwidth; open/closed-loop and disturbance responses")
    b.set_defaults(func=run_bode)
    lc = tsub.add_parser("limit-cycle", parents=[common],
                         help="describing-function limit-cycle prediction (and simulation), with/without "
                              "integrator switch-off")
    lc.add_argument("--predict-only", action="store_true",
                    help="only the describing-function prediction (no full-stack simulation)")
    lc.add_argument("--switch-off-kp", type=_positive_float, default=None,
                    help="position gain while the integrators are switched off (default: rig, else Kp+KvI)")
    lc.set_defaults(func=run_limit_cycle)


def _command_line(args: argparse.Namespace) -> str:
    argv = sys.argv[1:] if sys.argv and Path(sys.argv[0]).name in ("vmehil", "__main__.py") else None
    if argv:
        return "vmehil " + " ".join(shlex.quote(a) for a in argv)
    return f"vmehil tune {args.tune_cmd}"


def _load(args: argparse.Namespace) -> JointParams:
    return load_joint(args.rig, args.joint, gains=args.gains,
                      switch_off_kp=getattr(args, "switch_off_kp", None))


def run_bode(args: argparse.Namespace) -> int:
    from servo.analysis import report
    from servo.analysis.tuning import bode_analysis

    jp = _load(args)
    result = bode_analysis(jp)
    text = report.bode_text(result)
    print("vmehil tune bode — open loop broken at the plant input")
    print(text)
    files: list[Path] = []
    if args.report:
        d = Path(args.report)
        imgs = []
        files += report.save_figure_both(report.bode_figure(jp.cfg, result), d, "bode_open_loop")
        imgs.append("bode_open_loop.png")
        files += report.save_figure_both(report.responses_figure(jp.cfg, result, jp.inertia_kg_m2), d,
                                         "closed_loop_and_disturbance")
        imgs.append("closed_loop_and_disturbance.png")
        md = report.markdown(f"Bode analysis — {jp.rig} joint {jp.joint}", _command_line(args), text, imgs)
        files.append(report.write_text_atomic(d / "summary.md", md))
        result["report_files"] = [str(f) for f in files]
    if args.json_path:
        files.append(report.write_json_atomic(args.json_path, result))
    for f in files:
        print(f"wrote {f}")
    if not result["stable"]:
        print(f"vmehil tune bode: the sampled closed loop is UNSTABLE with gains {jp.cfg.gains}", file=sys.stderr)
        return 1
    return 0


def simulator() -> Any:
    """The full-stack limit-cycle simulation, ``simulate(gains, switch_off, joint_params=...) -> dict``,
    or None while the servo runner is not available (see servo.analysis.tuning)."""
    return None


def run_limit_cycle(args: argparse.Namespace) -> int:
    from servo.analysis import report
    from servo.analysis.tuning import limit_cycle_analysis

    jp = _load(args)
    sim = None if args.predict_only else simulator()
    note = None
    if sim is None and not args.predict_only:
        note = "the full-stack simulation is not available in this build; showing the prediction only"
    result = limit_cycle_analysis(jp, simulate=sim, with_traces=bool(args.report))
    text = report.limit_cycle_text(result)
    print("vmehil tune limit-cycle — describing-function prediction of the sampled loop")
    print(text)
    if note:
        print(f"note: {note}")
    files: list[Path] = []
    if args.report:
        d = Path(args.report)
        imgs = []
        views = (("df_nyquist", jp.cfg, result["predicted"], "integrators on"),
                 ("df_nyquist_switch_off", jp.switch_off_cfg(), result["switch_off"]["predicted"],
                  "integrators switched off"))
        for stem, cfg, block, label in views:
            nl = _headline_nl(jp, block)
            if nl is None:
                continue
            cyc = [c for c in block["cycles"] if c["nonlinearity"] == nl.name]
            title = f"{nl.name} alone — {label}\n({report._gain_text(cfg)})"
            fig = report.nyquist_df_figure(cfg, nl, cyc, title=title)
            files += report.save_figure_both(fig, d, stem)
            imgs.append(f"{stem}.png")
        traces = [("integrators on: reduced nonlinear joint", result.get("model_check")),
                  ("switched off: reduced nonlinear joint", result["switch_off"].get("model_check")),
                  ("integrators on: full-stack simulation", result.get("simulated")),
                  ("switched off: full-stack simulation", result["switch_off"].get("simulated"))]
        fig = report.cycle_time_figure(traces, f"Limit cycle, {jp.rig} joint {jp.joint}")
        if fig is not None:
            files += report.save_figure_both(fig, d, "cycle_time")
            imgs.append("cycle_time.png")
        md = report.markdown(f"Limit cycles — {jp.rig} joint {jp.joint}", _command_line(args), text, imgs)
        files.append(report.write_text_atomic(d / "summary.md", md))
        result["report_files"] = [str(f) for f in files]
    if args.json_path:
        files.append(report.write_json_atomic(args.json_path, _strip_traces(result)))
    for f in files:
        print(f"wrote {f}")
    return 0


def _headline_nl(jp: JointParams, block: dict):
    """The nonlinearity whose Nyquist/DF picture is drawn: the headline one when it is a single
    nonlinearity, else the tach dead band (the mechanism of the JPL cycle), else the first."""
    nls = jp.nonlinearities()
    name = block.get("nonlinearity")
    match = next((n for n in nls if n.name == name), None)
    if match is not None:
        return match
    return next((n for n in nls if n.location == "velocity_sensor"), nls[0] if nls else None)


def _strip_traces(result: dict) -> dict:
    """JSON keeps figures, not sample-by-sample traces of the model check."""
    out = dict(result)
    for key in ("model_check",):
        if out.get(key):
            out[key] = {k: v for k, v in out[key].items() if k not in ("t_s", "theta_deg")}
    so = dict(out["switch_off"])
    if so.get("model_check"):
        so["model_check"] = {k: v for k, v in so["model_check"].items() if k not in ("t_s", "theta_deg")}
    out["switch_off"] = so
    return out
