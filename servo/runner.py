"""Runners: when ticks happen, and what advances between them.

Both runners execute the same tick through the plant boundary (:mod:`servo.boundary`): let
time pass to the tick's instant, put the sensor values in place, run
:meth:`servo.loop.ServoLoop.tick` (drivers → law → drivers), then make the one exchange per
servo period. They differ only in pacing:

* :class:`LockstepRunner` — simulated time only, as fast as the CPU allows, deterministic for
  a seed.
* :class:`RealtimeRunner` — ticks start at absolute wall-clock deadlines ``t0 + k·T`` (hybrid
  sleep, then spin for the last ``spin_s``). It records per-tick compute time, wake-up lateness
  and overruns. **Overrun policy:** a tick is never skipped and deadlines never slip: a tick
  that ends after the next deadline counts as an overrun and the next tick starts at once,
  late; the loop catches up when later ticks are shorter. Because the plant advances exactly
  one period per tick, a real-time run computes the same numbers as a lockstep run with the
  same seed — only the timing statistics differ. A loop that falls more than
  ``max_lateness_periods`` (default 5: 40 ms at 125 Hz) behind its deadline is no longer
  controlling anything in time: with ``overrun="stop"`` (the default) it safe-stops with the
  cause ``overrun``; ``overrun="warn"`` counts it and runs on.

**Every exit path safe-stops.** An exception raised anywhere in a tick (trajectory, control
object, drivers, plant, an after-tick hook) safe-stops the rig in the same tick with the cause
``exception`` and the exception's text; SIGINT (KeyboardInterrupt) and SIGTERM (see
:mod:`servo.interrupts`) with the cause ``interrupted``. The stop is then carried to the plant
by one more exchange, and the run ends: ``run`` returns the number of ticks completed and
:attr:`LockstepRunner.ended_by` says why (``None`` for a run that went to the end).
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from servo.boundary import PlantBoundary, PlantBoundaryError
from servo.interrupts import INTERRUPTS, SignalsDeferred, interrupt_name
from servo.loop import ServoLoop
from servo.rt import RealtimeSettings, apply_realtime, check_rt_priority, involuntary_switches, wait_until

Progress = Callable[[int, int], None]
#: how long a run watches the joints after its stop (s of simulated time; issue #29)
WATCH_AFTER_STOP_S = 2.0


class TickSeries:
    """One per-tick timing figure (s) of a real-time run, memory-flat: the newest ``capacity``
    values in a preallocated ring (percentiles are over them), with the count and the maximum
    over every value appended since the last :meth:`clear`. Appends like a list."""

    def __init__(self, capacity: int = 2**16) -> None:
        self._a = np.full(capacity, np.nan)
        self.total = 0  #: values appended since the last clear
        self.peak = -math.inf  #: the largest of them

    def append(self, x: float) -> None:
        self._a[self.total % len(self._a)] = x
        self.total += 1
        if x > self.peak:
            self.peak = x

    def clear(self) -> None:
        self.total = 0
        self.peak = -math.inf

    def __len__(self) -> int:
        return min(self.total, len(self._a))

    def values(self) -> np.ndarray:
        """The values kept, oldest first."""
        n = len(self._a)
        if self.total <= n:
            return self._a[: self.total].copy()
        i = self.total % n
        return np.concatenate((self._a[i:], self._a[:i]))


@dataclass
class TimingStats:
    """Real-time pacing figures (seconds). Each series keeps its newest 2**16 ticks (8.7 min at
    125 Hz; percentiles are over them) and its count and maximum over the whole run."""

    compute_s: TickSeries = field(default_factory=TickSeries)
    lateness_s: TickSeries = field(default_factory=TickSeries)
    overruns: int = 0
    #: per tick, the part of ``compute_s`` spent in the servo loop (drivers + law: what a real HIL
    #: controller runs) and in the harness exchange (clock, publish, in-process plant step)
    controller_s: TickSeries = field(default_factory=TickSeries)
    harness_s: TickSeries = field(default_factory=TickSeries)
    #: per tick, the thread CPU time of the compute: below ``compute_s`` when the thread was
    #: switched out; equal to it when the time went in this thread (our work, or a virtual CPU
    #: the hypervisor paused: compare :func:`servo.rt.machine_probe`)
    compute_cpu_s: TickSeries = field(default_factory=TickSeries)
    #: ticks whose compute saw at least one involuntary context switch, and overruns among them
    preempted: int = 0
    overruns_preempted: int = 0

    def summary(self, period_s: float) -> dict[str, float | int]:
        c = self.compute_s.values() if len(self.compute_s) else np.zeros(1)
        late = self.lateness_s.values() if len(self.lateness_s) else np.zeros(1)
        return {
            "ticks": self.compute_s.total,
            "overruns": self.overruns,
            "compute_p50_ms": float(np.percentile(c, 50) * 1e3),
            "compute_p99_ms": float(np.percentile(c, 99) * 1e3),
            "compute_max_ms": float(max(c.max(), self.compute_s.peak) * 1e3),
            "compute_p99_fraction_of_period": float(np.percentile(c, 99) / period_s),
            "lateness_p50_ms": float(np.percentile(late, 50) * 1e3),
            "lateness_p99_ms": float(np.percentile(late, 99) * 1e3),
            "lateness_max_ms": float(max(late.max(), self.lateness_s.peak) * 1e3),
            "ticks_preempted": self.preempted,
            "overruns_preempted": self.overruns_preempted,
            **series_summary("compute_cpu", self.compute_cpu_s, period_s),
            **series_summary("controller", self.controller_s, period_s),
            **series_summary("harness", self.harness_s, period_s),
        }


def series_summary(name: str, series: TickSeries, period_s: float) -> dict[str, float]:
    """``<name>_p50_ms``, ``_p99_ms``, ``_max_ms`` and ``_p99_fraction_of_period`` of one series
    ({} when it is empty)."""
    if not len(series):
        return {}
    v = series.values()
    p99 = float(np.percentile(v, 99))
    return {f"{name}_p50_ms": float(np.percentile(v, 50) * 1e3), f"{name}_p99_ms": p99 * 1e3,
            f"{name}_max_ms": float(max(v.max(), series.peak) * 1e3), f"{name}_p99_fraction_of_period": p99 / period_s}


class LockstepRunner:
    """Simulated time only; ``run(n)`` executes ``n`` ticks back to back."""

    def __init__(self, plant: PlantBoundary, loop: ServoLoop) -> None:
        self.plant = plant
        self.loop = loop
        self.period_s = plant.period_s
        self.period_ns = round(plant.period_s * 1e9)
        self.delay_s = plant.computation_delay_s
        self.delay_ns = round(self.delay_s * 1e9)
        self.overruns = 0
        self.after_tick: list[Callable[[ServoLoop], None]] = []
        #: wall seconds of the last tick spent in the servo loop and in the harness exchange
        self.last_split = (0.0, 0.0)
        #: why the last run ended early: the exception or signal (``None``: it ran to the end)
        self.ended_by: BaseException | None = None
        self._exchanged = False
        self._completed = 0
        #: while :meth:`run` runs (main thread): SIGINT/SIGTERM/SIGHUP are held and raised at the
        #: next tick's start, never inside one
        self._signals: SignalsDeferred | None = None
        #: the plant boundary error that ended the last window after a stop early (``None``: none)
        self.window_ended_by: PlantBoundaryError | None = None
        self._watching = False

    @classmethod
    def from_lanes(cls, runners: Sequence[LockstepRunner], plant: PlantBoundary, loop: ServoLoop) -> LockstepRunner:
        """The runner of B lanes (batched lockstep, :mod:`hal.lanes`): ``plant``, the lanes' plant
        boundary (the lane harness), and ``loop``, the lanes' loop (:meth:`ServoLoop.from_lanes`),
        ticked exactly as one instance is — the tick's calls are the same, on lane objects. Stop
        the run when no lane is live (``run(n, stop=lambda: not lanes.alive.any())``): a lane's
        watchdog trip ejects it and never stops the loop. ``runners``: the lanes' scalar runners,
        which must be alike; after-tick hooks (injected faults, taps) cannot run in lanes."""
        for r in runners:
            if r.after_tick:
                raise NotImplementedError("a run with after-tick hooks (injected faults, taps) cannot run in lanes")
            if (r.period_ns, r.delay_ns) != (runners[0].period_ns, runners[0].delay_ns):
                raise NotImplementedError("lanes' runners differ in period or delay: they cannot run as lanes")
        runner = cls(plant, loop)
        if (runner.period_ns, runner.delay_ns) != (runners[0].period_ns, runners[0].delay_ns):
            raise ValueError("the lane plant's period or delay differs from the lanes' runners'")
        return runner

    def tick(self) -> None:
        signals = self._signals
        if signals is not None and signals.held:
            # a signal that came during the last tick, acted on here, between two ticks: raised in
            # the middle of a driver's cycles it left a board mid-scan, and the stop it started
            # then found the ADC busy (driver_error instead of the signal, under load)
            raise signals.held.pop(0)
        plant = self.plant
        k = self.loop.tick_count
        self._exchanged = False
        clock = time.perf_counter
        t0 = clock()
        plant.advance_to(k * self.period_ns)
        plant.sense(k)
        t1 = clock()
        self.loop.tick(truth=plant.truth())
        t2 = clock()
        # The command takes effect at t_k + delay: let the boards' pending events (a DAC's output
        # settling after its update strobe) run before the exchange reads the command nets.
        plant.advance_to(k * self.period_ns + self.delay_ns)
        self._exchanged = True  # from here on, a failure's stop reaches the plant at the next exchange
        try:
            plant.exchange(k)
        except PlantBoundaryError as e:
            loop = self.loop
            if self._watching and not loop.enabled and loop.stopping is None:
                # the window after a completed stop only watches: a plant that is lost or stale
                # ends it (nothing left to watch); the stop was done, so it adds no fault
                self.window_ended_by = e
                loop.note("servo", f"the watch after the stop ended: {e.cause}: {e}")
            else:
                # A remote plant (CAN node) gave no fresh data, vanished or restarted: the watchdog's
                # answer is a safe stop in this tick; the link then returns held values without waiting.
                loop.safe_stop(e.cause, str(e))
        self.last_split = (t2 - t1, (t1 - t0) + (clock() - t2))
        for cb in self.after_tick:
            cb(self.loop)

    def run(self, n_ticks: int, progress: Progress | None = None, stop: Callable[[], bool] | None = None) -> int:
        """Run up to ``n_ticks`` ticks; returns how many completed. ``stop()`` is asked before
        each tick (True ends the run there, without a fault)."""
        self.ended_by = None
        self._completed = 0
        outer, self._signals = self._signals, SignalsDeferred().begin()
        try:
            try:
                return self._run(n_ticks, progress, stop)
            except INTERRUPTS as e:
                self.loop.note_interruption(e, "run")
                self.stop_by_category("interrupted", f"{interrupt_name(e)} received", e)
            except Exception as e:
                self.stop_now("exception", f"{type(e).__name__}: {e}", e)
            return self._completed
        finally:
            section, self._signals = self._signals, outer
            section.end()
            if section.held:  # came with the run's last tick: an interruption all the same
                late = section.held.pop(0)
                self.loop.note_interruption(late, "run")
                if self.ended_by is None and self.loop.enabled and self.loop.fault is None:
                    self.stop_by_category("interrupted", f"{interrupt_name(late)} received", late)
                self.ended_by = self.ended_by or late

    def stop_by_category(self, cause: str, detail: str, exc: BaseException | None = None) -> None:
        """Stop by ``cause``'s category (:mod:`servo.stops`): a category-1 stop is ticked through
        here (decelerate, brakes, power off — :meth:`finish_stop`); a second signal, or an error,
        while it runs makes it category 0 at once (:meth:`stop_now`)."""
        loop = self.loop
        self.ended_by = exc
        try:
            loop.stop(cause, detail)
        except BaseException:  # the stop itself completed (held signals are raised after it)
            self._carry_to_plant()
            raise
        if loop.stopping is None:  # category 0 (or 2): carried to the plant as before
            if not loop.enabled:
                self._carry_to_plant()
            return
        try:
            self.finish_stop()
        except INTERRUPTS as e:
            loop.note_interruption(e, "stop")
            if loop.stopping is not None:  # a second signal: power off now (category 0)
                self.stop_now(cause, f"{detail}; {interrupt_name(e)} during the category-1 stop", exc)
            else:  # held by the stop's own final section, raised when it was done
                self._carry_to_plant()
        except Exception as e:
            self.stop_now("exception", f"{type(e).__name__}: {e} (during the category-1 stop)", exc)
        self.ended_by = exc

    def finish_stop(self) -> int:
        """Tick until the category-1 stop under way (if any) has completed (its time bound ends
        it); returns the ticks it took."""
        n = 0
        while self.loop.stopping is not None:
            self._pace(n)
            self.tick()
            n += 1
        return n

    def _pace(self, i: int) -> None:
        """Wait for tick ``i`` of a stop (lockstep: no wait)."""

    def end_run(self, seconds: float = WATCH_AFTER_STOP_S, cause: str = "end", detail: str = "the run ended") -> None:
        """The end of a run: a loop still servoing stops by the category of ``cause`` (``end``: 1, decelerate,
        brakes, power off); then, after whatever stop ended the run, :meth:`watch_after_stop`. A
        plant or driver that fails in the window ends it (the stop is done); a signal is raised."""
        loop = self.loop
        loop.run_ticks = loop.tick_count
        if loop.vision is not None:  # where the run left the arm, not where its stop and the 2 s after did
            loop.vision.freeze()
        if loop.fault is None and loop.enabled and loop.stopping is None:
            self.stop_by_category(cause, detail)
        elif loop.stopping is not None:
            self.finish_stop()
        if loop.enabled or loop.stop_category is None:  # nothing stopped
            return
        try:
            self.watch_after_stop(seconds)
        except Exception:  # the window only watches; what failed may be what stopped the run
            pass

    def watch_after_stop(self, seconds: float = 2.0) -> int:
        """After a stop: keep ticking (the loop reads its sensors, the plant keeps stepping with the
        amplifiers as the stop left them) for ``seconds``, so the run can say how far the joints
        moved (:meth:`servo.loop.ServoLoop.stop_summary`); returns the ticks it took. A signal ends
        it at once (raised); a lost or stale plant ends it too (:attr:`window_ended_by`, a note in
        the loop's log; no fault: the stop was done)."""
        n = round(seconds / self.period_s)
        self.window_ended_by = None
        self._watching = True
        try:
            for i in range(n):
                self._pace(i)
                self.tick()
                if self.window_ended_by is not None:
                    return i + 1
        finally:
            self._watching = False
        return n

    def _run(self, n_ticks: int, progress: Progress | None, stop: Callable[[], bool] | None) -> int:
        for i in range(n_ticks):
            if stop is not None and stop():
                return i
            self.tick()
            self._completed = i + 1
            if progress is not None:
                progress(i + 1, n_ticks)
        return n_ticks

    def stop_now(self, cause: str, detail: str, exc: BaseException | None = None) -> None:
        """Safe-stop the loop now and carry the stop to the plant with one more exchange.

        The exchange of the tick that failed is made if it had not happened yet; otherwise the
        next tick's. Errors while carrying the stop over are ignored: the drivers have already
        disabled the amplifiers and zeroed the DACs (and read it back) in :meth:`ServoLoop.safe_stop`.
        A signal that the stop held is raised after the exchange.
        """
        self.ended_by = exc
        try:
            self.loop.safe_stop(cause, detail)
        finally:
            self._carry_to_plant()

    def _carry_to_plant(self) -> None:
        """One more exchange, so that the plant sees the amplifiers as the stop left them."""
        k = self.loop.tick_count
        if self._exchanged:
            k += 1
        try:
            self.plant.advance_to(k * self.period_ns + self.delay_ns)
            self.plant.exchange(k)
        except Exception:  # the stop itself is done; the plant may be what failed
            pass
        self._exchanged = True


OVERRUN_POLICIES = ("stop", "warn")


class RealtimeRunner(LockstepRunner):
    """Paced by the wall clock at the rig's servo rate with absolute deadlines."""

    def __init__(self, plant: PlantBoundary, loop: ServoLoop, *, spin_s: float = 0.0005,
                 clock: Callable[[], float] = time.perf_counter,
                 sleep: Callable[[float], None] = time.sleep,
                 overrun: str = "stop", max_lateness_periods: float = 5.0,
                 rt_priority: int | None = None, lock_memory: bool = False,
                 cpus: list[int] | None = None) -> None:
        super().__init__(plant, loop)
        if overrun not in OVERRUN_POLICIES:
            raise ValueError(f"overrun policy {overrun!r}: expected one of {', '.join(OVERRUN_POLICIES)}")
        if not max_lateness_periods > 0 or max_lateness_periods == float("inf"):
            raise ValueError(f"max_lateness_periods {max_lateness_periods!r}: expected a finite number > 0")
        self.overrun = overrun
        self.max_lateness_periods = float(max_lateness_periods)
        #: ticks that started more than ``max_lateness_periods`` late (counted under "warn")
        self.late_ticks = 0
        self.spin_s = spin_s
        self.clock = clock
        self.sleep = sleep
        self.timing = TimingStats()
        self.gc_slack_s = 0.003  #: collect young objects only when the next deadline is this far
        #: real-time settings for the run (:func:`servo.rt.apply_realtime`; all off by default):
        #: applied when :meth:`run` starts, restored when it ends
        if rt_priority is not None:
            check_rt_priority(rt_priority)  # at construction, not when the run starts
        self.rt_priority, self.lock_memory, self.cpus = rt_priority, lock_memory, cpus
        #: what the last run applied and was refused (None: nothing was asked)
        self.rt_settings: RealtimeSettings | None = None

    def run(self, n_ticks: int, progress: Progress | None = None, stop: Callable[[], bool] | None = None) -> int:
        # Python's cyclic garbage collector can pause a tick for ~10 ms. During the run it is
        # switched off; what exists at the start is frozen out of it, and young objects are
        # collected in the slack after a tick, only when the next deadline is comfortably away.
        gc_was_enabled = gc.isenabled()
        gc.collect()
        gc.freeze()
        gc.disable()
        rt = None
        try:
            if self.rt_priority is not None or self.lock_memory or self.cpus is not None:
                rt = self.rt_settings = apply_realtime(self.rt_priority, self.lock_memory, self.cpus)
            return super().run(n_ticks, progress, stop)
        finally:
            if rt is not None:
                rt.restore()
            self.overruns = self.timing.overruns
            gc.unfreeze()
            if gc_was_enabled:
                gc.enable()

    def _run(self, n_ticks: int, progress: Progress | None, stop: Callable[[], bool] | None) -> int:
        t0 = self.clock() + self.period_s
        for i in range(n_ticks):
            if stop is not None and stop():
                return i
            deadline = t0 + i * self.period_s
            if deadline - self.clock() > self.gc_slack_s:
                gc.collect(0)
            self._wait_until(deadline)
            woke = self.clock()
            behind = (woke - deadline) / self.period_s
            if behind > self.max_lateness_periods and self.loop.fault is None and self.loop.stopping is None:
                self.late_ticks += 1
                if self.overrun == "stop":
                    # the sensors are sane: category 1 (decelerate, brakes, power off) — servo.stops
                    self.stop_by_category("overrun", f"the loop fell {behind:.1f} periods behind its deadline "
                                          f"(limit {self.max_lateness_periods:g}; --overrun warn runs on)")
                    return i
            switches, cpu0 = involuntary_switches(), time.thread_time()
            self.tick()
            cpu = time.thread_time() - cpu0
            preempted = involuntary_switches() != switches
            self._completed = i + 1
            done = self.clock()
            self.timing.compute_s.append(done - woke)
            self.timing.compute_cpu_s.append(cpu)
            self.timing.preempted += preempted
            self.timing.lateness_s.append(max(0.0, woke - deadline))
            self.timing.controller_s.append(self.last_split[0])
            self.timing.harness_s.append(self.last_split[1])
            if done > deadline + self.period_s:
                self.timing.overruns += 1
                self.timing.overruns_preempted += preempted
            if progress is not None:
                progress(i + 1, n_ticks)
        return n_ticks

    def _pace(self, i: int) -> None:
        if i == 0:
            self._pace_t0 = self.clock()
        self._wait_until(self._pace_t0 + i * self.period_s)

    def _wait_until(self, deadline: float) -> None:
        wait_until(deadline, self.clock, self.sleep, self.spin_s)
