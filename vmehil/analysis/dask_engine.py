"""The Dask engine of :func:`vmehil.analysis.parallel.run_parallel` (``--engine dask``).

Without a scheduler address it starts a ``distributed.LocalCluster`` of ``jobs`` single-threaded
worker processes on 127.0.0.1 (scheduler, workers and nannies bind there; no dashboard); with one
(``tcp://HOST:PORT``) it connects a ``distributed.Client`` to that cluster. Everything travels by
Dask's own means: ``client.submit`` (one future per item, keyed by its position, ``retries``),
``as_completed``, and a Dask ``Event`` that the tasks poll (every :data:`STOP_POLL_S`) through
:func:`~vmehil.analysis.parallel.stop_requested`, so an interrupted sweep ends every running
simulation through its own safe stop. A worker that dies mid-task is Dask's business: the
scheduler hands its tasks to another worker; ``retries`` covers a task that raised (e.g. its
worker was shutting down). The caller counts each position once.

A mixed cluster is refused: :func:`code_identity` (the installed vmehil version and a SHA-256 of
the source of hal, emulators, servo and vmehil, so two development trees at the same version but
different code are told apart too) is compared with every worker's on connection
(``client.run``), and again by every task on the worker that runs it (a worker that joined later).
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import logging
import os
import time
import uuid
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vmehil.analysis.parallel import EngineError, task_stop

RETRIES = 2  #: re-runs of a task that raised (a lost worker's tasks are re-scheduled by Dask anyway)
STOP_POLL_S = 0.5  #: how often a running task asks the scheduler whether the sweep was interrupted
CONNECT_TIMEOUT_S = 30.0  #: connecting to a scheduler, and waiting for its first worker
INTERRUPT_WAIT_S = 60.0  #: after an interruption, how long the running tasks get to stop safely
PACKAGES = ("hal", "emulators", "servo", "vmehil")
SOURCE_SUFFIXES = (".py", ".toml", ".dbc")


@functools.cache
def code_identity() -> dict[str, str]:
    """What must match between the client and every worker: ``version`` (the installed
    distribution's) and ``source_sha256`` (every ``.py``/``.toml``/``.dbc`` of our packages, by
    relative path and content; caches and compiled files are left out)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        ver = version("vmehil")
    except PackageNotFoundError:
        ver = "not installed"
    h = hashlib.sha256()
    for pkg in PACKAGES:
        root = Path(importlib.import_module(pkg).__file__ or "").parent
        for f in sorted(p for p in root.rglob("*") if p.suffix in SOURCE_SUFFIXES and "__pycache__" not in p.parts):
            h.update(f"{pkg}/{f.relative_to(root).as_posix()}\0".encode())
            h.update(f.read_bytes())
            h.update(b"\0")
    return {"version": ver, "source_sha256": h.hexdigest()}


def _identity_text(ident: dict[str, str]) -> str:
    return f"vmehil {ident['version']} (source {ident['source_sha256'][:12]})"


def _run_task(fn: Callable[[Any], Any], item: Any, stop_name: str, identity: dict[str, str]) -> Any:
    """On a worker: refuse to run other code than the client's, then ``fn(item)`` with the stop
    poll of this sweep (None without running when the sweep was interrupted before it started)."""
    mine = code_identity()
    if mine != identity:
        raise EngineError(f"worker runs {_identity_text(mine)}, the client {_identity_text(identity)}: "
                          "install the same vmehil on every worker")
    from distributed import Event, get_client

    event = Event(stop_name, client=get_client())
    asked_at = [-float("inf")]
    stopped = [False]

    def stop() -> bool:  # a runner calls this every tick: ask the scheduler at most every STOP_POLL_S
        now = time.monotonic()
        if not stopped[0] and now - asked_at[0] >= STOP_POLL_S:
            asked_at[0] = now
            stopped[0] = bool(event.is_set())
        return stopped[0]

    if stop():
        return None
    with task_stop(stop):
        return fn(item)


def _ignore_sigint() -> bool:
    """On a LocalCluster worker: leave Ctrl-C to the client (a terminal sends SIGINT to the whole
    process group), which stops the tasks through the sweep's stop event, as the local pool's
    workers do. False where the worker's event loop is not its main thread (nothing changed)."""
    import signal

    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:
        return False
    return True


def check_workers(client: Any) -> dict[str, dict[str, str]]:
    """Every worker's :func:`code_identity`; :class:`EngineError` naming the workers that differ
    from this client (or cannot import vmehil)."""
    mine = code_identity()
    try:
        theirs: dict[str, dict[str, str]] = client.run(code_identity)
    except Exception as e:  # a worker without vmehil cannot even unpickle the function
        raise EngineError(f"a worker cannot run vmehil's identity check ({type(e).__name__}: {e}); "
                          f"install {_identity_text(mine)} on every worker") from None
    bad = {addr: ident for addr, ident in theirs.items() if ident != mine}
    if bad:
        listed = "; ".join(f"{addr}: {_identity_text(i)}" for addr, i in sorted(bad.items()))
        raise EngineError(f"refusing a mixed cluster: this client runs {_identity_text(mine)}, but {listed}. "
                          "Install the same vmehil (same source) on every worker")
    return theirs


class ExposedClusterWarning(UserWarning):
    """The Dask cluster vmehil connected to listens on more than loopback (docs/sweeps.md)."""


def _listening_sockets() -> list[str]:
    """``host:port`` of every socket this process listens on (run in the scheduler or a worker)."""
    import psutil

    proc = psutil.Process()
    conns = proc.net_connections(kind="inet") if hasattr(proc, "net_connections") else proc.connections(kind="inet")
    return [f"{c.laddr.ip}:{c.laddr.port}" for c in conns if c.status == psutil.CONN_LISTEN]


def beyond_loopback(addresses: list[str]) -> list[str]:
    """The ``host:port`` addresses whose host is not loopback (127.0.0.0/8, ::1); 0.0.0.0 and ::
    (every interface) are beyond it."""
    import ipaddress

    out = []
    for a in addresses:
        host = a.rsplit(":", 1)[0].strip("[]")
        try:
            if ipaddress.ip_address(host).is_loopback:
                continue
        except ValueError:
            pass  # a name, not an address: cannot tell, so say it
        out.append(a)
    return out


def cluster_exposure(client: Any) -> dict[str, list[str]]:
    """Where the cluster behind ``client`` listens beyond loopback: ``{"scheduler": [...],
    "<worker address>": [...]}`` (empty: loopback only, or it could not tell — the scheduler or a
    worker could not run the check)."""
    try:
        found = {"scheduler": client.run_on_scheduler(_listening_sockets), **client.run(_listening_sockets)}
    except Exception:  # an old or locked-down cluster: nothing to say rather than a false alarm
        return {}
    return {where: wide for where, socks in found.items() if (wide := beyond_loopback(list(socks)))}


def warn_if_exposed(client: Any, address: str) -> None:
    """An :class:`ExposedClusterWarning` when the cluster listens beyond loopback: anyone who can
    reach those ports can run code on it (a Dask cluster has no authentication by default)."""
    exposed = cluster_exposure(client)
    if exposed:
        where = "; ".join(f"{who} on {', '.join(socks)}" for who, socks in sorted(exposed.items()))
        warnings.warn(f"the Dask cluster at {address} listens beyond loopback ({where}): anyone who reaches "
                      "those ports can run code on it; docs/sweeps.md has a loopback-only recipe",
                      ExposedClusterWarning, stacklevel=3)


class DaskEngine:
    """Dask ``distributed``: a LocalCluster of ``jobs`` workers on 127.0.0.1 (default one per core)
    or, with ``scheduler`` (``tcp://HOST:PORT``), that cluster's workers."""

    name = "dask"

    def __init__(self, scheduler: str | None = None, jobs: int | None = None, *, retries: int = RETRIES) -> None:
        self.scheduler = scheduler
        self.jobs = jobs
        self.retries = retries
        self.client: Any = None
        self.cluster: Any = None
        self.workers: dict[str, dict[str, str]] = {}
        self._futures: dict[str, Any] = {}  # key -> future, not yet reported
        self._position: dict[str, int] = {}
        self._completed: Any = None
        self._stop: Any = None

    def describe(self) -> str:
        where = self.scheduler or (self.cluster.scheduler_address if self.cluster is not None else "LocalCluster")
        return f"dask at {where}, {len(self.workers)} worker(s)"

    def open(self) -> DaskEngine:
        """Start the LocalCluster or connect; check the workers (:func:`check_workers`)."""
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise EngineError("--engine dask needs Dask's distributed: pip install 'vmehil[dask]' "
                              "(make venv installs it)") from None
        try:
            if self.scheduler:
                self.client = Client(self.scheduler, timeout=CONNECT_TIMEOUT_S)
                self.client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
                warn_if_exposed(self.client, self.scheduler)
            else:
                n = max(1, self.jobs or os.cpu_count() or 1)
                self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                            scheduler_port=0, protocol="tcp://", dashboard_address=None,
                                            silence_logs=logging.ERROR)
                self.client = Client(self.cluster)
                self.client.run(_ignore_sigint)
        except (OSError, TimeoutError) as e:
            self.close()
            target = self.scheduler or "a LocalCluster on 127.0.0.1"
            raise EngineError(f"could not start or reach {target}: {e}") from None
        try:
            self.workers = check_workers(self.client)
        except EngineError:
            self.close()
            raise
        return self

    def start(self, fn: Callable[[Any], Any], items: list[Any]) -> None:
        from distributed import Event, as_completed

        if self.client is None:
            self.open()
        token = uuid.uuid4().hex[:12]
        stop_name = f"vmehil-stop-{token}"
        self._stop = Event(stop_name, client=self.client)
        ident = code_identity()
        futures = [self.client.submit(_run_task, fn, item, stop_name, ident, key=f"vmehil-{token}-{i}",
                                      retries=self.retries, pure=False)
                   for i, item in enumerate(items)]
        self._futures = {f.key: f for f in futures}
        self._position = {f.key: i for i, f in enumerate(futures)}
        self._completed = as_completed(futures)

    def pending(self) -> int:
        return len(self._futures)

    def completed(self, timeout: float) -> list[tuple[int, Any]]:
        from distributed import wait

        if not self._completed.has_ready():
            try:
                wait(list(self._futures.values()), timeout=timeout, return_when="FIRST_COMPLETED")
            except TimeoutError:
                return []
        out = []
        for f in self._completed.next_batch(block=False):
            if self._futures.pop(f.key, None) is None:  # reported already
                continue
            result = f.result()  # a task that failed after its retries raises here
            out.append((self._position[f.key], result))
            f.release()
        return sorted(out, key=lambda pr: pr[0])

    def interrupt(self) -> None:
        """Set the sweep's stop event: running tasks stop at their next poll (safe stop), tasks not
        started return at once; wait for them (bounded), then cancel what is left."""
        from distributed import wait

        if self._stop is None:
            return
        self._stop.set()
        left = list(self._futures.values())
        try:
            wait(left, timeout=INTERRUPT_WAIT_S)
        except TimeoutError:
            pass
        self.client.cancel(left)

    def close(self) -> None:
        for f in self._futures.values():
            f.release()
        self._futures = {}
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.cluster is not None:
            self.cluster.close()
            self.cluster = None
