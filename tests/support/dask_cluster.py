"""A Dask cluster started with Dask's own command line (``dask scheduler``, ``dask worker``) as
separate processes on 127.0.0.1, for the engine tests; and a marked task the test can catch
while it runs (:func:`marked_call`)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tests.support import REPO

START_TIMEOUT_S = 180.0  #: generous: the machine is shared; a wait ends as soon as its condition holds


def wait_for(condition: Callable[[], bool], what: str, timeout_s: float = START_TIMEOUT_S) -> None:
    """Wait until ``condition()`` holds (checked every 50 ms), failing after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what}: not within {timeout_s:g} s")
        time.sleep(0.05)


@dataclass
class CliCluster:
    address: str
    scheduler: subprocess.Popen
    workers: list[subprocess.Popen] = field(default_factory=list)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=20)


@contextmanager
def cli_cluster(folder: Path, n_workers: int = 2) -> Iterator[CliCluster]:
    """A scheduler and ``n_workers`` single-threaded workers (no nanny: the worker process is the
    one started here, so killing it kills the worker), every socket on 127.0.0.1; every
    process is ended and waited for on the way out."""
    folder.mkdir(parents=True, exist_ok=True)
    sfile = folder / "scheduler.json"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    dask = [sys.executable, "-m", "dask"]
    procs: list[subprocess.Popen] = []
    log = (folder / "cluster.log").open("w")
    try:
        # `--no-dashboard` alone still listens on 0.0.0.0 (a second port of the scheduler's and of
        # each worker's): a dashboard on loopback port 0 keeps every socket on 127.0.0.1
        sched = subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", "0",
                                  "--dashboard-address", "127.0.0.1:0",
                                  "--scheduler-file", str(sfile)], env=env, stdout=log, stderr=log, cwd=folder)
        procs.append(sched)
        wait_for(lambda: (sfile.exists() and sfile.stat().st_size > 0) or sched.poll() is not None,
                 "dask scheduler wrote its scheduler file")
        assert sched.poll() is None, (folder / "cluster.log").read_text()
        address = json.loads(sfile.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:"), address
        cluster = CliCluster(address, sched)
        for i in range(n_workers):
            w = subprocess.Popen([*dask, "worker", "--scheduler-file", str(sfile), "--host", "127.0.0.1",
                                  "--nthreads", "1", "--no-nanny", "--dashboard-address", "127.0.0.1:0",
                                  "--name", f"w{i}",
                                  "--local-directory", str(folder / f"w{i}")], env=env, stdout=log, stderr=log,
                                 cwd=folder)
            procs.append(w)
            cluster.workers.append(w)
        yield cluster
    finally:
        for p in reversed(procs):
            _stop(p)
        log.close()


def marked_call(fn: Callable[[Any], Any], marker: str, marked_index: int, item: Any) -> Any:
    """``fn(item)``; but the first run of the item whose ``index`` is ``marked_index`` writes its
    process id to ``marker`` and then waits (for the test to kill its worker; it goes on after
    :data:`START_TIMEOUT_S` if nobody does). A re-run (the marker exists) goes straight on."""
    if getattr(item, "index", None) == marked_index:
        try:
            fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            pass
        else:
            os.write(fd, str(os.getpid()).encode())
            os.close(fd)
            release = Path(marker + ".release")
            deadline = time.monotonic() + START_TIMEOUT_S
            while not release.exists() and time.monotonic() < deadline:
                time.sleep(0.05)
    return fn(item)
