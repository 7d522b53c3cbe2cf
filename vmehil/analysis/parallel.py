"""Where the tools' full-stack runs execute: :func:`run_parallel` (the sweep's points,
``limit-cycle``'s and ``step``'s two runs) over an :class:`Engine`.

Two engines share one loop (submission, completion order, de-duplication, SIGINT):

* :class:`LocalEngine` — a process pool on this machine (the default). Forked workers ignore
  SIGINT and poll a shared stop event instead (:func:`stop_requested`), so that Ctrl-C in the
  parent ends every run through its own safe stop. A worker watches its parent: when the parent
  is gone (SIGKILL), it stops its run the same way and exits (:func:`_watch_parent`).

Signals: while :func:`run_parallel` runs — through the interruption and the engine's shutdown —
SIGINT, SIGTERM and SIGHUP only set a flag: the first ends the loop, tells the tasks to stop and
closes the engine, then raises (:class:`ParallelInterrupted` for SIGINT,
:class:`servo.interrupts.Terminated` for the others). A second signal cannot land inside the
pool's shutdown (that hung the sweep, its workers left as zombies): the workers are already
stopping (each at its next tick). A third one makes the engine kill its workers (``abort``)
instead of waiting for them (a worker stuck where it does not poll its stop).
* :class:`vmehil.analysis.dask_engine.DaskEngine` — Dask's ``distributed``: a LocalCluster on
  127.0.0.1 or a cluster's scheduler (``vmehil tune sweep --engine dask``, docs/sweeps.md). Its
  tasks poll a Dask ``Event`` through the same :func:`stop_requested`.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from contextlib import contextmanager
from typing import Any, Protocol

from servo.interrupts import Terminated
from vmehil.errors import VmehilError

_STOP: Any = None  # a multiprocessing.Event in workers (set by the pool initializer)
_TASK = threading.local()  # .stop: the stop poll of the task running in this thread (an engine's wrapper)
_BUSY = threading.Event()  # in a pool worker: set while a task runs
PARENT_POLL_S = 0.2  #: how often a pool worker checks that its parent is alive
ORPHAN_GRACE_S = 10.0  #: an orphaned worker's task gets this long to stop through its safe stop
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
ABORT_AFTER_SIGNALS = 3  #: the signal that kills the local pool's workers instead of waiting for them


def _worker_init(stop_event: Any, parent_pid: int | None = None) -> None:
    """Pool initializer: the parent handles SIGINT; workers watch ``stop_event`` instead. SIGTERM
    and SIGHUP raise :class:`~servo.interrupts.Terminated` (the handler forked from the parent
    only set the parent's flag); a thread watches the parent (:func:`_watch_parent`)."""
    global _STOP
    _STOP = stop_event
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for s in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, _raise_terminated)
    if parent_pid is not None:
        threading.Thread(target=_watch_parent, args=(parent_pid, stop_event), name="vmehil-parent-watch",
                         daemon=True).start()


def _raise_terminated(signum: int, frame: Any) -> None:
    raise Terminated(signum)


def _watch_parent(parent_pid: int, stop_event: Any) -> None:
    """In a pool worker: once the parent is gone (its pid is no longer our parent's: killed with
    SIGKILL), set the stop event (the running task ends through its own safe stop at its next
    tick), give it :data:`ORPHAN_GRACE_S`, and exit. Without this the workers of a SIGKILLed sweep
    waited for work forever."""
    while os.getppid() == parent_pid:
        time.sleep(PARENT_POLL_S)
    stop_event.set()
    deadline = time.monotonic() + ORPHAN_GRACE_S
    while _BUSY.is_set() and time.monotonic() < deadline:
        time.sleep(0.05)
    os._exit(0)


def _run_in_worker(fn: Callable[[Any], Any], item: Any) -> Any:
    """A pool task: ``fn(item)``, marked busy for :func:`_watch_parent`."""
    _BUSY.set()
    try:
        return fn(item)
    finally:
        _BUSY.clear()


class ParallelInterrupted(VmehilError):
    """:func:`run_parallel` was interrupted; ``done`` maps item positions to finished results."""

    def __init__(self, done: dict[int, Any]) -> None:
        super().__init__(f"interrupted after {len(done)} result(s)")
        self.done = done


class EngineError(VmehilError, RuntimeError):
    """An engine could not start or refused its workers (e.g. a mixed-version cluster)."""


class TaskFailed:
    """What an engine's :meth:`Engine.completed` reports for a task that raised, in place of its
    result, so that the other results of the same batch are not lost: :func:`run_parallel` hands
    those on first, then raises ``error``."""

    def __init__(self, error: BaseException) -> None:
        self.error = error

    def __repr__(self) -> str:
        return f"TaskFailed({self.error!r})"


def stop_requested() -> Callable[[], bool] | None:
    """In a :func:`run_parallel` task: a ``stop()`` poll for a runner (True once the parent was
    interrupted); None elsewhere."""
    task_stop = getattr(_TASK, "stop", None)
    if task_stop is not None:
        return task_stop
    stop_event = _STOP
    return None if stop_event is None else stop_event.is_set


@contextmanager
def task_stop(poll: Callable[[], bool]) -> Iterator[None]:
    """While a task runs in this thread, :func:`stop_requested` returns ``poll`` (an engine's
    task wrapper sets it: Dask runs tasks in worker threads, not in pool processes)."""
    previous = getattr(_TASK, "stop", None)
    _TASK.stop = poll
    try:
        yield
    finally:
        _TASK.stop = previous


class Engine(Protocol):
    """Where :func:`run_parallel` runs its tasks. ``start`` submits every item; ``completed``
    waits up to ``timeout`` s and returns the ``(position, result)`` pairs finished since the last
    call (an engine may return a position twice, e.g. a retried task: :func:`run_parallel` keeps
    the first; a task that raised is a :class:`TaskFailed`);
    ``interrupt`` tells running tasks to stop (:func:`stop_requested`) and cancels the
    rest; ``close`` releases what the engine started."""

    name: str

    def start(self, fn: Callable[[Any], Any], items: list[Any]) -> None: ...
    def pending(self) -> int: ...
    def completed(self, timeout: float) -> list[tuple[int, Any]]: ...
    def interrupt(self) -> None: ...
    def close(self) -> None: ...


class LocalEngine:
    """A process pool of ``jobs`` workers on this machine (default ``os.cpu_count()``, at most one
    per item), forked, so a worker starts with the parent's imports; or a caller's ``executor``
    (any :class:`concurrent.futures.Executor`: the caller owns and shuts it down; it is not sent
    the stop event, so an interruption only cancels what has not started)."""

    name = "local"

    def __init__(self, jobs: int | None = None, executor: Executor | None = None) -> None:
        self.jobs = jobs
        self._executor = executor
        self._own = executor is None
        self._stop_event: Any = None
        self._futures: dict[Future, int] = {}
        self._pending: set[Future] = set()

    def start(self, fn: Callable[[Any], Any], items: list[Any]) -> None:
        if self._executor is None:
            n = max(1, min(self.jobs or os.cpu_count() or 1, len(items) or 1))
            ctx = multiprocessing.get_context("spawn" if os.name == "nt" else "fork")
            self._stop_event = ctx.Event()
            self._executor = ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_worker_init,
                                                 initargs=(self._stop_event, os.getpid()))
        task = _run_in_worker if self._own else None
        self._futures = {(self._executor.submit(task, fn, item) if task else self._executor.submit(fn, item)): i
                         for i, item in enumerate(items)}
        self._pending = set(self._futures)

    def pending(self) -> int:
        return len(self._pending)

    def completed(self, timeout: float) -> list[tuple[int, Any]]:
        done, self._pending = wait(self._pending, timeout=timeout, return_when=FIRST_COMPLETED)
        return [(self._futures[f], _outcome(f)) for f in sorted(done, key=lambda f: self._futures[f])]

    def interrupt(self) -> None:
        if self._stop_event is not None:
            self._stop_event.set()
        for f in self._futures:
            f.cancel()

    def close(self) -> None:
        if self._own and self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)

    def abort(self) -> None:
        """Kill this engine's own workers now instead of waiting for them to stop (a third signal:
        a worker stuck where it does not poll its stop). Their rigs are emulated, in their memory."""
        if not self._own or self._executor is None:
            return
        # the pool's processes (a private attribute since 3.2; nothing public lists them)
        for p in list((getattr(self._executor, "_processes", None) or {}).values()):
            with contextlib.suppress(OSError, ValueError, AttributeError):
                p.kill()


def _outcome(f: Future) -> Any:
    """A finished future's result, or :class:`TaskFailed` with its exception."""
    error = f.exception() if not f.cancelled() else None
    return f.result() if error is None else TaskFailed(error)


def run_parallel(fn: Callable[[Any], Any], items: list[Any], *, executor: Executor | None = None,
                 jobs: int | None = None, engine: Engine | None = None,
                 on_result: Callable[[int, Any], None] | None = None,
                 finished: Callable[[Any], bool] = lambda result: True,
                 meanwhile: Callable[[], None] | None = None,
                 on_idle: Callable[[], None] | None = None) -> list[Any]:
    """``fn(item)`` for every item on ``engine``; the results in item order.

    ``fn`` is a top-level (picklable) function; a long one polls :func:`stop_requested` (every
    tick: a runner's ``stop``) and returns early once it is set, leaving its rig safe-stopped as any
    run does. ``engine``: default a :class:`LocalEngine` of ``jobs`` workers (or over ``executor``);
    :func:`run_parallel` closes it. ``on_result(position, result)`` is called in the calling thread
    as each completes, in completion order, once per position (an engine that reports a position
    again, e.g. after a retry, is not counted twice); a result ``finished`` says is not (it was cut
    short by an interruption) is neither passed on nor kept. SIGINT in the calling thread tells the
    tasks to stop, cancels what has not started, closes the engine and raises
    :class:`ParallelInterrupted` with the finished results (SIGTERM, SIGHUP: the same, then
    :class:`~servo.interrupts.Terminated`); any further signal ends the engine's workers instead
    of interrupting its shutdown (module docstring). ``meanwhile()``: work of the calling process
    done while the engine runs the items (``tune limit-cycle``'s prediction beside its two runs); a
    SIGINT during it is acted on when it returns. ``on_idle()`` is called in the calling thread
    after every wait for results (at least every 0.1 s while tasks run), e.g. to write batched
    results. Any exception (from
    ``meanwhile``, ``on_result``, a task or the engine) tells the running tasks to stop before it
    propagates, so none runs on unattended; a task's exception or ``on_result``'s is raised after
    every other result of the same batch was handed on (none finished is lost).
    """
    if engine is None:
        engine = LocalEngine(jobs=jobs, executor=executor)
    done: dict[int, Any] = {}
    # SIGINT, SIGTERM and SIGHUP set a flag that the loop below checks between completions,
    # instead of raising wherever the main thread happens to be (inside a file write, the progress
    # bar, the engine's internals or its shutdown), where it could be lost or hang the pool. They
    # stay so until the engine is closed; a second one ends the engine's workers (abort).
    signals: list[int] = []

    def on_signal(signum: int, frame: Any) -> None:
        signals.append(signum)
        abort = getattr(engine, "abort", None)
        if abort is not None and len(signals) >= ABORT_AFTER_SIGNALS:
            abort()

    previous: dict[int, Any] = {}
    if threading.current_thread() is threading.main_thread():
        previous = {s: signal.signal(s, on_signal) for s in STOP_SIGNALS}
    try:
        engine.start(fn, items)
        if meanwhile is not None:
            meanwhile()
        while engine.pending() and not signals:
            errors: list[BaseException] = []
            for position, result in engine.completed(timeout=0.1):
                if isinstance(result, TaskFailed):
                    errors.append(result.error)
                    continue
                if position in done or not finished(result):
                    continue
                try:
                    if on_result is not None:
                        on_result(position, result)
                except Exception as e:  # refused: the rest of the batch is still handed on
                    errors.append(e)
                    continue
                done[position] = result
            if on_idle is not None:
                on_idle()
            if errors and not signals:  # once interrupted, a task that died with its pool is no error
                raise errors[0]
        if signals:
            raise KeyboardInterrupt
    except KeyboardInterrupt:
        engine.interrupt()
        if signals and signals[0] != signal.SIGINT:
            raise Terminated(signals[0]) from None
        raise ParallelInterrupted(done) from None
    except BaseException:
        engine.interrupt()
        raise
    finally:
        try:
            engine.close()
        finally:
            for s, h in previous.items():
                signal.signal(s, h)
    return [done.get(i) for i in range(len(items))]  # None: cut short (a caller's executor only)
