"""Worker processes for the tools' full-stack runs: :func:`run_parallel` (the sweep's points,
``limit-cycle``'s and ``step``'s two runs). Forked workers ignore SIGINT and poll a shared stop
event instead (:func:`stop_requested`), so that Ctrl-C in the parent ends every run through its
own safe stop."""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, wait
from typing import Any

_STOP: Any = None  # a multiprocessing.Event in workers (set by the pool initializer)


def _worker_init(stop_event: Any) -> None:
    """Pool initializer: the parent handles SIGINT; workers watch ``stop_event`` instead."""
    global _STOP
    _STOP = stop_event
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class ParallelInterrupted(Exception):
    """:func:`run_parallel` was interrupted; ``done`` maps item positions to finished results."""

    def __init__(self, done: dict[int, Any]) -> None:
        super().__init__(f"interrupted after {len(done)} result(s)")
        self.done = done


def stop_requested() -> Callable[[], bool] | None:
    """In a :func:`run_parallel` worker: a ``stop()`` poll for a runner (True once the parent was
    interrupted); None elsewhere."""
    stop_event = _STOP
    return None if stop_event is None else stop_event.is_set


def run_parallel(fn: Callable[[Any], Any], items: list[Any], *, executor: Executor | None = None,
                 jobs: int | None = None, on_result: Callable[[int, Any], None] | None = None,
                 finished: Callable[[Any], bool] = lambda result: True) -> list[Any]:
    """``fn(item)`` for every item in worker processes; the results in item order.

    ``fn`` is a top-level (picklable) function; a long one polls :func:`stop_requested` (every
    tick: a runner's ``stop``) and returns early once it is set, leaving its rig safe-stopped as any
    run does. ``executor``: any :class:`concurrent.futures.Executor` (the caller owns and shuts it
    down; it is not sent the stop event, so an interruption only cancels what has not started).
    Default: a process pool of ``jobs`` workers (default ``os.cpu_count()``, at most one per item),
    forked, so a worker starts with the parent's imports. ``on_result(position, result)`` is called
    in the calling thread as each completes, in completion order; a result ``finished`` says is not
    (it was cut short by an interruption) is neither passed on nor kept. SIGINT in the calling
    thread sets the workers' stop event, cancels what has not started and raises
    :class:`ParallelInterrupted` with the finished results.
    """
    done: dict[int, Any] = {}
    own = executor is None
    stop_event = None
    if executor is None:
        n = max(1, min(jobs or os.cpu_count() or 1, len(items) or 1))
        ctx = multiprocessing.get_context("spawn" if os.name == "nt" else "fork")
        stop_event = ctx.Event()
        executor = ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_worker_init,
                                       initargs=(stop_event,))
    futures: dict[Future, int] = {}
    # SIGINT sets a flag that the loop below checks between completions, instead of raising
    # KeyboardInterrupt wherever the main thread happens to be (inside a file write, the progress
    # bar or the executor's internals), where it could be lost.
    sigint = threading.Event()
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, lambda signum, frame: sigint.set())
    try:
        futures = {executor.submit(fn, item): i for i, item in enumerate(items)}
        pending = set(futures)
        while pending and not sigint.is_set():
            completed, pending = wait(pending, timeout=0.1, return_when=FIRST_COMPLETED)
            for fut in sorted(completed, key=lambda f: futures[f]):
                result = fut.result()
                if not finished(result):
                    continue
                done[futures[fut]] = result
                if on_result is not None:
                    on_result(futures[fut], result)
        if sigint.is_set():
            raise KeyboardInterrupt
    except KeyboardInterrupt:
        if stop_event is not None:
            stop_event.set()
        for f in futures:
            f.cancel()
        raise ParallelInterrupted(done) from None
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        if own:
            executor.shutdown(wait=True, cancel_futures=True)
    return [done.get(i) for i in range(len(items))]  # None: cut short (a caller's executor only)
