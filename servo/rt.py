"""Real-time settings of the process running a paced loop, applied only when asked, and what the
machine itself does to a fixed amount of work (its own jitter).

:func:`apply_realtime` tries each setting it is given and records what the operating system
allowed and what it refused (with its reason) — nothing is assumed: a ``SCHED_FIFO`` priority
needs ``CAP_SYS_NICE`` (or an ``RLIMIT_RTPRIO``), locking memory needs ``CAP_IPC_LOCK`` or a
large enough ``RLIMIT_MEMLOCK``. :meth:`RealtimeSettings.restore` puts the scheduler, the memory
lock and the CPU affinity back as they were. None of these touch the rig: they change only when
and where this process runs.

:func:`machine_probe` runs a fixed pure-Python workload at the servo rate with the same pacing
as :class:`servo.runner.RealtimeRunner` and records its wall time, its thread CPU time and the
involuntary context switches per tick: on an idle machine the workload's p99 is close to its
p50; what it is not is the machine's (other processes, the hypervisor taking the virtual CPU),
the same-run baseline for the servo loop's own p99.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

try:  # Linux/BSD; elsewhere the involuntary switches are not counted (0)
    import resource

    def involuntary_switches() -> int:
        """Involuntary context switches of the calling thread so far (Linux: RUSAGE_THREAD)."""
        return resource.getrusage(getattr(resource, "RUSAGE_THREAD", resource.RUSAGE_SELF)).ru_nivcsw
except ImportError:  # pragma: no cover - not on this platform
    def involuntary_switches() -> int:
        return 0

_MCL_CURRENT, _MCL_FUTURE = 1, 2


def wait_until(deadline: float, clock: Callable[[], float] = time.perf_counter,
               sleep: Callable[[float], None] = time.sleep, spin_s: float = 0.0005) -> None:
    """Sleep until ``spin_s`` before ``deadline`` (seconds of ``clock``), then spin to it: the
    pacing of :class:`servo.runner.RealtimeRunner`."""
    remaining = deadline - clock()
    if remaining > spin_s:
        sleep(remaining - spin_s)
    while clock() < deadline:
        pass


def steal_seconds() -> float:
    """The machine's steal time so far (s, all CPUs; ``/proc/stat``): time the hypervisor ran
    something else while this virtual machine wanted a CPU. NaN where it is not reported."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return math.nan


@dataclass
class RealtimeSettings:
    """What :func:`apply_realtime` changed (``applied``) and what it was refused (``refused``:
    setting → the reason), with what :meth:`restore` needs."""

    applied: list[str] = field(default_factory=list)
    refused: dict[str, str] = field(default_factory=dict)
    _sched: tuple[int, int] | None = None
    _affinity: set[int] | None = None
    _locked: bool = False

    def describe(self) -> str:
        parts = [*self.applied, *(f"{k} refused ({v})" for k, v in self.refused.items())]
        return "; ".join(parts) if parts else "none"

    def restore(self) -> None:
        """Put back the scheduling policy, the CPU affinity and the memory lock as they were."""
        if self._sched is not None:
            policy, prio = self._sched
            try:
                os.sched_setscheduler(0, policy, os.sched_param(prio))
            except OSError:
                pass
            self._sched = None
        if self._affinity is not None:
            try:
                os.sched_setaffinity(0, self._affinity)
            except OSError:
                pass
            self._affinity = None
        if self._locked:
            _libc_call("munlockall")
            self._locked = False


def _libc_call(name: str, *args: int) -> str | None:
    """Call ``name`` in the C library; ``None`` on success, else the reason."""
    path = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(path, use_errno=True)
        fn = getattr(libc, name)
    except (OSError, AttributeError) as e:
        return f"no {name} here: {e}"
    if fn(*args) != 0:
        err = ctypes.get_errno()
        return f"{os.strerror(err)} (errno {err})"
    return None


def check_rt_priority(priority: int) -> None:
    """Refuse a ``SCHED_FIFO`` priority outside 1..99 (ValueError)."""
    if not 1 <= int(priority) <= 99:
        raise ValueError(f"real-time priority {priority!r}: expected 1..99 (SCHED_FIFO)")


def apply_realtime(priority: int | None = None, lock_memory: bool = False,
                   cpus: Sequence[int] | None = None) -> RealtimeSettings:
    """Apply the real-time settings asked for to this process (its calling thread's policy):

    * ``priority`` (1..99): ``SCHED_FIFO`` at that priority — the loop is no longer preempted by
      ordinary processes (it still sleeps between ticks, so they run then);
    * ``lock_memory``: ``mlockall(MCL_CURRENT | MCL_FUTURE)`` — no page faults inside a tick;
    * ``cpus``: the CPU affinity.

    Each refused setting is recorded with its reason (``refused``); the run goes on without it."""
    out = RealtimeSettings()
    if priority is not None:
        check_rt_priority(priority)
        if not hasattr(os, "sched_setscheduler"):
            out.refused["SCHED_FIFO"] = "not supported on this platform"
        else:
            before = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority)))
                out._sched = before
                out.applied.append(f"SCHED_FIFO priority {int(priority)}")
            except OSError as e:
                out.refused["SCHED_FIFO"] = f"{e.strerror} (needs CAP_SYS_NICE or RLIMIT_RTPRIO)"
    if lock_memory:
        why = _libc_call("mlockall", _MCL_CURRENT | _MCL_FUTURE)
        if why is None:
            out._locked = True
            out.applied.append("mlockall")
        else:
            out.refused["mlockall"] = f"{why} (needs CAP_IPC_LOCK or a large RLIMIT_MEMLOCK)"
    if cpus is not None:
        if not hasattr(os, "sched_setaffinity"):
            out.refused["affinity"] = "not supported on this platform"
        else:
            before_cpus = os.sched_getaffinity(0)
            try:
                os.sched_setaffinity(0, set(cpus))
                out._affinity = before_cpus
                out.applied.append(f"CPUs {sorted(set(cpus))}")
            except (OSError, ValueError) as e:
                out.refused["affinity"] = str(e)
    return out


def _work(n: int) -> float:
    """A fixed pure-Python workload: ``n`` rounds of float arithmetic and a list (bytecode,
    allocation and calls, like a servo tick's Python)."""
    acc = 0.0
    for i in range(n):
        x = [i * 0.5, i * 0.25]
        acc += math.sqrt(x[0] * x[0] + x[1]) - acc * 1e-9
    return acc


def calibrate_work(target_s: float = 0.001) -> int:
    """Rounds of :func:`_work` that take about ``target_s`` of thread CPU time (the fastest of
    several trials: what the workload costs when nothing interferes)."""
    n = 1000
    while True:
        best = math.inf
        for _ in range(5):
            t = time.thread_time()
            _work(n)
            best = min(best, time.thread_time() - t)
        if best >= target_s / 4 or n > 10**7:
            return max(1, round(n * target_s / best))
        n *= 4


def machine_probe(seconds: float, period_s: float = 0.008, work_s: float = 0.001,
                  spin_s: float = 0.0005) -> dict[str, float | int]:
    """The machine's own jitter: :func:`_work` sized to ``work_s`` run once per ``period_s`` for
    ``seconds``, paced as the real-time runner paces its ticks (absolute deadlines, sleep then
    spin). Returns the workload's wall and thread-CPU p50/p99/max (ms), ``p99_over_p50`` (wall),
    the ticks with an involuntary context switch, the ticks over ``period_s``, and the steal time
    and involuntary switches of the whole probe."""
    n_work = calibrate_work(work_s)
    n = max(1, round(seconds / period_s))
    wall = np.empty(n)
    cpu = np.empty(n)
    switched = 0
    clock = time.perf_counter
    steal0, sw_total0 = steal_seconds(), involuntary_switches()
    t0 = clock() + period_s
    for i in range(n):
        wait_until(t0 + i * period_s, clock, time.sleep, spin_s)
        s0, c0, w0 = involuntary_switches(), time.thread_time(), clock()
        _work(n_work)
        w1, c1 = clock(), time.thread_time()
        wall[i], cpu[i] = w1 - w0, c1 - c0
        switched += involuntary_switches() != s0
    p50, p99 = float(np.percentile(wall, 50)), float(np.percentile(wall, 99))
    return {
        "ticks": n, "work_rounds": n_work,
        "wall_p50_ms": p50 * 1e3, "wall_p99_ms": p99 * 1e3, "wall_max_ms": float(wall.max()) * 1e3,
        "cpu_p50_ms": float(np.percentile(cpu, 50)) * 1e3, "cpu_p99_ms": float(np.percentile(cpu, 99)) * 1e3,
        "cpu_max_ms": float(cpu.max()) * 1e3, "p99_over_p50": p99 / p50 if p50 > 0 else math.nan,
        "ticks_switched": switched, "ticks_over_period": int(np.count_nonzero(wall > period_s)),
        "steal_s": steal_seconds() - steal0, "involuntary_switches": involuntary_switches() - sw_total0,
    }
