"""The 125 Hz servo loop: sensors → control law → amplifiers, with a watchdog and a recorder.

One :meth:`ServoLoop.tick` per servo period. The loop sees the joints only through
:class:`servo.io.JointIO` (the drivers). Runners (:mod:`servo.runner`) decide when ticks happen
(lockstep or wall-clock paced) and advance the rig between them.

Live changes (gains, controller swaps, new motions, stop/enable — from MAVLink, the console or
the API) are submitted with :meth:`ServoLoop.submit` from any thread and applied at the start
of the next tick, never mid-tick.

Watchdog → safe stop (amplifiers disabled, DAC outputs 0 V, the reason recorded) on:

* a driver error (bus error, ADC timeout, decoder error, …) while reading or writing;
* implausible sensor data: non-finite values, a potentiometer at the ADC rail (open wiper), a
  position jump larger than ``max_jump_rad`` in one tick;
* an amplifier fault line;
* cross-checks (:mod:`servo.watchdog`): encoder against pot, tachometer against the position
  derivative, current monitor against the commanded current, and a position reading that
  stays put while its target moves on;
* a following error beyond the joint's limit;
* a measured position past a soft limit by more than the margin: a category-1 stop (cause
  ``soft_limit``, :mod:`servo.stops`), the joints decelerated from where they are.
"""

from __future__ import annotations

import queue
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any, Protocol

import numpy as np

from hal.hand import HandModel
from hal.lanes import LaneSet
from servo.blackbox import HOLDING, RUNNING, STOPPED, STOPPING, BlackBox
from servo.control.objects import ControlContext, Controller, SwitchableController
from servo.fine_positioning import MEASURE_KEY
from servo.hand import HandCurrent, HandError, HandStay, TorqueWindow
from servo.interrupts import INTERRUPTS, SignalsDeferred, interrupt_name
from servo.io import JointIO, Measurement
from servo.named_controllers import ControllerChoices
from servo.stops import NOT_FAULTS, ControlledStop, Deceleration, StopCategory, StopSettings
from servo.trajectory.base import Sample
from servo.trajectory.bounds import MotionRefused
from servo.trajectory.sequencer import LaneSequencer, PlanContext, Sequencer
from servo.watchdog import CrossChecks, LaneTrip, WatchdogConfig

__all__ = ["Fault", "LiveCommand", "Recorder", "ServoLoop", "WatchdogConfig"]

LiveCommand = Callable[["ServoLoop"], Any]


def _not_in_lanes(name: str, *args: Any, **kwargs: Any) -> Any:
    raise NotImplementedError(f"ServoLoop.{name} cannot run in lanes (batched lockstep)")


class VisionOutcome(Protocol):
    """What the loop keeps of a run's visual-servo link (:class:`servo.vservo.VisionLink`): the
    loop never steps it (its ``vservo`` trajectory does), the run report asks it how it went."""

    def summary(self) -> dict[str, Any]: ...

    def freeze(self) -> None:
        """Keep the state at the end of the run's own ticks (before its end-of-run stop)."""


@dataclass
class Fault:
    """Why the loop stopped."""

    tick: int
    time_s: float
    cause: str
    joint: str | None
    detail: str

    def as_dict(self) -> dict[str, Any]:
        return {"tick": self.tick, "time_s": self.time_s, "cause": self.cause, "joint": self.joint,
                "detail": self.detail}


@dataclass
class Recorder:
    """Per-tick arrays (preallocated; ``min(n_ticks, max_rows)`` × joints).

    A run of up to ``max_rows`` ticks keeps every tick. A longer one stays memory-flat: the
    arrays are a ring holding its last ``max_rows`` ticks (``dropped`` counts the older ones
    overwritten); :meth:`trimmed` returns them in time order. ``max_rows=None``: no bound."""

    n_ticks: int
    n: int
    count: int = 0
    data: dict[str, np.ndarray] = field(default_factory=dict)
    #: the most ticks kept (default: 2**15, 262 s at 125 Hz; ~8 MiB for 2 joints)
    max_rows: int | None = 2**15

    FIELDS = ("theta_d", "omega_d", "theta", "omega", "theta_pot", "theta_enc", "omega_tach", "omega_enc",
              "torque", "current_cmd", "current", "integrating", "kp_eff", "theta_true", "omega_true")

    def __post_init__(self) -> None:
        if self.max_rows is not None and self.max_rows < 1:
            raise ValueError(f"Recorder max_rows {self.max_rows!r}: expected at least 1 or None")
        # the arrays come with the first row (_allocate): a batch of lanes builds B scalar loops
        # whose recorders never record (Recorder.from_lanes), 1.2 MiB each for a jpl-arm sweep point

    def _allocate(self) -> dict[str, np.ndarray]:
        rows = self.rows
        data = self.data
        for f in self.FIELDS:
            data[f] = np.full((rows, self.n), np.nan)
        data["t"] = np.full(rows, np.nan)
        data["compute_s"] = np.full(rows, np.nan)
        return data

    @property
    def rows(self) -> int:
        """How many ticks the arrays hold."""
        return max(0, self.n_ticks) if self.max_rows is None else max(0, min(self.n_ticks, self.max_rows))

    @property
    def dropped(self) -> int:
        """Ticks recorded and since overwritten by later ones (0 unless the run outgrew ``max_rows``)."""
        return max(0, self.count - self.rows)

    def put(self, k: int, **values: Any) -> None:
        if not 0 <= k < self.n_ticks:
            return
        i = k % self.rows
        data = self.data or self._allocate()
        for name, v in values.items():
            data[name][i] = v
        self.count = max(self.count, k + 1)

    @classmethod
    def from_lanes(cls, recorders: Sequence[Recorder]) -> Recorder:
        """One recorder for B lanes (batched lockstep, :mod:`hal.lanes`): rows of B·n joints,
        lane-major; the rows recorded so far (the same ticks in every lane) concatenated. The B
        recorders are spent: their arrays are released (a batch of 400 would hold every row twice)."""
        first = recorders[0]
        for r in recorders:
            if (r.n_ticks, r.n, r.count, r.max_rows) != (first.n_ticks, first.n, first.count, first.max_rows):
                raise NotImplementedError("lanes' recorders differ in size or rows: they cannot run as lanes")
        rec = cls._of(first.n_ticks, first.n * len(recorders), first.count, first.max_rows)
        if first.count == 0:  # nothing recorded yet (a batch stacks before its first tick)
            return rec
        for f in cls.FIELDS:
            rec.data[f] = np.concatenate([r.data[f] for r in recorders], axis=1)
        for f in ("t", "compute_s"):
            rec.data[f] = first.data[f].copy()
        for r in recorders:
            r.data = {}
        return rec

    @classmethod
    def _of(cls, n_ticks: int, n: int, count: int, max_rows: int | None) -> Recorder:
        """A recorder of these sizes whose arrays come with its first row or from the caller."""
        rec = cls.__new__(cls)
        rec.n_ticks, rec.n, rec.count, rec.max_rows, rec.data = n_ticks, n, count, max_rows, {}
        return rec

    def lane(self, lane: int, n: int) -> Recorder:
        """Lane ``lane``'s rows of a lane recorder of ``n`` joints per lane (:meth:`from_lanes`): a
        recorder of one instance holding what its scalar run records (``compute_s``: the batch's).
        Its joint arrays are views of this recorder's (no copy: a batch reads its lanes one by one)."""
        rec = Recorder._of(self.n_ticks, n, self.count, self.max_rows)
        if not self.data:
            return rec
        sl = slice(lane * n, (lane + 1) * n)
        for f in self.FIELDS:
            rec.data[f] = self.data[f][:, sl]
        for f in ("t", "compute_s"):
            rec.data[f] = self.data[f].copy()
        return rec

    def trimmed(self) -> dict[str, np.ndarray]:
        """The ticks kept, in time order: all of them (``count``) unless some were ``dropped``."""
        data = self.data or self._allocate()
        if self.count <= self.rows:
            return {k: v[: self.count] for k, v in data.items()}
        start = self.count % self.rows
        return {k: np.concatenate((v[start:], v[:start])) for k, v in data.items()}


class ServoLoop:
    """Per-tick control of all joints of a rig."""

    LOG_MAX = 10_000  #: notes kept in :attr:`log`

    def __init__(self, io: JointIO, controller: Controller, sequencer: Sequencer, watchdog: WatchdogConfig,
                 *, recorder: Recorder | None = None, names: list[str] | None = None,
                 plan_context: PlanContext | None = None) -> None:
        """``plan_context``: the limits new moves are planned with (live motions, :meth:`resume`);
        ``None``: the current sequencer's."""
        self.io = io
        self.n = io.n
        self.period_s = io.period_s
        self.controller = SwitchableController(controller)
        self.sequencer = sequencer
        self.watchdog = watchdog
        self.recorder = recorder
        self.names = names or [f"j{i + 1}" for i in range(self.n)]
        self.fault: Fault | None = None
        #: after a safe stop: what its read-back could not confirm as safe (empty: all safe)
        self.stop_incomplete: list[str] = []
        #: how the run ended (:meth:`shutdown`): reason, tick, whether the read-back confirmed it
        self.final_stop: dict[str, Any] | None = None
        #: every interruption of the run, in order: ``{"signal", "tick", "during"}`` with
        #: ``during`` ``run`` (it ended the ticks), ``stop`` (held by a stop's critical section
        #: until the stop was done) or ``after`` (held while the run's results were written)
        self.interruptions: list[dict[str, Any]] = []
        self._interrupts_seen: list[BaseException] = []
        self.enabled = False
        self.tick_count = 0
        self._inbox: queue.SimpleQueue[tuple[LiveCommand, Callable[[Any, BaseException | None], None] | None]] = (
            queue.SimpleQueue())
        self._t_motion0 = 0.0
        self._last_theta: np.ndarray | None = None
        self.cross_checks = CrossChecks(io, watchdog)
        self.last: dict[str, Any] = {}
        #: every fault of the run, oldest first (``fault`` is the current one; a resume clears
        #: ``fault`` but not this list)
        self.faults: list[Fault] = []
        #: live changes and notes, (time, source, message), the newest ``LOG_MAX`` of them
        self.log: deque[tuple[float, str, str]] = deque(maxlen=self.LOG_MAX)
        #: notes dropped from the front of ``log`` to keep it bounded (long runs)
        self.log_dropped = 0
        self.plan_context = plan_context
        self._offer_measurement(sequencer.ctx)
        if plan_context is not None:
            self._offer_measurement(plan_context)
        #: the run's visual-servo link when it has one (set by ``vmehil run --vision``), for the report
        self.vision: VisionOutcome | None = None
        #: when this tick's readings were taken (s; ``None``: one period per tick), for the
        #: cross-checks: set where samples can skip or repeat periods (a free-running plant)
        self.sample_clock: Callable[[], float | None] | None = None
        #: how stops run (servo.stops; set by servo.assembly.build_loop). ``None``: every stop is
        #: category 0, as a loop built by hand always stopped
        self.stop_settings: StopSettings | None = None
        #: the ticks of the run proper, before its end (the end-of-run stop and the window watched
        #: after it: :meth:`servo.runner.LockstepRunner.end_run`); ``None``: not ended that way
        self.run_ticks: int | None = None
        #: a category-1 stop under way (``None``: none)
        self.stopping: ControlledStop | None = None
        #: the category of the last stop (``None``: none yet), and its cause
        self.stop_category: StopCategory | None = None
        self.stop_cause: str | None = None
        #: a category-1 stop that fell to category 0: why (``None``: none did)
        self.stop_fell: str | None = None
        #: the tick the last stop began, and the true (plant) and measured angles then (rad)
        self.stop_tick: int | None = None
        self._stop_origin: dict[str, np.ndarray] = {}
        #: per joint the largest movement from the angles at the stop, true and measured (rad)
        self.stop_excursion: dict[str, np.ndarray] = {}
        #: moves refused when they were to start (planned only then: after an open vservo move)
        self.refusals: list[MotionRefused] = []
        #: moves wait until every homeable joint's encoder is homed (``io.homed``; set from the
        #: settings by servo.assembly); the loop itself does not refuse them, its hosts do
        self.require_homing = False
        #: per joint how far past its soft limit it may be (``None``: the margin; see _soft_allowance)
        self._soft_allow: np.ndarray | None = None
        #: the named controllers per joint (servo.named_controllers; set by servo.assembly.build_loop)
        #: and per joint the index of the one in force
        self.controllers: ControllerChoices | None = None
        self.active_controller: list[int] = [0] * self.n
        #: the hand's current-command mode (servo.hand; ``None``: every joint by position)
        self.hand: HandCurrent | None = None
        #: the hand move last started: each starts its command once
        self._hand_move: HandStay | None = None
        #: the soft limit the hand is held at by position once its current drove it there (servo.hand)
        self.hand_hold_rad: float | None = None
        #: the hand's fingers (``[hand]``, set by servo.assembly.build_loop; ``None``: no hand)
        self.hand_model: HandModel | None = None
        #: the arm's measured holding torques over the last second (servo.hand; ``None``: not
        #: kept — the console's ``open`` starts it, for ``weigh``)
        self.torque_window: TorqueWindow | None = None
        #: the last seconds of every joint's signals and lines (servo.blackbox; set by
        #: servo.assembly.build_loop; ``None``: not kept)
        self.blackbox: BlackBox | None = None
        #: the lanes of a batch this loop ticks (batched lockstep, :meth:`from_lanes`); ``None``:
        #: one instance. In lanes, ``n`` counts the joints of every lane (lane-major) and
        #: ``lane_n`` those of one lane
        self.lanes: LaneSet | None = None
        self.lane_n = self.n
        #: in lanes: why each lane its watchdog ejected would have stopped (its scalar run's fault)
        self.lane_faults: dict[int, Fault] = {}

    # --- lanes (batched lockstep) -----------------------------------------------------------------
    @classmethod
    def from_lanes(cls, loops: Sequence[ServoLoop], io: JointIO, lanes: LaneSet) -> ServoLoop:
        """One loop ticking the B lanes of ``loops`` (batched lockstep, :mod:`hal.lanes`; lane b is
        ``loops[b]``, built and not yet ticked as its scalar run builds it) through ``io``, their
        drivers stacked (:meth:`servo.io.JointIO.from_lanes`). Joints are lane-major: joint j of
        lane b at ``b*n + j``; the controller, watchdog, cross-checks, motion and recorder are the
        lanes' stacked (their ``from_lanes``).

        :meth:`tick` is then the lane tick, selected here once (the scalar tick is unchanged): every
        check runs per lane, and a lane whose scalar run would stop (a watchdog trip, a soft limit)
        is ejected with its cause (``lanes.reasons``, :attr:`lane_faults`) while the others run on.
        A failure every lane shares (a driver error, an exception) ejects every lane. The end of
        the run (:meth:`armed`'s exit) stops every live lane alike. :meth:`write_lane` hands each
        lane's end state back to its scalar loop. Not in lanes (NotImplementedError): live
        commands pending, the hand by current, vision, a free-running plant's sample clock, a stop
        under way or a fault; the loops' black boxes are not kept (no part of a run's results)."""
        first = loops[0]
        size = len(loops)
        if size != lanes.size:
            raise ValueError(f"{size} loops for {lanes.size} lanes")
        n = first.n
        for lp in loops:
            if lp.lanes is not None:
                raise NotImplementedError("a loop already in lanes cannot be stacked again")
            if (lp.n, lp.period_s, lp.names, lp.tick_count, lp.enabled, lp._t_motion0) != (
                    n, first.period_s, first.names, first.tick_count, first.enabled, first._t_motion0):
                raise NotImplementedError("lanes' loops differ in joints, period, tick or state: not as lanes")
            if lp.fault is not None or lp.stopping is not None or lp.stop_category is not None:
                raise NotImplementedError("a stopped loop cannot run in lanes")
            if lp.hand is not None or lp._hand_move is not None or lp.torque_window is not None:
                raise NotImplementedError("the hand by current cannot run in lanes")
            if lp.vision is not None:
                raise NotImplementedError("a vision link cannot run in lanes")
            if lp.sample_clock is not None:
                raise NotImplementedError("a free-running plant's sample clock cannot run in lanes")
            if lp._soft_allow is not None:
                raise NotImplementedError("a loop resumed past its soft limit cannot run in lanes")
            if not lp._inbox.empty():
                raise NotImplementedError("live commands pending cannot run in lanes")
            if (lp._last_theta is None) != (first._last_theta is None) or (lp.recorder is None) != (
                    first.recorder is None):
                raise NotImplementedError("lanes' loops are not at the same point: they cannot run as lanes")
        obj = cls.__new__(cls)
        obj.__dict__.update(first.__dict__)  # rig-wide settings (names, period, stop settings…), then per lane:
        obj.io = io
        obj.n = n * size
        obj.lanes = lanes
        obj.lane_n = n
        obj.lane_faults = {}
        obj.controller = SwitchableController.from_lanes([lp.controller for lp in loops])
        obj.sequencer = LaneSequencer([lp.sequencer for lp in loops])  # type: ignore[assignment]
        obj.watchdog = WatchdogConfig.from_lanes([lp.watchdog for lp in loops])
        obj.cross_checks = CrossChecks.from_lanes([lp.cross_checks for lp in loops], io, obj.watchdog, size)
        obj.recorder = None if first.recorder is None else Recorder.from_lanes(
            [lp.recorder for lp in loops if lp.recorder is not None])
        obj._last_theta = None if first._last_theta is None else np.concatenate(
            [lp._last_theta for lp in loops if lp._last_theta is not None])
        obj.fault = None
        obj.faults = []
        obj.stop_incomplete = []
        obj.final_stop = None
        obj.interruptions = []
        obj._interrupts_seen = []
        obj._inbox = queue.SimpleQueue()
        obj.last = {}
        obj.log = deque(maxlen=cls.LOG_MAX)
        obj.log_dropped = 0
        obj.refusals = []
        obj._stop_origin = {}
        obj.stop_excursion = {}
        obj.active_controller = list(first.active_controller)
        obj.blackbox = None
        obj.__dict__["tick"] = obj._tick_lanes  # the lane tick, chosen once (the scalar one is untouched)
        for name in ("submit", "set_motion", "set_hand", "resume"):  # live changes: not in lanes
            obj.__dict__[name] = partial(_not_in_lanes, name)
        return obj

    def _tick_lanes(self, truth: Mapping[str, np.ndarray] | None = None) -> None:
        """:meth:`tick` in lanes: the scalar tick's work, elementwise over the lanes' joints; where
        the scalar tick would stop a lane, that lane is ejected (see :meth:`from_lanes`)."""
        k = self.tick_count
        t0 = time.perf_counter()
        lanes = self.lanes
        assert lanes is not None
        lanes.tick = k
        t = k * self.period_s
        with np.errstate(all="ignore"):  # ejected lanes go on being computed: garbage, never an error
            if self.fault is not None or not self.enabled:
                try:
                    m_stopped: Measurement | None = self.io.read()
                except Exception:
                    m_stopped = None
                self._record(k, t, m_stopped, None, None, truth, t0)
                self.tick_count += 1
                return
            try:
                m = self.io.read()
            except Exception as e:  # every lane's read: every lane's stop
                self.safe_stop("driver_error", f"{type(e).__name__}: {e}")
                self._record(k, t, None, None, None, truth, t0)
                self.tick_count += 1
                return
            wd = self.watchdog
            if wd.enabled and (wd.soft_min_rad is not None or wd.soft_max_rad is not None):
                over = wd.past_soft_limit(m.theta) - wd.soft_limit_margin_rad
                self._trip_lanes("soft_limit", over > 0.0, np.argmax(over.reshape(-1, self.lane_n), axis=1), lambda i: (
                    f"position {np.degrees(m.theta[i]):+.2f}° past a soft limit by more than "
                    f"{np.degrees(wd.soft_limit_margin_rad):g}° (a category-1 stop in its scalar run)"))
            sample = self.sequencer.sample(max(0.0, t - self._t_motion0))
            self._check_lanes(m, sample)
            out = self.controller.update(self._context(k, t, m, sample))
            try:
                current = self.io.write_torque(out.torque, m.omega)
            except Exception as e:
                self.safe_stop("driver_error", f"{type(e).__name__}: {e}")
                current = None
            self._record(k, t, m, sample, (out, current), truth, t0)
            self.tick_count += 1

    def _trip_lanes(self, cause: str, bad: np.ndarray, worst: np.ndarray | None,
                    detail: Callable[[int], str]) -> None:
        """Eject the live lanes where ``bad`` (per joint, lane-major) holds for some joint: each with
        ``cause`` and its scalar stop's ``detail`` for the joint its scalar check names (``worst``:
        per lane the joint's index within the lane, or its flat index; ``None``: the first joint
        where ``bad`` holds)."""
        lanes = self.lanes
        assert lanes is not None
        n = self.lane_n
        flat = np.asarray(bad, bool)
        if not np.count_nonzero(flat):  # the usual: no joint of any lane (a dozen checks a tick)
            return
        rows = flat.reshape(-1, n)
        hit = rows.any(axis=1) & lanes.alive
        if not hit.any():
            return
        for b in np.flatnonzero(hit).tolist():
            j = int(np.argmax(rows[b])) if worst is None else int(worst[b]) % n
            text = detail(b * n + j)
            tick = self.tick_count
            self.lane_faults[b] = Fault(tick, tick * self.period_s, cause, self.names[j], text)
            lanes.eject(np.arange(lanes.size) == b, f"{cause} ({self.names[j]}): {text}")

    def _check_lanes(self, m: Measurement, sample: Sample) -> None:
        """:meth:`_check` per lane: a lane whose check fails is ejected (its scalar run stops)."""
        wd = self.watchdog
        if not wd.enabled:
            return
        n = self.lane_n
        self._trip_lanes("amplifier_fault", np.asarray(m.fault, bool), None,
                         lambda i: "amplifier fault line asserted")
        self._trip_lanes("implausible_sensor", ~np.isfinite(m.theta) | ~np.isfinite(m.omega), None,
                         lambda i: "non-finite position or velocity reading")
        rail = np.isfinite(m.pot_v) & (np.abs(m.pot_v) >= wd.pot_rail_v)
        self._trip_lanes("implausible_sensor", rail, None,
                         lambda i: f"potentiometer at the ADC rail ({m.pot_v[i]:+.3f} V): open wiper?")
        if self._last_theta is not None:
            jump = np.abs(m.theta - self._last_theta)
            self._trip_lanes("implausible_sensor", jump > wd.max_jump_rad, np.argmax(jump.reshape(-1, n), axis=1),
                             lambda i: f"position jumped {jump[i]:.3f} rad in one tick")
        self._last_theta = m.theta.copy()
        self.cross_checks.config = wd
        t_s = self.sample_clock() if self.sample_clock is not None else None
        trips: list[LaneTrip] = self.cross_checks.check_lanes(m, sample.theta_d, sample.omega_d, t_s)
        for cause, hit, worst, detail in trips:
            self._trip_lanes(cause, np.repeat(hit, n), worst, detail)
        err = np.abs(np.asarray(sample.theta_d) - m.theta)
        over = err > wd.following_error_rad
        fe = wd.following_error_rad
        self._trip_lanes("following_error", over, None,
                         lambda i: f"following error {err[i]:.4f} rad > limit {fe[i]:.4f} rad")

    def recorder_for_lane(self, lane: int) -> Recorder | None:
        """Lane ``lane``'s rows as its scalar recorder holds them (``None``: no recorder)."""
        if self.recorder is None:
            return None
        return self.recorder.lane(lane, self.lane_n) if self.lanes is not None else self.recorder

    def write_lane(self, lane: int, loop: ServoLoop) -> None:
        """Hand lane ``lane``'s end state to ``loop``, its scalar loop (the one stacked as that lane):
        recorded rows, the law's state and events, the cross-checks, the tick count and how the run
        ended — so that its run's report (``summarize``, the figures) reads as its scalar run's.
        Its sequencer is the lane's own already. For a lane still live at the end."""
        n = self.lane_n
        sl = slice(lane * n, (lane + 1) * n)
        if self.recorder is not None:
            loop.recorder = self.recorder.lane(lane, n)
        self.controller.active.write_lane(lane, loop.controller.active)
        self.cross_checks.write_lane(lane, loop.cross_checks)
        loop.tick_count = self.tick_count
        loop.run_ticks = self.run_ticks
        loop.enabled = self.enabled
        loop._last_theta = None if self._last_theta is None else self._last_theta[sl].copy()
        loop.stop_category, loop.stop_cause, loop.stop_fell = self.stop_category, self.stop_cause, self.stop_fell
        loop.stop_tick = self.stop_tick
        loop._stop_origin = {k: v[sl].copy() for k, v in self._stop_origin.items()}
        loop.stop_excursion = {k: v[sl].copy() for k, v in self.stop_excursion.items()}
        loop.last = {k: (v[sl].copy() if isinstance(v, np.ndarray) and v.shape == (self.n,) else v)
                     for k, v in self.last.items() if k != "measurement"}
        failures = list(self.stop_incomplete)
        per_lane = getattr(self.io, "lane_stop_failures", None)
        if per_lane is not None:
            failures = list(per_lane[lane])
        loop.stop_incomplete = failures
        loop.interruptions = list(self.interruptions)
        loop.faults = list(self.faults)
        loop.fault = self.fault
        if self.final_stop is not None:
            fs = dict(self.final_stop)
            fs.update(verified=not failures, incomplete=list(failures), interruptions=loop.interruptions)
            fs.update(loop.stop_summary())
            loop.final_stop = fs

    # --- live interface ------------------------------------------------------------------------
    def submit(self, command: LiveCommand,
               done: Callable[[Any, BaseException | None], None] | None = None) -> None:
        """Queue ``command(loop)`` for the next tick boundary (thread-safe). ``done(result, error)``
        is called after it ran."""
        self._inbox.put((command, done))

    def _drain(self) -> None:
        while True:
            try:
                command, done = self._inbox.get_nowait()
            except queue.Empty:
                return
            try:
                result = command(self)
            except Exception as e:
                if done is not None:
                    done(None, e)
                continue
            if done is not None:
                done(result, None)

    def note(self, source: str, message: str) -> None:
        """Log a change with simulated time and its source (``mavlink``, ``console``, ``api``); past
        ``LOG_MAX`` notes the oldest is dropped (counted in ``log_dropped``)."""
        if len(self.log) == self.LOG_MAX:
            self.log_dropped += 1
        self.log.append((self.tick_count * self.period_s, source, message))

    def set_motion(self, sequencer: Sequencer) -> None:
        """Start a new motion at the current tick (call inside a live command)."""
        self.sequencer = sequencer
        self._offer_measurement(sequencer.ctx)
        self._t_motion0 = self.tick_count * self.period_s

    def _offer_measurement(self, ctx: PlanContext) -> None:
        """Moves that act on where the joints are (a Cartesian move's fine positioning,
        servo.fine_positioning) read the latest measured angles through their plan context (the
        loop given the motion last is the one that moves it)."""
        ctx.extras[MEASURE_KEY] = self._measured_theta

    def _measured_theta(self) -> np.ndarray | None:
        return self.last.get("theta")

    @property
    def law(self):
        return self.controller.active.law

    # --- start / stop -----------------------------------------------------------------------------
    def start(self) -> None:
        """Clear amplifier faults, zero the outputs and enable the amplifiers."""
        self.io.clear_faults()
        self.io.write_torque(np.zeros(self.n))
        self.io.enable(True)
        self.enabled = True

    @property
    def interrupted_by(self) -> BaseException | None:
        """The first interruption recorded (:meth:`note_interruption`), ``None`` if none was."""
        return self._interrupts_seen[0] if self._interrupts_seen else None

    def note_interruption(self, exc: BaseException, during: str) -> None:
        """Record a SIGINT/SIGTERM/SIGHUP (as raised or held) in :attr:`interruptions`; the same
        exception seen again (re-raised up the stack) is recorded once."""
        if any(x is exc for x in self._interrupts_seen):
            return
        self._interrupts_seen.append(exc)
        self.interruptions.append({"signal": interrupt_name(exc), "tick": self.tick_count, "during": during})

    def shutdown(self, reason: str, detail: str = "") -> list[str]:
        """End of a run: amplifiers disabled, 0 V commanded, PWM off, read back.

        Recorded in :attr:`final_stop` (``reason``: ``end``, ``fault``, ``interrupted`` or
        ``exception``; ``detail``; what the read-back could not confirm; ``interruptions``: every
        interruption of the run, this list kept up to date to the end); a fault recorded earlier
        is kept as it was. Returns the unconfirmed items. A signal-safe critical section like
        :meth:`safe_stop`: a signal arriving meanwhile is raised when it is done."""
        held = self._shutdown(reason, detail)
        if held:
            raise held[0]
        return self.stop_incomplete

    def _shutdown(self, reason: str, detail: str, then: SignalsDeferred | None = None) -> list[BaseException]:
        """:meth:`shutdown`'s work in a critical section; returns what it held. ``then`` (a
        section of the caller's) begins before this one ends, so no signal falls in between."""
        held: list[BaseException] = []
        with SignalsDeferred(held):
            powered = self.enabled and self.fault is None  # this shutdown is the stop itself
            failures = self.io.safe_stop(held)
            self.enabled = False
            self.stop_incomplete = failures
            if self.stopping is not None:  # a category-1 stop cut short by the end of the run
                self.stop_fell = f"{reason}: {detail} (before the category-1 stop for {self.stopping.cause} completed)"
                self.stopping = None
                self.stop_category = StopCategory.UNCONTROLLED
            if powered or self.stop_category is None:  # no stop before this one: power off at once
                self._note_stop_begin(reason)
                self.stop_category = StopCategory.UNCONTROLLED
            self.final_stop = {"reason": reason, "detail": detail, "tick": self.tick_count,
                               "time_s": self.tick_count * self.period_s, "verified": not failures,
                               "incomplete": list(failures), "interruptions": self.interruptions,
                               **self.stop_summary()}
            for e in held:
                self.note_interruption(e, "stop")
            if then is not None:
                then.begin()
        for e in held:  # any held after the notes above
            self.note_interruption(e, "stop")
        return held

    @contextmanager
    def armed(self, then: SignalsDeferred | None = None) -> Iterator[ServoLoop]:
        """``start()`` the loop; however the block is left — its end, an exception, Ctrl-C,
        SIGTERM raised as :class:`servo.interrupts.Terminated` — :meth:`shutdown` it. An
        exception or a signal that leaves the block is also recorded as the fault (cause
        ``exception`` or ``interrupted``) unless one was recorded already, and re-raised; a
        block that ends after a fault (a watchdog stop, or a runner that caught a signal) ends
        with that fault's cause as the reason.

        The stops here complete whatever signals arrive (each a critical section, retried when
        a signal came just before it began); every interruption is recorded (:attr:`interruptions`).
        A block that ended normally but was interrupted during its final stop raises the first
        such interruption after it. ``then``: the caller's critical section (writing the run's
        results), begun before the final stop's own ends — the caller ends it."""
        self.start()
        ended = False
        try:
            yield self
            ended = True
        except INTERRUPTS as e:
            self.note_interruption(e, "run")
            self._stop_retrying("interrupted", f"{interrupt_name(e)} received")
            raise
        except BaseException as e:
            self._stop_retrying("exception", f"{type(e).__name__}: {e}")
            raise
        finally:
            held: list[BaseException] = []
            while True:
                try:
                    f = self.fault
                    if f is None:
                        held = self._shutdown("end", "the run ended", then)
                    else:
                        reason = f.cause if f.cause in ("interrupted", "exception") else "fault"
                        held = self._shutdown(reason, f.detail, then)
                    break
                except INTERRUPTS as e:  # came before the stop's section began: stop again
                    self.note_interruption(e, "stop")
            if held and ended:
                raise held[0]

    def _stop_retrying(self, cause: str, detail: str) -> None:
        """:meth:`safe_stop` until it has run to its end; interruptions are recorded, not raised."""
        while True:
            try:
                self._safe_stop(cause, detail, None)
                return
            except INTERRUPTS as e:  # came before the stop's section began
                self.note_interruption(e, "stop")

    def resume(self, hold_measured: bool = True) -> np.ndarray | None:
        """Leave a safe stop (or a stop) and servo again: clear the fault, forget the watchdog's
        memory of positions from before the stop (the joints may have moved meanwhile), reset the
        control objects' state (pid integrators, switch-off) — with ``hold_measured``, each joint's
        law starts with the torque that holds it where it is (:meth:`_holding_torque`,
        ``preload_torque``), so the amplifier carries its load when the brake releases
        (:class:`servo.io.JointIO`: one release delay after the first torque write) — then
        :meth:`start` (clear amplifier faults, zero the outputs, enable).

        ``hold_measured``: read the joints first and hold them where they are (a new, empty
        motion from the measured position, rad) — returned. A read error or a non-finite position
        raises before anything changes; an error while enabling safe-stops again and re-raises.
        Call it at a tick boundary (inside a live command) or while no runner ticks.
        """
        theta = None
        if hold_measured:
            theta = np.asarray(self.io.read().theta, float).copy()
            if not np.all(np.isfinite(theta)):
                raise ValueError("a joint position reads as not finite; check the sensors before resuming")
        if theta is not None:  # a joint a soft-limit stop left past its limit may come back from there
            past = self.watchdog.past_soft_limit(theta)
            margin = self.watchdog.soft_limit_margin_rad
            self._soft_allow = np.maximum(margin, past + margin) if np.any(past > 0.0) else None
        self.fault = None
        self.stopping = None
        self.set_hand(None)  # the hand too is held by position where it is (servo.hand)
        self.stop_tick = None  # the excursion of the last stop is kept, no longer tracked
        self._last_theta = None
        self.cross_checks.reset()
        if theta is not None:
            ctx = self.plan_context or self.sequencer.ctx
            self.set_motion(Sequencer([], theta, ctx))
        preload = self._holding_torque(theta)
        for obj in self.controller.active.objects:
            obj.reset()
            if preload is not None and preload.any():
                # the law starts with the torque that holds each joint where it is, so the
                # amplifier carries the load before the brake lets go (servo.io.JointIO)
                obj.preload_torque(preload, self.controller.active.chain)
        try:
            self.start()
        except Exception as e:
            self.safe_stop("driver_error", f"resume failed: {type(e).__name__}: {e}")
            raise
        return theta

    def _holding_torque(self, theta: np.ndarray | None) -> np.ndarray | None:
        """The torque a resume holding ``theta`` (the measured angles) starts each joint's law
        with: its holding load there (:class:`servo.stops.HoldingLoad`, the joint's nominal
        gravity) where the rig states it; else, for a joint its holding brake kept, the torque
        commanded when it stopped (its load if it was at rest then; a moving joint's also carried
        its friction and acceleration); else 0. ``None`` without ``theta``: a kept target's error
        would add to it."""
        if theta is None:
            return None
        held = getattr(self.io, "torque_at_stop_nm", None)  # (test fakes of JointIO have none)
        at_stop = np.zeros(self.n) if held is None else np.asarray(held, float).copy()
        if self.stop_settings is None:
            return at_stop
        load = self.stop_settings.load.torque_nm(theta)
        return np.where(np.isfinite(load), load, at_stop)

    def category_of(self, cause: str) -> StopCategory:
        """The stop category for ``cause`` (servo.stops; 0 for a loop without stop settings)."""
        return self.stop_settings.category(cause) if self.stop_settings is not None else StopCategory.UNCONTROLLED

    def stop(self, cause: str, detail: str = "", joint: int | None = None) -> StopCategory:
        """Stop by ``cause``'s category (:mod:`servo.stops`): 0 — :meth:`safe_stop` now; 1 — begin
        a controlled deceleration (the ticks that follow decelerate, engage the brakes with the
        amplifiers holding, then :meth:`safe_stop`; :attr:`stopping` until then); 2 — hold where
        the joints are, power kept. A category-1 stop asked of a loop that is not servoing (or
        already stopping) is done at once as category 0 (or left to the one under way). Call it
        at a tick boundary (inside a live command, or between runner ticks). Returns the category."""
        if self.lanes is not None:  # in lanes: every lane stops now (category 0), and is ejected
            self.safe_stop(cause, detail, joint)
            return StopCategory.UNCONTROLLED
        cat = self.category_of(cause)
        if cat == StopCategory.CONTROLLED and self.stopping is not None:
            return cat
        if not self.enabled and self.stopping is None and self.stop_category is not None:
            # already stopped: this request is the final stop's cause (the operator's shutdown
            # after an overrun); the category is that of the stop that removed the power
            self.stop_cause = cause
            self.safe_stop(cause, detail, joint)
            return self.stop_category
        if cat != StopCategory.UNCONTROLLED and (self.fault is not None or not self.enabled):
            cat = StopCategory.UNCONTROLLED
        if cat == StopCategory.UNCONTROLLED:
            self.safe_stop(cause, detail, joint)
            return cat
        # from where the joints are (not where their target was: the joints lag it by the following
        # error, and catching up would add that to the way to rest), at the target's speed
        target = self.last.get("theta")
        speed = self.last.get("omega_d")
        if speed is None or not np.all(np.isfinite(speed)):
            speed = self.last.get("omega")
        if target is None or speed is None or not np.all(np.isfinite(target)):
            self.safe_stop(cause, detail + " (no position to decelerate from)", joint)
            return StopCategory.UNCONTROLLED
        assert self.stop_settings is not None
        decel = np.asarray(self.stop_settings.decel_rad_s2, float)
        if cat == StopCategory.HOLDING:
            speed = np.zeros(self.n)
        self._note_stop_begin(cause)
        traj = Deceleration(np.asarray(target, float), np.asarray(speed, float), decel)
        if cat == StopCategory.HOLDING:
            ctx = self.plan_context or self.sequencer.ctx
            self.set_motion(Sequencer([], traj.theta0, ctx))
            self.stop_category = cat
            return cat
        self.stopping = ControlledStop(cause, detail, joint, self.tick_count, traj)
        self.note("servo", f"category-1 stop for {cause}: decelerating ({traj.duration:.3f} s)")
        return cat

    def _note_stop_begin(self, cause: str) -> None:
        """Remember where the joints were when a stop began (for :attr:`stop_excursion`)."""
        self.stop_cause = cause
        self.stop_fell = None
        self.stop_tick = self.tick_count
        self._stop_origin = {}
        self.stop_excursion = {}
        for key, name in (("theta_true", "true"), ("theta", "sensor")):
            v = self.last.get(key)
            if v is not None:
                self._stop_origin[name] = np.asarray(v, float).copy()
                self.stop_excursion[name] = np.zeros(self.n)

    def _track_excursion(self, truth: np.ndarray | None, theta: np.ndarray | None) -> None:
        for name, v in (("true", truth), ("sensor", theta)):
            if v is None:
                continue
            v = np.asarray(v, float)
            if name not in self._stop_origin:
                self._stop_origin[name] = v.copy()
                self.stop_excursion[name] = np.zeros(self.n)
            moved = np.abs(v - self._stop_origin[name])
            self.stop_excursion[name] = np.fmax(self.stop_excursion[name], moved)

    def stop_summary(self) -> dict[str, Any]:
        """The last stop for the run JSON: ``category``, ``cause``, ``fell_to_0`` (why a category-1
        stop fell to category 0, or ``None``), ``excursion_deg`` (joint → the largest movement from
        the angle at the stop, degrees: the plant's truth where there is one, else the sensors) and
        ``excursion_sensor_deg`` (the same from the sensors)."""
        def per_joint(v: np.ndarray | None) -> dict[str, float | None] | None:
            if v is None:
                return None
            return {n: (round(float(np.degrees(x)), 4) if np.isfinite(x) else None)
                    for n, x in zip(self.names, v, strict=True)}

        if self.lanes is not None:  # per lane: write_lane gives each lane's scalar loop its own
            sensor = true = None
        else:
            sensor = per_joint(self.stop_excursion.get("sensor"))
            true = per_joint(self.stop_excursion.get("true"))
        return {"category": None if self.stop_category is None else int(self.stop_category),
                "cause": self.stop_cause, "fell_to_0": self.stop_fell,
                "excursion_deg": true if true is not None else sensor, "excursion_sensor_deg": sensor}

    def _advance_stop(self, k: int) -> None:
        """A category-1 stop's next step, after this tick's command: past its time bound it falls to
        category 0; at rest (and settled) the brake lines drop, the amplifiers still holding; one
        engage delay later, power off."""
        st, cfg = self.stopping, self.stop_settings
        if st is None or cfg is None:
            return
        elapsed = (k + 1 - st.tick0) * self.period_s
        if elapsed > cfg.time_bound_s:
            self.safe_stop(st.cause, f"{st.detail} (the category-1 stop passed its time bound of "
                           f"{cfg.time_bound_s:g} s: fell to category 0)".lstrip(), st.joint)
            return
        if st.brakes_tick is None:
            if elapsed >= st.trajectory.duration + cfg.settle_s:
                self.io.engage_brakes()
                st.brakes_tick = k
            return
        # the brake lines dropped with tick brakes_tick's outputs, the enables drop with this tick's:
        # (k - brakes_tick) periods apart, at least the engage delay
        if (k - st.brakes_tick) * self.period_s >= cfg.brake_engage_s - 1e-9:
            held = self._safe_stop(st.cause, st.detail, st.joint, StopCategory.CONTROLLED)
            if held:
                raise held[0]

    def safe_stop(self, cause: str, detail: str, joint: int | None = None) -> None:
        """Disable the amplifiers, command 0 V, stop PWM, read it all back, and record why.

        The first fault is kept (later stops add nothing to it). What the read-back could not
        confirm goes to :attr:`stop_incomplete` — a separate, louder condition than the fault
        itself: the rig may still be powered.

        A signal-safe critical section (:class:`servo.interrupts.SignalsDeferred`): a signal
        arriving during the stop, or an interrupt raised inside one of its driver writes, does
        not cut it short; each is recorded (:attr:`interruptions`) and the first is raised once
        the stop is done and recorded."""
        held = self._safe_stop(cause, detail, joint)
        if held:
            raise held[0]

    def _safe_stop(self, cause: str, detail: str, joint: int | None,
                   category: StopCategory = StopCategory.UNCONTROLLED) -> list[BaseException]:
        held: list[BaseException] = []
        if self.lanes is not None:  # in lanes a stop is every lane's (a driver error, an exception, a signal)
            self.lanes.eject(True, f"{cause}: {detail}")
        with SignalsDeferred(held):
            failures = self.io.safe_stop(held)
            self.stop_incomplete = failures
            if failures:
                detail += " (safe stop incomplete: " + "; ".join(failures) + ")"
            controlled = self.stopping
            self.stopping = None
            if controlled is not None and category != StopCategory.CONTROLLED:
                # a category-1 stop that could not complete falls to category 0
                self.stop_fell = f"{cause}: {detail}"
                detail += f" (during a category-1 stop for {controlled.cause}: fell to category 0)"
            first = self.fault is None and (self.enabled or controlled is not None)
            if self.fault is None and cause not in NOT_FAULTS:
                tick = controlled.tick0 if controlled is not None and category == StopCategory.CONTROLLED \
                    else self.tick_count
                self.fault = Fault(tick, tick * self.period_s, cause,
                                   self.names[joint] if joint is not None else None, detail)
                self.faults.append(self.fault)
            if first:
                if controlled is None:
                    self._note_stop_begin(cause)
                self.stop_category = category
            self.enabled = False
            for e in held:
                self.note_interruption(e, "stop")
        for e in held:
            self.note_interruption(e, "stop")
        return held

    # --- one tick ---------------------------------------------------------------------------------
    def tick(self, truth: Mapping[str, np.ndarray] | None = None) -> None:
        """Run one servo period's work at tick ``self.tick_count``."""
        k = self.tick_count
        t0 = time.perf_counter()
        self._drain()
        t = k * self.period_s
        if self.fault is not None or not self.enabled:
            # stopped: the drivers still read (status, the excursion after the stop); a sensor
            # that no longer answers reads as nothing
            try:
                m_stopped: Measurement | None = self.io.read()
            except Exception:
                m_stopped = None
            self._record(k, t, m_stopped, None, None, truth, t0)
            self.tick_count += 1
            return
        try:
            m = self.io.read()
        except Exception as e:
            self.safe_stop("driver_error", f"{type(e).__name__}: {e}")
            self._record(k, t, None, None, None, truth, t0)
            self.tick_count += 1
            return
        if self.stopping is None and self.watchdog.enabled:
            past = self.watchdog.beyond_soft_limit(m.theta, self._soft_allowance(m.theta))
            if past is not None:  # a controlled stop (category 1): the sensors are sane
                j, pos, lim, side = past
                self.stop("soft_limit", f"position {np.degrees(pos):+.2f}° past the soft limit {side}_deg = "
                          f"{np.degrees(lim):+.2f}° by more than {np.degrees(self.watchdog.soft_limit_margin_rad):g}°",
                          j)
                if not self.enabled:  # it became a category-0 stop: nothing more to command
                    self._record(k, t, m, None, None, truth, t0)
                    self.tick_count += 1
                    return
        st = self.stopping
        if st is not None:
            sample = st.trajectory.sample((k - st.tick0) * self.period_s)
        else:
            sample = self._next_sample(t)
        hand = self.hand
        if hand is not None:  # the hand by current: its desired position is where it is
            j = hand.joint
            if self.hand_hold_rad is None and np.isfinite(m.theta[j]):
                lo, hi = self.watchdog.soft_limits(self.n)
                self.hand_hold_rad = hand.limit_hold(float(m.theta[j]), float(lo[j]), float(hi[j]))
            theta_d, omega_d = np.array(sample.theta_d, float), np.array(sample.omega_d, float)
            theta_d[j] = m.theta[j] if self.hand_hold_rad is None else self.hand_hold_rad
            omega_d[j] = 0.0
            sample = sample._replace(theta_d=theta_d, omega_d=omega_d)
        if self._check(m, sample):
            self._record(k, t, m, sample, None, truth, t0)
            self.tick_count += 1
            return
        if self.torque_window is not None and self.hand_model is not None:
            self.torque_window.add(m.current, float(m.omega[self.hand_model.joint]))
        out = self.controller.update(self._context(k, t, m, sample))
        if hand is not None and self.hand_hold_rad is None:
            out = replace(out, torque=self._hand_torque(hand, out.torque, m.omega))
        try:
            current = self.io.write_torque(out.torque, m.omega)
        except Exception as e:
            self.safe_stop("driver_error", f"{type(e).__name__}: {e}")
            current = None
        self._record(k, t, m, sample, (out, current), truth, t0)
        self.tick_count += 1
        if self.stopping is not None and self.fault is None:
            self._advance_stop(k)

    def set_hand(self, command: HandCurrent | None) -> None:
        """Drive the hand by ``command`` from the next tick (``None``: by position, where it is
        commanded now). Call at a tick boundary (inside a live command)."""
        self.hand = command
        self.hand_hold_rad = None

    def _hand_torque(self, hand: HandCurrent, torque: np.ndarray, omega: np.ndarray) -> np.ndarray:
        """``torque`` with the hand joint's replaced by its current command's (servo.hand)."""
        j = hand.joint
        s = self.io.scaling[j]
        out = np.array(torque, float)
        out[j] = hand.current_at(float(omega[j])) * s.ratio * s.kt_nm_per_a
        return out

    def _soft_allowance(self, theta: np.ndarray) -> np.ndarray | None:
        """How far past its soft limit each joint may be before the watchdog stops the loop: the
        margin, or for a joint a stop left further out (:meth:`resume`), where it was then plus the
        margin — shrinking as it comes back, so it may return but never go further out."""
        if self._soft_allow is None:
            return None
        margin = self.watchdog.soft_limit_margin_rad
        past = self.watchdog.past_soft_limit(theta)
        self._soft_allow = np.maximum(margin, np.fmin(self._soft_allow, past + margin))
        if np.all(self._soft_allow <= margin):
            self._soft_allow = None  # every joint back within the margin: the plain check again
        return self._soft_allow

    def _next_sample(self, t: float) -> Sample:
        """The motion's sample at ``t``. A move planned only when it starts (after an open
        ``vservo`` move) that the bounds refuse is not started: the joints hold where the previous
        move ended, and the refusal is noted (:attr:`refusals`)."""
        try:
            sample = self.sequencer.sample(max(0.0, t - self._t_motion0))
        except MotionRefused as e:
            self.refusals.append(e)
            self.note("servo", str(e))
            hold = np.asarray(self.sequencer.current.end, float).copy()
            self.set_motion(Sequencer([], hold, self.plan_context or self.sequencer.ctx))
            return self.sequencer.sample(0.0)
        current = self.sequencer.current
        if isinstance(current, HandStay) and self._hand_move is not current:
            self._hand_move = current  # a hand move starts: its command once
            self._start_hand_move(current)
        return sample

    def _start_hand_move(self, move: HandStay) -> None:
        """A motion file's hand move (servo.motion.HandMove): the hand by its current from now."""
        if self.hand_model is None:
            self.note("servo", f"hand move {move.hand_action}: this rig states no [hand]; ignored")
            return
        j = self.hand_model.joint
        try:
            cmd = HandCurrent.make(j, move.hand_action, move.hand_current_a, self.io.scaling[j].current_limit_a)
        except HandError as e:
            self.note("servo", f"hand move refused: {e}")
            return
        self.set_hand(cmd)
        self.note("servo", f"hand {cmd.action} at {cmd.current_a:g} A")

    def _context(self, k: int, t: float, m: Measurement, sample):
        ctrl = self.controller.active
        return ControlContext(
            tick=k, t=t, dt=self.period_s, theta=m.theta, omega=m.omega, theta_d=sample.theta_d,
            omega_d=sample.omega_d, alpha_d=np.broadcast_to(np.asarray(sample.alpha_d, float), (self.n,)),
            motion_done=sample.done, chain=ctrl.chain)

    def _check(self, m: Measurement, sample) -> bool:
        """Watchdog checks; returns True when it stopped the loop."""
        wd = self.watchdog
        if not wd.enabled:
            return False
        fault = np.asarray(m.fault, bool)
        if fault.any():
            self.safe_stop("amplifier_fault", "amplifier fault line asserted", int(np.argmax(fault)))
            return True
        bad = ~np.isfinite(m.theta) | ~np.isfinite(m.omega)
        if bad.any():
            i = int(np.argmax(bad))
            self.safe_stop("implausible_sensor", "non-finite position or velocity reading", i)
            return True
        rail = np.isfinite(m.pot_v) & (np.abs(m.pot_v) >= wd.pot_rail_v)
        if rail.any():
            i = int(np.argmax(rail))
            self.safe_stop("implausible_sensor", f"potentiometer at the ADC rail ({m.pot_v[i]:+.3f} V): open wiper?", i)
            return True
        if self._last_theta is not None:
            jump = np.abs(m.theta - self._last_theta)
            if (jump > wd.max_jump_rad).any():
                i = int(np.argmax(jump))
                self.safe_stop("implausible_sensor", f"position jumped {jump[i]:.3f} rad in one tick", i)
                return True
        self._last_theta = m.theta.copy()
        self.cross_checks.config = wd  # the limits in force now (live changes replace them)
        t_s = self.sample_clock() if self.sample_clock is not None else None
        trip = self.cross_checks.check(m, sample.theta_d, sample.omega_d, t_s)
        if trip is not None:
            self.safe_stop(trip.cause, trip.detail, trip.joint)
            return True
        err = np.abs(np.asarray(sample.theta_d) - m.theta)
        over = err > wd.following_error_rad
        if over.any():
            i = int(np.argmax(over))
            self.safe_stop("following_error",
                           f"following error {err[i]:.4f} rad > limit {wd.following_error_rad[i]:.4f} rad", i)
            return True
        return False

    def _record(self, k, t, m, sample, out, truth, t0) -> None:
        rec = self.recorder
        law = self.law
        row: dict[str, Any] = {"t": t}
        if m is not None:
            row.update(theta=m.theta, omega=m.omega, theta_pot=m.theta_pot, theta_enc=m.theta_enc,
                       omega_tach=m.omega_tach, omega_enc=m.omega_enc, current=m.current)
        if sample is not None:
            row.update(theta_d=sample.theta_d, omega_d=sample.omega_d)
        if out is not None:
            o, current = out
            row.update(torque=o.torque, integrating=o.integrating.astype(float))
            if current is not None:
                row["current_cmd"] = current
        elif self.fault is not None:
            row.update(torque=np.zeros(self.n), current_cmd=np.zeros(self.n))
        if law is not None:
            row["kp_eff"] = law.kp_eff()
        if truth is not None:
            row.update(theta_true=truth.get("theta_joint"), omega_true=truth.get("omega_joint"))
        row = {k2: v for k2, v in row.items() if v is not None}
        if self.stop_tick is not None:
            self._track_excursion(row.get("theta_true"), row.get("theta"))
        # the tick's readings as the drivers gave them (a trace's driver values: vmehil.scope)
        self.last = {**row, "tick": k, "fault": self.fault.as_dict() if self.fault else None, "measurement": m}
        if self.blackbox is not None:
            self._to_blackbox(self.blackbox, k, t, row, m, law)
        if rec is not None:
            rec.put(k, compute_s=time.perf_counter() - t0, **row)

    def _to_blackbox(self, box: BlackBox, k: int, t: float, row: dict[str, Any], m: Measurement | None,
                     law: Any) -> None:
        """This tick's row into the black box: values the tick already has, no bus access."""
        if not self.enabled:
            state = STOPPED
        elif self.stopping is not None:
            state = STOPPING
        elif self.stop_category == StopCategory.HOLDING and self.stop_tick is not None:
            state = HOLDING
        else:
            state = RUNNING
        lstate = law.state if law is not None else None
        box.put(k, t, row, state, integrator_e=lstate.ie if lstate is not None else None,
                integrator_v=lstate.iv if lstate is not None else None, enabled=self.enabled,
                brake_released=getattr(self.io, "brake_released", None),  # (test fakes of JointIO have none)
                amp_fault=m.fault if m is not None else None, stop_tick=self.stop_tick)
