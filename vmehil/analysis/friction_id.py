"""Friction identification of one joint through the drivers only (``vmehil calibrate friction``).

The procedure sees the joint as the servo does on the real robot: amplifier commands go out
through the DAC, the current comes back through the amplifier's current monitor (ADC), the
motion through the motor encoder (quadrature decoder). Nothing reads the emulator's state.

1. **Running friction — the JPL paper's test.** The joint follows ``θd = θ0 + A·sin(2π·f·t)``
   (A = 0.4 rad, f = 0.06 Hz, one cycle by default) under a stiff PD position loop closed on the
   *encoder* position and *encoder* velocity (Kp = 400 s⁻², Kv = 40 s⁻¹, no integrators, no
   switch-off, with the trajectory's acceleration as feedforward) — the tachometer is blind at
   the test's speeds (its brush dead band; docs/plant.md). The other joints hold with the rig's
   own settings. Per servo tick it records the motor torque ``Kt·i`` (current monitor) and the
   motor angle ``N·θ_enc``; :func:`emulators.plant.friction_metrics.running_torque_metrics` (the
   measurement definition, docs/plant.md) gives the running torque (mean of ``|τ_f|`` over the
   fast part of the strokes), the ripple amplitude and the ripple frequency.
2. **Breakout — slow open-loop current ramps.** With the joint's loop opened (the others keep
   holding), the amplifier current is ramped slowly from rest until the encoder has moved
   ``move_counts`` counts; the breakout is the measured ``Kt·i`` (a straight-line fit of the
   current monitor over the ramp, evaluated at that tick). Ramps alternate in direction and are
   made at ``ramps`` wave-generator angles spread over half a motor turn (the Harmonic Drive's
   friction ripple repeats twice per wave-generator turn), so the spread of the local breakout
   shows. Between ramps the loop is closed again and the joint moved to the next angle (and a
   whole motor turn on every other ramp).
3. **Output breakout** = ``N × input breakout`` (mean of the ramps): **derived, not measured**
   (``breakout_output_method`` says so in the JSON). The JPL paper measured ~600 oz-in directly
   with a torque gauge on the output; this procedure has no gauge, and the plant has no friction
   on the output side (wave generator/flexspline/output bearing), so a gauge would read N × input
   by construction.

Torques are reported in oz-in at the motor (input) shaft unless named ``output``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hal.si import nm_to_oz_in
from servo.control.law import SwitchOffConfig
from servo.control.objects import BaseControlObject, ControlContext
from servo.loop import ServoLoop
from servo.motion import Motion
from servo.runner import LockstepRunner
from servo.trajectory.base import Sample
from servo.trajectory.quintic import Quintic
from servo.trajectory.sequencer import Sequencer
from servo.trajectory.stay import Stay
from vmehil.calibration.base import CalibrationAbort, Check, ProcedureResult, ProcedureSpec
from vmehil.errors import VmehilError
from vmehil.rig_setup.session import build_loop, plan_context_of
from vmehil.rig_setup.system import EmulatedRig
from vmehil.writers.files import save_figure, write_atomic

PAPER_AMPLITUDE_RAD = 0.4
PAPER_FREQUENCY_HZ = 0.06


class FrictionIdError(VmehilError, RuntimeError):
    """The procedure cannot run or went wrong (unsuitable joint, watchdog stop, no breakout)."""


class Sinusoid:
    """``θd = start + A·sin(2π·f·t)`` on one joint (the others hold ``start``) for ``cycles`` cycles,
    then a hold of ``start`` (``done``). Implements :class:`servo.trajectory.base.Trajectory`.

    Args:
        start: joint angles (rad), the centre of the motion and the hold afterwards.
        joint: 0-based index of the moving joint.
        amplitude_rad: A (rad); frequency_hz: f (Hz); cycles: number of periods (> 0).
    """

    def __init__(self, start: np.ndarray, joint: int, amplitude_rad: float, frequency_hz: float,
                 cycles: float = 1.0) -> None:
        if not (amplitude_rad > 0 and frequency_hz > 0 and cycles > 0):
            raise ValueError("a sinusoid needs amplitude, frequency and cycles > 0")
        self.start = np.asarray(start, float).copy()
        self.end = self.start
        self.joint = int(joint)
        self.amplitude = float(amplitude_rad)
        self.omega = 2.0 * math.pi * float(frequency_hz)
        self.duration = float(cycles) / float(frequency_hz)

    def sample(self, t: float) -> Sample:
        th, w, a = self.start.copy(), np.zeros_like(self.start), np.zeros_like(self.start)
        done = t >= self.duration
        if not done:
            x = self.omega * max(t, 0.0)
            th[self.joint] += self.amplitude * math.sin(x)
            w[self.joint] = self.amplitude * self.omega * math.cos(x)
            a[self.joint] = -self.amplitude * self.omega**2 * math.sin(x)
        return Sample(th, w, a, done)


@dataclass
class _Play:
    """A move spec that plays a ready-made trajectory (for :class:`Sequencer`)."""

    trajectory: Any
    kind: str = "friction_id"

    def build(self, start: np.ndarray, ctx: Any) -> Any:
        return self.trajectory


class _OpenLoop(BaseControlObject):
    """Transform appended to the controller: replaces one joint's torque (N·m at the joint) while
    ``torque_nm`` is set — the joint's loop is open, the other joints are untouched."""

    kind = "transform"

    def __init__(self, joint: int) -> None:
        self.name = "friction_id_open_loop"
        self.joint = joint
        self.torque_nm: float | None = None

    def update(self, ctx: ControlContext, tau: np.ndarray) -> np.ndarray:
        if self.torque_nm is None:
            return tau
        out = np.array(tau, float)
        out[self.joint] = self.torque_nm
        return out


#: a breakout stroke starts only after the encoder stood still this long at zero torque (s)
REST_WINDOW_S = 0.08
#: how long a released joint may take to come to rest before the stroke is refused (s)
MAX_REST_WAIT_S = 2.0
#: the amplifier's first ticks of a ramp: a "breakout" in them is a joint that was still moving
SETTLE_TICKS = 3
#: strokes tried per ramp before the procedure refuses (it repeats one that did not start at rest)
STROKE_TRIES = 4


@dataclass
class _Stroke:
    """One breakout stroke: the ramp tick the joint moved in (``None``: not clean, ``why``)."""

    moved_at: int | None
    why: str
    trace: dict[str, list[float]]


@dataclass
class _Records:
    t: list[float]
    torque_nm: list[float]
    theta_enc: list[float]
    omega_d: list[float]


def identify_friction(system: EmulatedRig, joint: int, *, amplitude_rad: float = PAPER_AMPLITUDE_RAD,
                      frequency_hz: float = PAPER_FREQUENCY_HZ, cycles: float = 1.0, kp: float = 400.0,
                      kv: float = 40.0, ramps: int = 4, ramp_rate_nm_s: float | None = None,
                      move_counts: int = 2, settle_s: float = 0.5,
                      runner_factory: Callable[[EmulatedRig, ServoLoop], LockstepRunner] | None = None,
                      keep_records: bool = False) -> dict[str, Any]:
    """Identify the friction of ``joint`` (1-based, as the papers number links) on ``system``.

    Args:
        system: an assembled rig (:func:`vmehil.rig_setup.system.build_emulated_rig`); only its drivers
            (``system.io``) and rig file are used, plus a runner to let time pass.
        amplitude_rad, frequency_hz, cycles: the sinusoid (default: the paper's 0.4 rad, 0.06 Hz, 1).
        kp, kv: the stiff PD loop's normalized gains (s⁻², s⁻¹) on the encoder.
        ramps: number of breakout ramps (alternating direction, spread wave-generator angles).
        ramp_rate_nm_s: motor-torque ramp rate (N·m/s); default 2 % of the amplifier's peak
            torque ``Kt·I_limit`` per second.
        move_counts: encoder counts that mean "the joint moved" (≥ 1).
        settle_s: hold time before the test and between ramps (s).
        runner_factory: builds what advances time from ``(system, loop)`` (default
            :class:`LockstepRunner`; :class:`servo.runner.RealtimeRunner` works too).
        keep_records: add the raw records (``records``) to the result, for plots.

    Returns:
        A JSON-ready dict: ``running_torque_oz_in.mean``, ``running_torque_oz_in.ripple_amplitude``,
        ``ripple_frequency_hz``, ``breakout_input_oz_in`` (mean of the ramps),
        ``breakout_input_range_oz_in``, ``breakout_output_oz_in`` (DERIVED = N × input, not measured),
        ``breakout_output_method`` (says so), ``breakout_ramps``,
        ``test`` (the settings used) and the joint's identity.
    """
    rig = system.rig
    spec = rig.joint(joint)
    j = spec.index
    io = system.io
    for need in ("encoder", "imon"):
        if need not in spec.wiring:
            raise FrictionIdError(f"joint {joint} ({spec.name}) has no '{need}' in its [joint.wiring]: the "
                                  "procedure needs the motor encoder and the amplifier current monitor")
    if spec.amplifier != "linear":
        raise FrictionIdError(f"joint {joint} ({spec.name}) is on an H-bridge: the procedure needs a "
                              "transconductance amplifier (current command and current monitor)")
    if move_counts < 1 or ramps < 1:
        raise ValueError("move_counts and ramps must be >= 1")
    saved = (io.position_source[j], io.velocity_source[j])
    # The stiff loop runs on the encoder for both position and velocity.
    io.set_sources(j, "encoder", "encoder")
    try:
        return _identify(system, joint, amplitude_rad, frequency_hz, cycles, kp, kv, ramps, ramp_rate_nm_s,
                         move_counts, settle_s, runner_factory, keep_records)
    finally:
        io.set_sources(j, *saved)


def _identify(system: EmulatedRig, joint: int, amplitude_rad: float, frequency_hz: float, cycles: float, kp: float,
              kv: float, ramps: int, ramp_rate_nm_s: float | None, move_counts: int, settle_s: float,
              runner_factory: Callable[[EmulatedRig, ServoLoop], LockstepRunner] | None,
              keep_records: bool) -> dict[str, Any]:
    rig = system.rig
    spec = rig.joint(joint)
    j = spec.index
    io = system.io
    sc = io.scaling[j]
    ratio, kt = sc.ratio, sc.kt_nm_per_a
    cpr_joint = sc.encoder_counts_per_rev  # x4 counts per joint revolution
    loop = build_loop(system, motion=Motion((), "friction_id", "<friction_id>"))
    # ticks continue the crate's time (other procedures may have run on this rig before)
    loop.tick_count = -(-int(system.crate.clock.now_ns) // system.period_ns) + 1
    law = loop.law
    law.set_gains(kp=kp, kpi=0.0, kv=kv, kvi=0.0, joint=j)
    so = law.switch_off
    enabled = so.enabled.copy()
    enabled[j] = False
    law.set_switch_off(SwitchOffConfig(enabled, so.inner_band, so.outer_band, so.kp_boost, so.settle_time,
                                       so.zero_crossing))
    chain = loop.controller.active.chain
    j_motor = float(chain.j_eff[j]) / ratio**2
    opener = _OpenLoop(j)
    loop.controller.active.objects.append(opener)
    run = (runner_factory or LockstepRunner)(system, loop)
    period = rig.period_s
    with loop.armed():  # every way out of the identification ends with the amplifiers off
        target = io.read().theta.copy()

        def play(traj: Any) -> None:
            loop.set_motion(Sequencer([_Play(traj)], traj.start, plan_context_of(loop)))

        def ticks(seconds: float) -> int:
            return max(1, round(seconds / period))

        def check() -> None:
            if loop.fault is not None:
                f = loop.fault
                raise FrictionIdError(f"the watchdog stopped the loop at t = {f.time_s:.3f} s: {f.cause} "
                                      f"({f.joint}: {f.detail})")

        # --- 1. the paper's sinusoid -----------------------------------------------------------------
        play(Stay(target, settle_s))
        run.run(ticks(settle_s))
        check()
        rec = _Records([], [], [], [])

        def record(lp: ServoLoop) -> None:
            last = lp.last
            if "theta_enc" not in last or "omega_d" not in last:
                return
            rec.t.append(float(last["t"]))
            rec.torque_nm.append(kt * float(last["current"][j]))
            rec.theta_enc.append(float(last["theta_enc"][j]))
            rec.omega_d.append(float(last["omega_d"][j]))

        sine = Sinusoid(target, j, amplitude_rad, frequency_hz, cycles)
        play(sine)
        run.after_tick.append(record)
        run.run(round(sine.duration / period) + 2)
        run.after_tick.remove(record)
        check()
        t = np.asarray(rec.t)
        tau = np.asarray(rec.torque_nm)
        theta_m = np.asarray(rec.theta_enc) * ratio
        w_d = np.asarray(rec.omega_d)
        # the analysis needs scipy (the 'tune' extra): imported here, so that listing the
        # procedures (vmehil calibrate --help) works without it
        from emulators.plant.friction_metrics import running_torque_metrics

        metrics = running_torque_metrics(t, tau, theta_m, w_d, j_motor)

        # --- 2. breakout ramps -----------------------------------------------------------------------
        rate = ramp_rate_nm_s if ramp_rate_nm_s is not None else 0.02 * kt * sc.current_limit_a
        max_torque = kt * sc.current_limit_a
        base = target.copy()
        ramp_out: list[dict[str, Any]] = []
        ramp_traces: list[dict[str, list[float]]] = []
        found: list[float] = []
        rest_ticks = ticks(REST_WINDOW_S)

        def encoder_counts() -> float:
            return float(loop.last["theta_enc"][j]) * cpr_joint / (2.0 * math.pi)

        def _stroke(tq0: float, sign: float) -> _Stroke:
            """One ramp from rest: release the joint (zero torque) until its encoder has stood still
            for REST_WINDOW_S, then ramp the torque in ``sign``'s direction until it moves
            ``move_counts`` that way. Not clean when it never came to rest, moved the other way, or
            "broke out" within the amplifier's first ticks (it was still moving)."""
            opener.torque_nm = 0.0
            still, last_counts = 0, None
            for _ in range(ticks(MAX_REST_WAIT_S)):
                run.run(1)
                check()
                c = encoder_counts()
                still = still + 1 if last_counts is not None and abs(c - last_counts) < 0.5 else 0
                last_counts = c
                if still >= rest_ticks:
                    break
            else:
                opener.torque_nm = None
                return _Stroke(None, "not at rest", {})
            start_counts = encoder_counts()
            trace: dict[str, list[float]] = {"t": [], "command_nm": [], "measured_nm": [], "counts": []}
            k = 0
            try:
                while True:
                    cmd = tq0 + rate * k * period
                    if cmd > max_torque:
                        return _Stroke(None, "no movement", trace)
                    opener.torque_nm = sign * cmd * ratio  # joint torque: write_torque divides by N·Kt
                    run.run(1)
                    check()
                    last = loop.last
                    # counts in the commanded direction: a move the other way is not a breakout
                    counts = sign * (encoder_counts() - start_counts)
                    trace["t"].append(k * period)
                    trace["command_nm"].append(cmd)
                    trace["measured_nm"].append(kt * float(last["current"][j]) * sign)
                    trace["counts"].append(counts)
                    if counts <= -move_counts + 1e-6:
                        return _Stroke(None, "moved against the torque", trace)
                    if counts >= move_counts - 1e-6:
                        if k < SETTLE_TICKS:
                            return _Stroke(None, f"moved in tick {k} of the ramp", trace)
                        return _Stroke(k, "", trace)
                    k += 1
            finally:
                opener.torque_nm = None

        retried = 0
        for r in range(ramps):
            sign = 1.0 if r % 2 == 0 else -1.0
            if r > 0:
                # r/ramps of the ripple period (half a motor turn) further on, plus a whole motor
                # turn on every other ramp so that the joint really travels between ramps
                new = target.copy()
                new[j] = base[j] + (r * math.pi / ramps + (2.0 * math.pi if r % 2 else 0.0)) / ratio
                move = Quintic(target, new, max(0.5, 8.0 * abs(new[j] - target[j])))
                play(move)
                run.run(ticks(move.duration))
                target = new
            tq0 = 0.0 if not found else 0.5 * min(found)
            refused: list[str] = []
            for _try in range(STROKE_TRIES):
                play(Stay(target, float("inf")))
                run.run(ticks(settle_s))
                check()
                stroke = _stroke(tq0, sign)
                if stroke.moved_at is not None:
                    break
                if stroke.why == "no movement":
                    raise FrictionIdError(
                        f"joint {joint} ({spec.name}) did not move with up to {nm_to_oz_in(max_torque):.1f} oz-in "
                        "(the amplifier's current limit): is the joint blocked, or the amplifier disabled?")
                refused.append(stroke.why)
            else:
                raise FrictionIdError(
                    f"joint {joint} ({spec.name}): breakout ramp {r + 1} never started cleanly from rest in "
                    f"{STROKE_TRIES} tries ({'; '.join(refused)}): is the joint being moved by something else?")
            retried += len(refused)
            moved_at, trace = stroke.moved_at, stroke.trace
            tt = np.asarray(trace["t"])
            meas = np.asarray(trace["measured_nm"])
            use = slice(SETTLE_TICKS, moved_at + 1)  # skip the amplifier's first ticks
            if moved_at - use.start >= 2:
                coef = np.polyfit(tt[use], meas[use], 1)
                breakout = float(np.polyval(coef, tt[moved_at]))
            else:
                breakout = float(meas[moved_at])
            found.append(abs(breakout))
            ramp_out.append({
                "direction": "+" if sign > 0 else "-",
                "motor_angle_rad": float(io.read().theta_enc[j] * ratio),
                "torque_oz_in": float(nm_to_oz_in(abs(breakout))),
                "command_oz_in": float(nm_to_oz_in(trace["command_nm"][moved_at])),
                "ramp_s": float(tt[moved_at]),
            })
            ramp_traces.append(trace)
        play(Stay(target, float("inf")))
        run.run(ticks(settle_s))
        check()
        loop.controller.active.objects.remove(opener)

    b_in = float(np.mean(found))
    result: dict[str, Any] = {
        "rig": rig.name,
        "joint": joint,
        "joint_name": spec.name,
        "seed": system.seed,
        "running_torque_oz_in": {
            "mean": float(nm_to_oz_in(metrics.mean_nm)),
            "ripple_amplitude": float(nm_to_oz_in(metrics.ripple_amplitude_nm)),
        },
        "ripple_frequency_hz": metrics.ripple_frequency_hz,
        "breakout_input_oz_in": float(nm_to_oz_in(b_in)),
        "breakout_input_range_oz_in": [float(nm_to_oz_in(min(found))), float(nm_to_oz_in(max(found)))],
        "breakout_output_oz_in": float(nm_to_oz_in(ratio * b_in)),
        "breakout_output_method": f"DERIVED: N x input breakout (N = {ratio:g}), not measured at the output "
                                  "(the paper used a torque gauge; the model has no output-side friction)",
        "breakout_ramps": ramp_out,
        "test": {
            "amplitude_rad": amplitude_rad,
            "frequency_hz": frequency_hz,
            "cycles": cycles,
            "loop": {"kp": kp, "kv": kv, "kpi": 0.0, "kvi": 0.0, "position": "encoder", "velocity": "encoder",
                     "feedforward": "trajectory acceleration"},
            "ratio": ratio,
            "kt_nm_per_a": kt,
            "motor_inertia_kg_m2": j_motor,
            "fast_samples": metrics.fast_samples,
            "strokes": metrics.strokes,
            "ramp_rate_oz_in_s": float(nm_to_oz_in(rate)),
            "move_counts": move_counts,
            "ramps": ramps,
            "ramp_retries": retried,
            "measurement": "docs/plant.md (Friction measurement); torque = Kt x current monitor",
        },
    }
    if keep_records:
        result["records"] = {"t": t, "torque_nm": tau, "theta_motor": theta_m, "omega_d": w_d,
                             "j_motor": j_motor, "ramps": ramp_traces}
    return result


def _friction_estimate(rec: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """τ_f = Kt·i − J_m·α_m and ω_m from the records (as in the measurement definition)."""
    t, thm = rec["t"], rec["theta_motor"]
    dt = float(np.median(np.diff(t)))
    wm = np.gradient(thm, dt)
    am = np.zeros_like(thm)
    am[1:-1] = (thm[2:] - 2.0 * thm[1:-1] + thm[:-2]) / (dt * dt)
    return rec["torque_nm"] - rec["j_motor"] * am, wm


def write_friction_report(result: dict[str, Any], folder: str | Path) -> list[Path]:
    """Plots (torque against time, torque against velocity, breakout ramps) and ``summary.md``.

    ``result`` must come from :func:`identify_friction` with ``keep_records=True``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    rec = result["records"]
    tau_f, wm = _friction_estimate(rec)
    oz = nm_to_oz_in
    rt = result["running_torque_oz_in"]
    files: list[Path] = []
    name = f"{result['rig']} joint {result['joint']} ({result['joint_name']})"

    fig, ax = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    ax[0].plot(rec["t"], oz(rec["torque_nm"]), lw=0.7, label="Kt·i (current monitor)")
    ax[0].plot(rec["t"], oz(tau_f), lw=0.7, label="friction estimate Kt·i − J_m·α_m")
    ax[0].axhline(rt["mean"], color="k", ls="--", lw=0.8, label=f"running torque ±{rt['mean']:.1f} oz-in")
    ax[0].axhline(-rt["mean"], color="k", ls="--", lw=0.8)
    ax[0].set_ylabel("torque at the motor (oz-in)")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[0].set_title(f"{name}: {result['test']['frequency_hz']} Hz ±{result['test']['amplitude_rad']} rad")
    ax[1].plot(rec["t"], rec["omega_d"], lw=0.8, label="commanded joint speed")
    ax[1].plot(rec["t"], wm / result["test"]["ratio"], lw=0.6, label="encoder joint speed")
    ax[1].set_xlabel("time (s)")
    ax[1].set_ylabel("rad/s")
    ax[1].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    files += save_figure(fig, out / "torque_vs_time")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 6))
    ax.plot(wm, oz(tau_f), ".", ms=2, alpha=0.6)
    ax.set_xlabel("motor speed (rad/s, encoder)")
    ax.set_ylabel("friction torque at the motor (oz-in)")
    ax.set_title(f"{name}: running torque {rt['mean']:.1f} oz-in, ripple ±{rt['ripple_amplitude']:.1f} oz-in "
                 f"at {result['ripple_frequency_hz']:.2f} Hz", fontsize=9)
    ax.axhline(0, color="k", lw=0.5)
    ax.axvline(0, color="k", lw=0.5)
    fig.tight_layout()
    files += save_figure(fig, out / "torque_vs_velocity")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 5))
    for tr, info in zip(rec["ramps"], result["breakout_ramps"], strict=True):
        line, = ax.plot(tr["t"], oz(np.asarray(tr["measured_nm"])), lw=0.8,
                        label=f"{info['direction']} at θm = {info['motor_angle_rad']:.2f} rad: "
                              f"{info['torque_oz_in']:.2f} oz-in")
        ax.plot([info["ramp_s"]], [info["torque_oz_in"]], "o", color=line.get_color())
    ax.set_xlabel("time into the ramp (s)")
    ax.set_ylabel("|Kt·i| (oz-in, current monitor)")
    ax.set_title(f"{name}: breakout ramps (dot = first encoder motion); output {result['breakout_output_oz_in']:.0f} "
                 "oz-in DERIVED (N × input, not measured)", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    files += save_figure(fig, out / "breakout_ramps")
    plt.close(fig)

    lo, hi = result["breakout_input_range_oz_in"]
    md = [f"# Friction identification: {name}", "",
          "| figure | value |", "|---|---|",
          f"| running torque (mean, motor) | {rt['mean']:.2f} oz-in |",
          f"| ripple amplitude | ±{rt['ripple_amplitude']:.2f} oz-in |",
          f"| ripple frequency | {result['ripple_frequency_hz']:.2f} Hz |",
          f"| breakout at the input | {result['breakout_input_oz_in']:.2f} oz-in (ramps: {lo:.2f}–{hi:.2f}) |",
          f"| breakout at the output (**derived**, not measured) | {result['breakout_output_oz_in']:.0f} oz-in "
          f"({result['breakout_output_method']}) |", "",
          "Measurement definition: docs/plant.md (Friction measurement); procedure: vmehil/analysis/friction_id.py.", ""]  # noqa: E501  (a moved module's longer path; apply_moves.py)
    files.append(write_atomic(out / "summary.md", "\n".join(md)))
    return files


def public_result(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` without the raw records (for JSON)."""
    return {k: v for k, v in result.items() if k != "records"}


def format_result(r: dict[str, Any]) -> str:
    """A few lines for the terminal."""
    rt = r["running_torque_oz_in"]
    lo, hi = r["breakout_input_range_oz_in"]
    return "\n".join([
        f"{r['rig']} joint {r['joint']} ({r['joint_name']}): friction at the motor shaft",
        f"  running torque     {rt['mean']:7.2f} oz-in  (ripple ±{rt['ripple_amplitude']:.2f} oz-in "
        f"at {r['ripple_frequency_hz']:.2f} Hz)",
        f"  breakout (input)   {r['breakout_input_oz_in']:7.2f} oz-in  (ramps {lo:.2f}–{hi:.2f})",
        f"  breakout (output)  {r['breakout_output_oz_in']:7.1f} oz-in  DERIVED = N x input, not measured "
        f"(the paper's torque gauge)",
    ])


class FrictionProcedure:
    """``vmehil calibrate friction --joint N``: the calibration procedure wrapping
    :func:`identify_friction` (not part of ``calibrate all``; writes no calibration entries).

    Result data: for one joint the figures at the top level of the procedure's result
    (``procedures.friction.running_torque_oz_in.mean`` … in the command's JSON), and per joint under ``joints.<name>``.
    ``ctx.options["report"]`` (the command's ``--report``): plots in ``<report>/friction-<joint>/``.
    """

    name = "friction"
    version = 1
    title = "friction identification: running torque, ripple, breakout (drivers only)"

    def run(self, ctx: Any) -> Any:
        if not ctx.joints:
            raise CalibrationAbort("friction identification needs --joint N (1-based; repeat for several)")
        system = getattr(ctx.positioner(), "system", None)
        if system is None:
            raise CalibrationAbort("friction identification needs the rig's servo loop (an emulated rig here)")
        report = ctx.options.get("report")
        res = ProcedureResult(self.name, self.version)
        joints: dict[str, Any] = {}
        try:
            for j in ctx.joints:
                r = identify_friction(system, j + 1, keep_records=bool(report))
                ctx.say(format_result(r))
                if report:
                    write_friction_report(r, Path(report) / f"friction-{r['joint_name']}")
                pub = public_result(r)
                joints[r["joint_name"]] = pub
                name = r["joint_name"]
                res.checks.append(Check(f"{name} strokes measured", pub["test"]["strokes"], "", 2, kind="min"))
                # every ramp started from rest (a stroke that did not was repeated, up to STROKE_TRIES)
                res.checks.append(Check(f"{name} breakout ramps from rest", len(pub["breakout_ramps"]), "",
                                        pub["test"]["ramps"], kind="min"))
        finally:
            ctx.refresh_positioner()  # this procedure ran its own loop on the rig
        res.data = {"joints": joints}
        if len(joints) == 1:
            res.data.update(next(iter(joints.values())))
        return res


#: ``vmehil calibrate friction``: the entry point ``friction`` of group ``vmehil.calibration_procedures``
#: in pyproject.toml names this (the calibration table cannot import this module, built on the rig).
FRICTION_PROCEDURE = ProcedureSpec("friction", FrictionProcedure, order=90, in_all=False,
                                   help="friction: running torque, ripple, breakout of --joint N (not in `all`)")
