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

Connecting to a scheduler (:func:`check_address`, :func:`probe_scheduler`): the address is
``tcp://HOST:PORT`` (or ``HOST:PORT``), or ``tls://`` with Dask's TLS settings in its config;
Dask's own connect and handshake are tried first under one overall bound of
:data:`CONNECT_TIMEOUT_S` — Dask bounds the TCP connect but not the handshake read after it, so a
port that accepted and never answered hung the sweep (202 s), and one that answered garbage died
in Dask's frame decoder (``MemoryError: Unable to allocate 3.07 EiB``); both are an
:class:`~vmehil.analysis.parallel.EngineError` now, as is ``tls://`` without TLS settings (a
``TypeError`` in Dask).

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

from vmehil.analysis.parallel import EngineError, TaskFailed, task_stop

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


SCHEMES = ("tcp", "tls")  #: the scheduler addresses vmehil connects to


def check_address(address: str) -> str:
    """``address`` as Dask takes it (``HOST:PORT`` gets ``tcp://``); :class:`EngineError` for any
    other protocol, and for ``tls://`` without Dask's TLS settings (its config's
    ``distributed.comm.tls.*``: a CA file, the client's certificate and key)."""
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    if scheme not in SCHEMES or not rest:
        raise EngineError(f"--scheduler {address!r}: give tcp://HOST:PORT (or tls://HOST:PORT with Dask's TLS "
                          "settings); other Dask protocols are not used by vmehil")
    if scheme == "tls":
        from distributed.security import Security

        if Security().get_connection_args("client").get("ssl_context") is None:
            raise EngineError(f"--scheduler {address}: tls:// needs Dask's TLS settings (distributed.comm.tls.ca-file, "
                              ".client.cert and .client.key in the Dask config, or the DASK_DISTRIBUTED__COMM__TLS__* "
                              "variables); none are set")
    return f"{scheme}://{rest}"


def probe_scheduler(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
    """Dask's own connect and handshake to ``address`` (and close), bounded as a whole by
    ``timeout_s``: :class:`EngineError` when nothing answers in time, the port is closed, or what
    answers is no Dask scheduler (its bytes do not decode)."""
    import asyncio

    from distributed.comm import connect
    from distributed.security import Security

    args = Security().get_connection_args("client")

    async def handshake() -> None:
        comm = await asyncio.wait_for(connect(address, timeout=timeout_s, **args), timeout_s)
        await comm.close()

    try:
        asyncio.run(handshake())
    except TimeoutError:
        raise EngineError(f"no Dask scheduler answered at {address} within {timeout_s:g} s (something accepted the "
                          "connection but said nothing, or nothing accepted it)") from None
    except OSError as e:
        raise EngineError(f"could not reach the scheduler at {address}: {e}") from None
    except (Exception, MemoryError) as e:  # Dask's decoder on bytes of another protocol
        raise EngineError(f"what answers at {address} is not a Dask scheduler ({_describe(e)})") from None


def _describe(e: BaseException) -> str:
    """``Type: message`` of an exception, whatever its ``__str__`` does."""
    try:
        text = str(e)
    except Exception:  # a broken __str__ of a worker's exception
        text = "<message cannot be shown>"
    return f"{type(e).__name__}: {text[:500]}" if text else type(e).__name__


def call_with_plain_errors(fn: Callable[[Any], Any], item: Any) -> Any:
    """``fn(item)`` on a worker; an exception it raises is sent to the client as an
    :class:`EngineError` holding only its type and message as text — never the worker's exception
    object, its cause or its context. An object that does not unpickle on the client as an
    exception makes Dask's client handler (``clean_exception``) assert in its event loop: the
    future never completes and the sweep waited forever (#30 item 12)."""
    try:
        return fn(item)
    except Exception as e:
        err = EngineError(f"the task raised {_describe(e)}")
    raise err  # outside the handler: no __context__ to pickle


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
        return call_with_plain_errors(fn, item)


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

    def __init__(self, scheduler: str | None = None, jobs: int | None = None, *, retries: int = RETRIES,
                 connect_timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        self.scheduler = scheduler
        self.connect_timeout_s = connect_timeout_s
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
                address = check_address(self.scheduler)
                probe_scheduler(address, self.connect_timeout_s)
                self.client = Client(address, timeout=self.connect_timeout_s)
                self.client.wait_for_workers(1, timeout=self.connect_timeout_s)
                warn_if_exposed(self.client, self.scheduler)
            else:
                n = max(1, self.jobs or os.cpu_count() or 1)
                try:
                    self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                                host="127.0.0.1", scheduler_port=0, protocol="tcp://",
                                                dashboard_address=None, silence_logs=logging.ERROR)
                except RuntimeError as e:  # Dask's "Nanny failed to start" (a worker killed while starting)
                    raise OSError(f"{type(e).__name__}: {e}") from e
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
            position = self._position[f.key]
            try:
                result = f.result()  # a task that failed after its retries raises here
            except Exception as e:  # the batch's other results are still handed on (TaskFailed)
                result = TaskFailed(EngineError(f"point {position} failed on its worker after {self.retries} "
                                                f"retries ({_describe(e)})"))
            out.append((position, result))
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
