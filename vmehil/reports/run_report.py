"""The report of a `vmehil run`: per-joint figures, JSON, plots."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from servo.fine_positioning import FinePositioning
from servo.loop import ServoLoop
from vmehil.reports.metrics import CYCLE_RULE, limit_cycle
from vmehil.writers.files import save_figure, write_atomic, write_json

SETTLE_S = 2.0  #: the limit cycle window starts this long after the last motion ended


def motion_end_time(loop: ServoLoop) -> float:
    """When the last non-wait move ended (s); 0 if there was none."""
    end = 0.0
    for r in loop.sequencer.records:
        if r.kind not in ("wait", "stay"):
            end = r.t_start + r.duration
    return end + getattr(loop, "_t_motion0", 0.0)


def _final_integrating(loop: ServoLoop, rec: dict[str, np.ndarray], i: int) -> bool | None:
    """Whether joint ``i``'s integrators ran at the run's last servoing tick: the recorder's last
    row that has it (a run's end-of-run stop and the 2 s after it are not the run), else the law's."""
    col = rec.get("integrating")
    if col is not None and col.size:
        known = col[:, i][np.isfinite(col[:, i])]
        if known.size:
            return bool(known[-1])
    return bool(loop.law.integrating[i]) if loop.law is not None else None


def summarize(loop: ServoLoop, *, rig: str, seed: int, realtime: bool, overruns: int,
              timing: dict[str, Any] | None = None) -> dict[str, Any]:
    rec = loop.recorder.trimmed() if loop.recorder is not None else {}
    run_ticks = getattr(loop, "run_ticks", None)
    ticks: int = loop.tick_count if run_ticks is None else int(run_ticks)
    t = rec.get("t", np.zeros(0))
    t_end_motion = motion_end_time(loop)
    t_window = t_end_motion + SETTLE_S
    # no move (--motion none, a hold): no tracking error to speak of, not the first sample's
    has_moves = any(r.kind not in ("wait", "stay") for r in loop.sequencer.records)
    joints = []
    # one ADC code of each pot (NaN: no pot); an I/O without converters (a test's fake) has none
    resolution = getattr(loop.io, "resolution", None)
    pot_step_rad = resolution().pot_rad if resolution is not None else np.full(len(loop.names), np.nan)
    for i, name in enumerate(loop.names):
        th_true = rec["theta_true"][:, i] if rec else np.zeros(0)
        th_d = rec["theta_d"][:, i] if rec else np.zeros(0)
        th_pot = rec["theta_pot"][:, i] if rec else np.zeros(0)
        err = th_d - th_true
        moving = (t <= t_end_motion) if has_moves else np.zeros(t.shape, bool)
        finite = np.isfinite(err)
        lc = limit_cycle(t, th_true, t_window)
        q = float(pot_step_rad[i]) if np.isfinite(pot_step_rad[i]) else 0.0
        lc_pot = limit_cycle(t, th_pot, t_window, quantum_rad=q)
        # the run's own events: not those of its end-of-run stop (servo.runner.LockstepRunner.end_run)
        so_events = [e for e in loop.law.events if e.joint == i and e.tick < ticks] if loop.law is not None else []
        joints.append({
            "name": name,
            "final_error_deg": _deg(err[finite][-1]) if finite.any() else None,
            "max_tracking_error_deg": _deg(np.max(np.abs(err[moving & finite]))) if (moving & finite).any() else None,
            # amplitude_deg: half peak-to-peak of the hold (a cycle or not; None: window too short);
            # cycle / frequency_hz: by the rule of vmehil.reports.metrics (CYCLE_RULE)
            "limit_cycle": {"amplitude_deg": lc.amplitude_deg, "frequency_hz": lc.frequency_hz,
                            "cycle": lc.cycle, "spectrum_peak_hz": lc.spectrum_peak_hz,
                            "window_s": list(lc.window_s), "source": "true angle"},
            "limit_cycle_pot": {"amplitude_deg": lc_pot.amplitude_deg, "frequency_hz": lc_pot.frequency_hz,
                                "cycle": lc_pot.cycle, "spectrum_peak_hz": lc_pot.spectrum_peak_hz,
                                "source": "potentiometer"},
            "switch_off_events": len(so_events),
            "final_integrating": _final_integrating(loop, rec, i),
        })
    out = {
        "rig": rig,
        "seed": seed,
        "mode": "realtime" if realtime else "lockstep",
        # the run's own ticks: the end-of-run stop and the 2 s watched after it are in final_stop
        "ticks": ticks,
        "duration_s": ticks * loop.period_s,
        "overruns": overruns,
        "faults": [f.as_dict() for f in loop.faults],
        # how the run ended: the final safe stop and what its read-back could not confirm
        "final_stop": loop.final_stop,
        "safe_stop_incomplete": list(loop.stop_incomplete),
        "motion_end_s": t_end_motion,
        "joints": joints,
    }
    if timing is not None:
        out["timing"] = timing
    if loop.log:  # live changes (MAVLink, console, API), in the order they took effect
        out["changes"] = [{"time_s": t, "source": src, "change": msg} for t, src, msg in loop.log]
    if loop.log_dropped:  # a long run: the oldest changes were dropped to keep the log bounded
        out["changes_dropped"] = loop.log_dropped
    if loop.recorder is not None and loop.recorder.dropped:  # a long run: the joints' figures are of its end
        out["recorded"] = {"ticks_kept": loop.recorder.rows, "ticks_dropped": loop.recorder.dropped,
                           "from_s": float(t[0]) if t.size else None}
    vision = loop.vision
    if vision is not None:
        out["vision"] = vision.summary()
    tool = tool_summary(loop, rec)
    if tool is not None:
        out["tool"] = tool
    return out


def tool_summary(loop: ServoLoop, rec: dict[str, np.ndarray]) -> dict[str, Any] | None:
    """Where the tool ended against the target of the motion's last move when that is a Cartesian
    one (docs/cartesian.md): ``final_error_mm`` from the emulated truth (the plant's true joint
    angles through the arm's forward kinematics) at the run's last recorded tick, and
    ``measured_error_mm`` from the drivers' angles (what the servo believed: its own static error),
    ``sensor_error_mm`` between the two (the pots' and calibration's part); ``None`` when the last
    move that ran is not Cartesian, or there is no arm model or no truth."""
    ctx = getattr(loop, "plan_context", None)
    arm = ctx.bounds.arm if ctx is not None and ctx.bounds is not None else None
    ran = [r for r in loop.sequencer.records if r.kind not in ("wait", "stay")]
    if arm is None or not ran or not rec or "theta_true" not in rec:
        return None
    move = loop.sequencer.moves[ran[-1].index]
    target = getattr(move, "tool_target_m", None)
    truth = rec["theta_true"]
    rows = np.flatnonzero(np.all(np.isfinite(truth), axis=1))
    if target is None or not rows.size:
        return None
    last = int(rows[-1])
    where = arm.tool_position(truth[last])
    measured = arm.tool_position(rec["theta"][last])
    measured_mm = float(np.linalg.norm(measured - target) * 1e3)
    sensor_mm = float(np.linalg.norm(measured - where) * 1e3)
    return {"move": ran[-1].index + 1, "kind": move.kind,
            "target_m": [round(float(x), 6) for x in target],
            "final_position_m": [round(float(x), 6) for x in where],
            "final_error_mm": float(np.linalg.norm(where - target) * 1e3),
            # None when a sensor no longer answered at that tick
            "measured_error_mm": measured_mm if np.isfinite(measured_mm) else None,
            # the sensing part of the error: where the drivers' angles put the tool against the truth
            "sensor_error_mm": sensor_mm if np.isfinite(sensor_mm) else None,
            "source": "true joint angles through the arm's forward kinematics",
            **_fine_positioning(ran[-1].trajectory)}


def _fine_positioning(trajectory: object) -> dict[str, Any]:
    """The fine-positioning phase's outcome (servo.fine_positioning) when the move had one."""
    if not isinstance(trajectory, FinePositioning):
        return {}
    err = trajectory.error_m
    return {"fine_positioning": {
        "tolerance_mm": trajectory.settings.tolerance_m * 1e3, "settled": trajectory.settled,
        "after_s": trajectory.settled_after_s, "trims": trajectory.trims,
        # the tool's measured error over the last averaging window (the pots' noise averaged)
        "window_error_mm": None if err is None else err * 1e3,
        "trim_deg": [round(float(np.degrees(x)), 4) for x in trajectory.setpoint - trajectory.planned]}}


def _deg(x: float) -> float:
    return float(np.degrees(x))


def table(summary: dict[str, Any]) -> str:
    # the two errors are of different moments (the last tick; the moves), both on the true angle:
    # named so that a small one beside a large one does not read as a contradiction
    rows = [("joint", "err at end °", "max err in moves °", "LC amp ° (true)", "LC Hz", "LC amp ° (pot)")]
    for j in summary["joints"]:
        lc, lp = j["limit_cycle"], j["limit_cycle_pot"]
        rows.append((j["name"], _f(j["final_error_deg"]), _f(j["max_tracking_error_deg"]), _f(_cycle_amp(lc)),
                     _f(lc["frequency_hz"], 2), _f(_cycle_amp(lp))))
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    lines = ["  ".join(r[c].rjust(widths[c]) if c else r[c].ljust(widths[c]) for c in range(len(r))) for r in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    head = (f"{summary['rig']} · {summary['mode']} · {summary['ticks']} ticks ({summary['duration_s']:.2f} s) · "
            f"overruns {summary['overruns']} · faults {len(summary['faults'])}")
    v = summary.get("vision")
    vis = [] if v is None else [
        f"vision: {v['commands']} commands, robot {v['robot_state']} ({v['end_reason']}), "
        f"end effector {_f(v['final_distance_mm'], 2)} mm from the target"]
    tool = summary.get("tool")
    if tool is not None:
        vis.append(f"tool: {tool['final_error_mm']:.2f} mm from the target of move {tool['move']} ({tool['kind']}; "
                   f"the drivers' angles say {_f(tool['measured_error_mm'], 2)} mm)")
    tail = [*vis] + [f"fault: {f['cause']} at {f['time_s']:.3f} s"
                     + (f" ({f['joint']})" if f["joint"] is not None else "") + f": {f['detail']}"
                     for f in summary["faults"]]
    note = [f"LC: limit cycle over the hold from {SETTLE_S:g} s after the last move; \"—\": none ({CYCLE_RULE})."]
    return "\n".join([head, "", *lines, *note, *tail, *units_section(summary)])


def units_section(summary: dict[str, Any]) -> list[str]:
    """A run of parallel units (``vmehil run --units parallel``): one line per unit (its joints,
    ticks, how it stopped; compute, lateness and overruns when real time) and the first stop the
    coordinator saw. Empty for a run of one controller."""
    units = summary.get("units")
    if not units:
        return []
    lines = ["", f"units (parallel; plant steps {summary.get('plant_steps', '?')}):"]
    for name, u in units.items():
        if "error" in u:
            lines.append(f"  {name:6s} did not run: {u['error']}")
            continue
        fault = u["faults"][0] if u.get("faults") else None
        stop = u.get("final_stop") or {}
        how = "ran to the end" if fault is None else f"stopped: {fault['cause']} at tick {fault['tick']}"
        line = (f"  {name:6s} {len(u['joints'])} joints  ticks {u['ticks']}  {how}  "
                f"stop {'verified' if stop.get('verified') else 'NOT verified'}")
        t = u.get("timing")
        if t:
            line += (f"  compute p50 {t['compute_p50_ms']:.2f} ms p99 {t['compute_p99_ms']:.2f} ms  "
                     f"lateness p99 {t['lateness_p99_ms']:.2f} ms max {t['lateness_max_ms']:.2f} ms  "
                     f"overruns {t['overruns']}")
        lines.append(line)
    stop = summary.get("stop")
    if isinstance(stop, dict) and "exchange" in stop:
        lines.append(f"stop: unit {stop['unit']} at exchange {stop['exchange']}: {stop['what']}")
    return lines


def _cycle_amp(lc: dict[str, Any]) -> float | None:
    """The amplitude to print in a limit-cycle column: only that of a cycle (older JSON without
    ``cycle``: a frequency means a cycle)."""
    return lc["amplitude_deg"] if lc.get("cycle", lc.get("frequency_hz") is not None) else None


def _f(v: float | None, nd: int = 3) -> str:
    return "—" if v is None else f"{v:.{nd}f}"


def write_report(loop: ServoLoop, summary: dict[str, Any], out_dir: str | Path) -> list[Path]:
    """Plots per joint (position/target, error, current, integrator state with switch-off events)
    and an overview, plus ``summary.md`` and ``run.json``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if loop.recorder is None:
        raise ValueError("write_report: the servo loop has no recorder (nothing to report)")
    rec = loop.recorder.trimmed()
    t = rec["t"]
    files: list[Path] = []
    for i, name in enumerate(loop.names):
        fig, ax = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
        ax[0].plot(t, np.degrees(rec["theta_d"][:, i]), "k--", lw=1, label="target")
        ax[0].plot(t, np.degrees(rec["theta_true"][:, i]), lw=1, label="true angle")
        ax[0].plot(t, np.degrees(rec["theta"][:, i]), lw=0.8, alpha=0.7, label="measured (servo)")
        ax[0].set_ylabel("angle (°)")
        ax[0].legend(loc="best", fontsize=8)
        ax[1].plot(t, np.degrees(rec["theta_d"][:, i] - rec["theta_true"][:, i]), lw=1)
        ax[1].set_ylabel("error (°)")
        ax[2].plot(t, rec["current_cmd"][:, i], lw=1, label="commanded")
        ax[2].plot(t, rec["current"][:, i], lw=0.8, alpha=0.7, label="monitor")
        ax[2].set_ylabel("current (A)")
        ax[2].legend(loc="best", fontsize=8)
        ax[3].step(t, rec["integrating"][:, i], where="post", lw=1, label="integrating (1) / switched off (0)")
        ax3b = ax[3].twinx()
        ax3b.plot(t, rec["kp_eff"][:, i], "r", lw=0.8, label="Kp effective")
        ax3b.set_ylabel("Kp effective (s⁻²)", color="r")
        ax[3].set_ylabel("integrators")
        ax[3].set_xlabel("time (s)")
        j = summary["joints"][i]
        lc = j["limit_cycle"]
        lc_text = (f"limit cycle ±{_f(lc['amplitude_deg'])}° @ {_f(lc['frequency_hz'], 2)} Hz" if _cycle_amp(lc)
                   is not None else "no limit cycle")
        fig.suptitle(f"{name}: final error {_f(j['final_error_deg'])}°, {lc_text}")
        for a in ax:
            a.grid(alpha=0.3)
            if summary["motion_end_s"]:
                a.axvline(summary["motion_end_s"], color="grey", lw=0.6, ls=":")
        files += save_figure(fig, out / f"joint{i + 1}_{name}")
        plt.close(fig)
    files.append(write_json(out / "run.json", summary))
    files.append(write_atomic(out / "summary.md", "# vmehil run\n\n```\n" + table(summary) + "\n```\n"))
    return files


def final_stop_line(stop: dict[str, Any] | None) -> str | None:
    """The terminal's line for a run's final stop: "final stop: end (category 1); moved after the
    stop …" (``None``: the stop has no category, an older loop's)."""
    stop = stop or {}
    if stop.get("category") is None:
        return None
    return (f"final stop: {stop.get('cause') or stop.get('reason')} (category {stop['category']}); "
            f"{excursion_text(stop.get('excursion_deg'))}")


def excursion_text(excursion_deg: dict[str, float | None] | None) -> str:
    """A stop's excursion for the terminal: "moved after the stop (deg): j1 0.012, j2 0.150, …"."""
    if not excursion_deg:
        return "moved after the stop: not measured"
    parts = [f"{name} {'?' if v is None else f'{v:.3f}'}" for name, v in excursion_deg.items()]
    return "moved after the stop (deg, over the stop and 2 s after it): " + ", ".join(parts)
