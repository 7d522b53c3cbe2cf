"""Full-stack simulations for ``vmehil tune``: the real servo loop driving the emulated rig.

Each run builds the rig afresh (:func:`vmehil.rig_setup.system.build_emulated_rig`, seeded), the loop with
the rig's settings (:func:`vmehil.rig_setup.session.build_loop`), sets the analysed joint's gains on that
joint only (``PidLaw.set_gains(..., joint=)``, so the other joints keep the rig's gains and hold
still), and runs it lockstep (:class:`servo.runner.LockstepRunner`). The figures are measured
exactly as ``vmehil run`` measures them (:func:`vmehil.reports.run_report.summarize`): the limit cycle on
the true angle over the hold from 2 s after the last move ended, amplitude = half peak-to-peak,
frequency from zero crossings (null below 0.02° or with fewer than two periods).

The plant is in-process by default; ``link_factory(rig_path, seed) -> PlantLink`` runs it elsewhere
(``vmehil tune … --plant can``: :class:`vmehil.option_groups.can_options.CanLinkFactory`). It is called
once per run, so every run gets a fresh link whose plant was reset with the run's seed; the run
closes it. In lockstep the figures equal the in-process run's bit for bit (docs/can.md).

Motions (:class:`SimSettings`):

* ``"joint"`` (default): a quintic move of the analysed joint only, by ``move_deg`` (default the
  demo's delta for that joint: 20° for joint 1) at ``speed`` (0.5, as the demo), then ``hold_s``;
* ``"demo"``: the default demo (every joint moves), then ``hold_s``;
* a step (:func:`simulate_step`): the target jumps by ``step_deg`` at t = 0 (ωd = αd = 0).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, overload

import numpy as np

from vmehil.errors import VmehilError
from vmehil.reports.metrics import limit_cycle, settling_time

if TYPE_CHECKING:  # rigparams brings python-control and scipy (≈1 s): only where a joint is analysed
    from vmehil.analysis.rigparams import JointParams

MOTIONS = ("joint", "demo")
STATIC_WINDOW_S = 1.0  #: the static error is the mean error over the last second of the hold
STEADY_WINDOW_S = 2.0  #: the steady-state envelope (settling reference) is taken over the last 2 s


def settling_after(t: np.ndarray, y: np.ndarray, t_start: float, band: float) -> float | None:
    """Settling time (s after ``t_start``) of ``y`` into its steady state: until it stays within
    the steady-state envelope — mean ± half the peak-to-peak over the last
    :data:`STEADY_WINDOW_S` (so a limit cycle counts as settled once the transient has died into
    it) — widened by ``band``. None if it never does."""
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    if t.size == 0:
        return None
    tail = y[t >= t[-1] - STEADY_WINDOW_S]
    mid = 0.5 * (float(np.max(tail)) + float(np.min(tail)))
    half = 0.5 * (float(np.max(tail)) - float(np.min(tail)))
    return settling_time(t, y - mid, t_start, half + band)


class SimulationError(VmehilError, ValueError):
    """Bad simulation settings (hold too short, move of zero size, ...)."""


@dataclass(frozen=True)
class SimSettings:
    """What to simulate: ``motion`` ("joint" or "demo"), the move size (deg; None = the demo's
    delta for the joint) and ``speed`` factor, the hold after it (s, ≥ 8 for a limit cycle unless
    ``allow_short``), the noise ``seed`` and the settling band (deg)."""

    seed: int = 0
    motion: str = "joint"
    move_deg: float | None = None
    speed: float = 0.5
    hold_s: float = 8.0
    settle_band_deg: float = 0.1
    allow_short: bool = False
    #: the drivers' calibration (a :class:`~vmehil.calibration.store.CalibrationStore`, loaded once
    #: by the command and shipped as data with each run); None: nominal values
    calibration: Any = None

    def __post_init__(self) -> None:
        if self.motion not in MOTIONS:
            raise SimulationError(f"motion {self.motion!r} must be one of {', '.join(MOTIONS)}")
        if not (math.isfinite(self.hold_s) and self.hold_s > 0):
            raise SimulationError(f"hold {self.hold_s} s must be a positive number of seconds")
        if self.hold_s < 8.0 and not self.allow_short:
            raise SimulationError(f"hold {self.hold_s:g} s is too short to measure a limit cycle; use at least 8 s")
        if self.move_deg is not None and not (math.isfinite(self.move_deg) and self.move_deg != 0):
            raise SimulationError(f"move {self.move_deg} deg must be a non-zero finite angle")
        if not 0 < self.speed <= 1:
            raise SimulationError(f"speed factor {self.speed} must be in (0, 1]")
        if not (math.isfinite(self.settle_band_deg) and self.settle_band_deg > 0):
            raise SimulationError(f"settling band {self.settle_band_deg} deg must be > 0")


Progress = Callable[[int, int], None]
LinkFactory = Callable[[Any, int], Any]  #: ``(rig, seed) -> PlantLink`` (connected, plant reset; rig: path or RigSpec)


def _motion(system, jp: JointParams, s: SimSettings, step_deg: float | None):
    from hal.si import deg_to_rad
    from servo.motion import DEMO_DELTAS_DEG, Motion, QuinticMove, WaitMove, default_demo_motion

    n = system.rig.n_joints
    j = jp.joint - 1
    if step_deg is not None:
        delta = np.zeros(n)
        delta[j] = deg_to_rad(step_deg)
        return Motion((StepMove(delta), WaitMove(s.hold_s)), "step", "<tune step>")
    if s.motion == "demo":
        return default_demo_motion(n, hold_s=max(s.hold_s, 8.0), speed=s.speed)
    delta = np.zeros(n)
    delta[j] = deg_to_rad(s.move_deg if s.move_deg is not None else DEMO_DELTAS_DEG[j % len(DEMO_DELTAS_DEG)])
    return Motion((QuinticMove(None, delta, s.speed), WaitMove(s.hold_s)), "joint move", "<tune>")


@dataclass(frozen=True)
class StepMove:
    """A step of the target by ``delta`` (rad per joint) at the move's start; ``done`` at once."""

    delta: np.ndarray
    kind: str = "step"

    def build(self, start: np.ndarray, ctx: Any):
        from servo.trajectory.stay import Stay

        return Stay(np.asarray(start, float) + self.delta, 0.0)


def _planned_s(system, motion, settings=None) -> float:
    from servo.settings import servo_settings
    from servo.trajectory.base import JointLimits
    from servo.trajectory.sequencer import PlanContext

    st = settings if settings is not None else servo_settings(system.rig)
    ctx = PlanContext(JointLimits.make(system.rig.n_joints, list(st.max_velocity_rad_s)))
    start = np.zeros(system.rig.n_joints)
    total = 0.0
    for m in motion.moves:
        tr = m.build(start, ctx)
        total += float(tr.duration)
        start = tr.end
    return total


def simulate(jp: JointParams, switch_off: bool | None = False, settings: SimSettings | None = None, *,
             step_deg: float | None = None, traces: bool = True, progress: Progress | None = None,
             stop: Callable[[], bool] | None = None, link_factory: LinkFactory | None = None) -> dict[str, Any]:
    """Run the full stack once for joint ``jp`` with its gains; ``switch_off`` forces the
    integrator switch-off on/off for every joint (None: as the rig says). ``link_factory``: where
    the plant runs (None: in this process; else called once for this run's link, closed at the end).

    Returns JSON-ready figures for the joint (angles in degrees, times in seconds): ``amplitude_deg``,
    ``frequency_hz`` (limit cycle on the true angle, as ``vmehil run``), ``amplitude_pot_deg``,
    ``spectrum_peak_hz``, ``max_tracking_error_deg`` (during the move, true angle, as ``vmehil run``:
    includes the uncalibrated pot's ≈1° non-linearity), ``max_tracking_error_servo_deg`` (the error
    the servo measures; quantized to the pot's ADC step) and ``rms_tracking_error_servo_deg``,
    ``settling_time_s`` (after the move ended, until the true angle stays in its steady-state
    envelope widened by the settling band, :func:`settling_after`; None if never),
    ``static_error_deg`` (|mean error| over the last second, as the servo measures it) and
    ``static_error_true_deg`` (against the true angle: adds the uncalibrated pot's non-linearity),
    ``final_error_deg``, ``switch_off_events``, ``integral_terms_rad_s2`` (Kpi·∫e + KvI·∫ė at the end:
    frozen while switched off), ``balance_error_deg`` (−that/Kp_eff: where a stuck joint's error is
    centred, within ±T_F/(J·Kp_eff)), ``fault`` (None or the watchdog's record), and with
    ``traces`` the per-tick ``t_s``, ``theta_deg`` (true), ``theta_meas_deg``, ``theta_d_deg``,
    ``omega_d_deg_s``.
    """
    run = SimRun(jp, switch_off, settings, step_deg=step_deg, link_factory=link_factory)
    try:
        with run.loop.armed():  # every way out of the simulation ends with the amplifiers off
            run.runner.run(run.n_ticks, progress=progress, stop=run.halt_when(stop))
        summary = run.summarize()
    finally:
        run.close()
    return run.figures(summary, traces=traces)


class SimRun:
    """One :func:`simulate` run in its steps — built here (rig, loop with the joint's gains,
    lockstep runner), ticked by the caller inside ``loop.armed()`` (:func:`simulate` runs every
    tick in one :meth:`~servo.runner.LockstepRunner.run`; :mod:`vmehil.analysis.batch` ticks
    several runs in lockstep), then :meth:`summarize`, :meth:`close` and :meth:`figures`. The same
    objects and calls in the same order either way, so a run's numbers do not depend on who ticks it."""

    def __init__(self, jp: JointParams, switch_off: bool | None = False, settings: SimSettings | None = None, *,
                 step_deg: float | None = None, link_factory: LinkFactory | None = None,
                 faults: tuple[str, ...] = ()) -> None:
        """``faults``: ``--fault`` specs (docs/faults.md) injected into this run alone, at their times."""
        from servo.runner import LockstepRunner
        from vmehil.rig_setup.session import build_loop
        from vmehil.rig_setup.system import build_emulated_rig

        s = settings or SimSettings()
        self.jp, self.switch_off, self.settings, self.step_deg = jp, switch_off, s, step_deg
        self.faults = tuple(faults)
        self._link_factory = link_factory
        rig = jp.spec if jp.spec is not None else jp.rig_path
        link = None if link_factory is None else link_factory(rig, s.seed)
        try:
            system = build_emulated_rig(rig, seed=s.seed, link=link, calibration=s.calibration)
        except BaseException:
            if link is not None:
                link.close()
            raise
        self.system = system
        try:
            j = jp.joint - 1
            motion = _motion(system, jp, s, step_deg)
            duration = _planned_s(system, motion, jp.servo)
            self.n_ticks = max(2, round(duration * system.rig.servo_rate_hz))
            loop = build_loop(system, motion=motion, switch_off=switch_off, n_ticks=self.n_ticks, settings=jp.servo)
            self.loop = loop
            self.theta_start = float(loop.sequencer.current.end[j])  # the target before the first move
            loop.law.set_gains(**jp.cfg.gains.as_dict(), joint=j)
            self.runner = LockstepRunner(system, loop)
            if faults:
                from vmehil.fault_scenarios.injection import FaultContext, FaultSchedule, check_rig, parse_fault_spec

                scheduled = [parse_fault_spec(f) for f in faults]
                check_rig(scheduled, system.rig)
                FaultSchedule(scheduled, FaultContext(system, loop, s.seed)).attach(self.runner)
        except BaseException:
            system.close()
            raise

    def fresh(self) -> SimRun:
        """A new run of the same joint, gains, settings, faults and link: built from scratch, so
        it does everything this one would from its start (a batch of lanes runs an instance it
        left again this way: vmehil.analysis.lanes)."""
        return SimRun(self.jp, self.switch_off, self.settings, step_deg=self.step_deg,
                      link_factory=self._link_factory, faults=self.faults)

    def halt_when(self, stop: Callable[[], bool] | None) -> Callable[[], bool]:
        """The runner's ``stop``: the loop faulted (its watchdog stopped it), or ``stop()``."""
        loop = self.loop

        def halt() -> bool:
            return loop.fault is not None or (stop is not None and stop())
        return halt

    def summarize(self) -> dict[str, Any]:
        from vmehil.reports.run_report import summarize

        return summarize(self.loop, rig=self.system.rig.name, seed=self.settings.seed, realtime=False, overruns=0)

    def close(self) -> None:
        self.system.close()

    def figures(self, summary: dict[str, Any], *, traces: bool = True) -> dict[str, Any]:
        """:func:`simulate`'s result from the ended run and its ``summary``."""
        return _figures(self.jp, self.settings, self.step_deg, self.loop, self.switch_off, self.theta_start,
                        summary, traces)


def _figures(jp: JointParams, s: SimSettings, step_deg: float | None, loop: Any, switch_off: bool | None,
             theta_start: float, summary: dict[str, Any], traces: bool) -> dict[str, Any]:
    from vmehil.reports.run_report import SETTLE_S

    j = jp.joint - 1
    law = loop.law
    js = summary["joints"][j]
    if loop.recorder is None:
        raise RuntimeError("simulate: the servo loop was built without a recorder")
    rec = loop.recorder.trimmed()
    t = rec["t"]
    th_true, th_meas, th_d = rec["theta_true"][:, j], rec["theta"][:, j], rec["theta_d"][:, j]
    t_end = summary["motion_end_s"]
    lc = limit_cycle(t, th_true, t_end + SETTLE_S)
    growth = window_thirds(t, th_true, t_end + SETTLE_S)
    err_true = th_d - th_true
    err_servo = th_d - th_meas
    last = t >= (t[-1] - STATIC_WINDOW_S) if t.size else np.zeros(0, bool)
    band = math.radians(s.settle_band_deg)
    settle = settling_after(t, th_true, t_end, band) if t.size else None
    moving = t <= t_end
    track_servo = _deg(np.nanmax(np.abs(err_servo[moving]))) if moving.any() else None
    track_rms = _deg(float(np.sqrt(np.nanmean(err_servo[moving] ** 2)))) if moving.any() else None
    g = law.gains
    frozen = float(g.kpi[j] * law.state.ie[j] + g.kvi[j] * law.state.iv[j])  # Kpi·∫e + KvI·∫ė, rad/s²
    kp_now = float(law.kp_eff()[j])
    if law.filtered[j]:  # the velocity filter's KvI·ef follows e at rest: static stiffness Kp_eff + KvI
        kp_now += float(g.kvi[j])
    fault = summary["faults"][0] if summary["faults"] else None
    so = js["switch_off_events"]
    out: dict[str, Any] = {
        "motion": "step" if step_deg is not None else s.motion,
        "switch_off": "rig" if switch_off is None else bool(switch_off),
        "seed": s.seed,
        "duration_s": summary["duration_s"],
        "motion_end_s": t_end,
        "theta_start_deg": _deg(theta_start),
        "window_s": js["limit_cycle"]["window_s"],
        "amplitude_deg": None if fault else js["limit_cycle"]["amplitude_deg"],
        "frequency_hz": None if fault else js["limit_cycle"]["frequency_hz"],
        "amplitude_pot_deg": None if fault else js["limit_cycle_pot"]["amplitude_deg"],
        "spectrum_peak_hz": None if fault or lc.frequency_hz is None else lc.spectrum_peak_hz,
        # a cycle still growing (or dying) through the window: its amplitude is an average of a
        # transient, not the cycle's (half peak-to-peak of the window's first and last thirds)
        "amplitude_first_third_deg": None if fault or growth is None else _deg(growth[0]),
        "amplitude_last_third_deg": None if fault or growth is None else _deg(growth[1]),
        "settled": None if fault or growth is None or lc.frequency_hz is None else
        bool(abs(growth[1] - growth[0]) <= SETTLED_FRACTION * max(growth)),
        "max_tracking_error_deg": js["max_tracking_error_deg"],
        "max_tracking_error_servo_deg": track_servo,
        "rms_tracking_error_servo_deg": track_rms,
        "settling_time_s": None if fault else settle,
        "settle_band_deg": s.settle_band_deg,
        "static_error_deg": None if fault else _deg(abs(np.mean((th_d - th_meas)[last]))),
        "static_error_true_deg": None if fault else _deg(abs(np.mean(err_true[last]))),
        "final_error_deg": js["final_error_deg"],
        "switch_off_events": so,
        "final_integrating": js["final_integrating"],
        "integral_terms_rad_s2": frozen,
        "balance_error_deg": None if fault else _deg(-frozen / kp_now) if kp_now else None,
        "fault": fault,
    }
    if traces:
        out.update({
            "t_s": t.tolist(), "theta_deg": np.degrees(th_true).tolist(),
            "theta_meas_deg": np.degrees(th_meas).tolist(), "theta_d_deg": np.degrees(th_d).tolist(),
            "omega_d_deg_s": np.degrees(rec["omega_d"][:, j]).tolist(),
        })
    return out


#: a cycle is settled when the amplitudes of the window's first and last thirds differ by at most
#: this fraction of the larger (the jpl-arm demo's integrators-on cycle grew ±0.45° → ±0.71°)
SETTLED_FRACTION = 0.15


def window_thirds(t: np.ndarray, x: np.ndarray, t_start: float) -> tuple[float, float] | None:
    """Half peak-to-peak of ``x`` over the first and the last third of the window from ``t_start``
    (``None``: fewer than 12 samples in the window)."""
    xw = x[(t >= t_start) & np.isfinite(x)]
    if xw.size < 12:
        return None
    n = xw.size // 3
    return 0.5 * float(np.ptp(xw[:n])), 0.5 * float(np.ptp(xw[-n:]))


@dataclass(frozen=True)
class SimJob:
    """One :func:`simulate` call to run in a worker process (:func:`run_job`); picklable."""

    jp: JointParams
    switch_off: bool | None
    settings: SimSettings
    link_factory: LinkFactory | None = None
    step_deg: float | None = None
    traces: bool = True


def run_job(job: SimJob) -> dict[str, Any] | None:
    """:func:`simulate` for ``job`` in a :func:`vmehil.analysis.parallel.run_parallel` worker: stops
    when the parent is interrupted (every tick polls it; the run ends safe-stopped as any run),
    and then returns None."""
    from vmehil.analysis.parallel import stop_requested

    stop = stop_requested()
    out = simulate(job.jp, switch_off=job.switch_off, settings=job.settings, step_deg=job.step_deg,
                   traces=job.traces, stop=stop, link_factory=job.link_factory)
    return None if stop is not None and stop() else out


def _deg(x: float) -> float:
    return float(np.degrees(x))


TRACE_KEYS = ("t_s", "theta_deg", "theta_meas_deg", "theta_d_deg", "omega_d_deg_s")


@overload
def strip_traces(d: dict[str, Any]) -> dict[str, Any]: ...
@overload
def strip_traces(d: None) -> None: ...
@overload
def strip_traces(d: dict[str, Any] | None) -> dict[str, Any] | None: ...


def strip_traces(d: dict[str, Any] | None) -> dict[str, Any] | None:
    """The run's figures without its per-tick traces (for JSON)."""
    if d is None:
        return None
    return {k: v for k, v in d.items() if k not in TRACE_KEYS}


def linear_prediction(jp: JointParams, t: np.ndarray, theta_d: np.ndarray, omega_d: np.ndarray | None = None,
                      alpha_d: np.ndarray | None = None, theta_start: float | None = None) -> np.ndarray:
    """The sampled linear loop's joint angle (rad, relative to ``theta_start``, default θd[0]; the
    loop starts at rest there) for the command samples ``theta_d`` (rad) at the tick times ``t``,
    with the velocity reference ``omega_d`` and the acceleration feedforward ``alpha_d`` (rad/s²;
    entered as a plant-input acceleration held over each period, i.e. without the computation
    delay: a small approximation)."""
    import control as ct

    from vmehil.analysis.loop_model import build_loop

    cl = build_loop(jp.cfg, sampled=True)
    r = np.asarray(theta_d, float) - float(theta_d[0] if theta_start is None else theta_start)
    rv = np.zeros_like(r) if omega_d is None else np.asarray(omega_d, float)
    ad = np.zeros_like(r) if alpha_d is None else np.asarray(alpha_d, float)
    n = r.size
    tt = np.arange(n) * jp.cfg.sample_period_s
    resp = ct.forced_response(cl, T=tt, U=np.vstack([r, rv, ad]))
    return np.asarray(resp.outputs[cl.output_labels.index("th")]).reshape(-1)[:n]


def step_metrics(d: dict[str, Any], linear_rad: np.ndarray | None, band_deg: float) -> dict[str, Any]:
    """Response figures of a run ``d`` (from :func:`simulate` with traces): the servo's measured
    angle, or — with ``linear_rad`` — the linear prediction for the same command. Angles relative to
    the start; ``overshoot_pct`` and ``rise_time_s`` (10–90 %) for a step, ``max_tracking_error_deg``
    while a move runs (servo's error), ``settling_time_s`` after it (true angle into its steady-state
    envelope ± ``band_deg``, :func:`settling_after`),
    ``final_error_deg`` (|mean error| over the last second), ``move_deg``."""
    t = np.asarray(d["t_s"])
    r = np.asarray(d["theta_d_deg"]) - d["theta_start_deg"]
    if linear_rad is None:
        y = np.asarray(d["theta_meas_deg"]) - d["theta_meas_deg"][0]
        y_true = np.asarray(d["theta_deg"]) - d["theta_deg"][0]
    else:
        y = y_true = np.degrees(np.asarray(linear_rad))
    e = r - y
    size = float(r[-1])
    t_end = float(d["motion_end_s"])
    out: dict[str, Any] = {"move_deg": size, "settle_band_deg": band_deg}
    if d.get("fault"):
        return {**out, "overshoot_pct": None, "rise_time_s": None, "max_tracking_error_deg": None,
                "settling_time_s": None, "final_error_deg": None}
    sgn = 1.0 if size >= 0 else -1.0
    if d["motion"] == "step" and size:
        ys = sgn * y
        out["overshoot_pct"] = max(0.0, (float(np.max(ys)) - abs(size)) / abs(size) * 100.0)
        i10 = np.nonzero(ys >= 0.1 * abs(size))[0]
        i90 = np.nonzero(ys >= 0.9 * abs(size))[0]
        out["rise_time_s"] = float(t[i90[0]] - t[i10[0]]) if i10.size and i90.size else None
        out["max_tracking_error_deg"] = None
    else:
        out["overshoot_pct"] = None
        out["rise_time_s"] = None
        moving = t <= t_end
        out["max_tracking_error_deg"] = float(np.max(np.abs(e[moving]))) if moving.any() else None
    last = t >= t[-1] - STATIC_WINDOW_S
    out["settling_time_s"] = settling_after(t, y_true, t_end, band_deg)
    out["final_error_deg"] = float(abs(np.mean(e[last])))
    return out
