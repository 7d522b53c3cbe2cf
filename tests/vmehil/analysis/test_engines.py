"""Sweep engines: the local process pool, a Dask LocalCluster and a cluster started with Dask's
own command line give the same rows; a worker killed while it runs a point loses nothing and
counts nothing twice; a mixed cluster is refused."""

from __future__ import annotations

import functools
import os
import signal
import threading
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("distributed")

from servo.settings import servo_settings
from tests.support.dask_cluster import cli_cluster, marked_call, wait_for
from vmehil.analysis.dask_engine import DaskEngine, _run_task, check_workers, code_identity
from vmehil.analysis.parallel import EngineError, run_parallel
from vmehil.analysis.simulate import SimSettings
from vmehil.analysis.sweep import SweepTask, evaluate_point, evaluate_points, rig_text, task_rig

FAST = SimSettings(move_deg=2.0, hold_s=1.0, allow_short=True)  # ~1.4 s simulated per point


def _tasks() -> list[SweepTask]:
    rig = task_rig(rig_text("jpl-arm"), "/nonexistent/jpl-arm.toml")
    base = {"kp": 100.0, "kpi": 5000.0, "kv": 50.0, "kvi": 1000.0}
    # a path no worker has: the rig travels parsed, with the servo's typed settings
    return [SweepTask(i, "/nonexistent/jpl-arm.toml", 1, {**base, "kp": kp}, FAST, rig=rig, servo=servo_settings(rig))
            for i, kp in enumerate((80.0, 110.0, 140.0))]


def _same(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows without their wall time (the one column that depends on the machine)."""
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


@pytest.fixture(scope="module")
def local_rows() -> list[dict[str, Any]]:
    return _same(evaluate_points(_tasks(), jobs=2))


@pytest.mark.slow
def test_local_cluster_gives_the_rows_of_the_local_pool(local_rows) -> None:
    seen: list[int] = []
    engine = DaskEngine(jobs=2).open()
    assert engine.cluster.scheduler_address.startswith("tcp://127.0.0.1:")
    assert all(addr.startswith("tcp://127.0.0.1:") for addr in engine.workers)
    rows = evaluate_points(_tasks(), engine=engine, on_result=lambda row, _rows: seen.append(row["index"]))
    assert engine.client is None and engine.cluster is None  # closed by run_parallel
    assert _same(rows) == local_rows
    assert sorted(seen) == [0, 1, 2]
    assert [r["kp"] for r in rows] == [80.0, 110.0, 140.0] and all(r["status"] == "ok" for r in rows)


@pytest.mark.slow
def test_local_cluster_runs_batches_with_the_rows_of_the_local_pool(local_rows) -> None:
    """--batch 2 on Dask: the engine ships batches (two tasks for three points) to its workers."""
    seen: list[int] = []
    engine = DaskEngine(jobs=2).open()
    rows = evaluate_points(_tasks(), engine=engine, batch=2, on_result=lambda row, _rows: seen.append(row["index"]))
    assert _same(rows) == local_rows
    assert sorted(seen) == [0, 1, 2]


@pytest.mark.slow
@pytest.mark.filterwarnings("error::vmehil.analysis.dask_engine.ExposedClusterWarning")  # loopback only
def test_cli_cluster_worker_killed_mid_point_gives_every_row_once(tmp_path: Path, local_rows) -> None:
    """Scheduler and two workers from `dask scheduler`/`dask worker` on 127.0.0.1; the worker that
    starts point 0 is SIGKILLed while it runs it: Dask re-runs the point on the other worker, and
    the sweep ends with the three rows of the local pool, each once."""
    marker = tmp_path / "marked"
    with cli_cluster(tmp_path / "cluster") as cluster:
        from distributed import Client

        with Client(cluster.address, timeout=60) as c:  # both workers joined (Dask's own wait)
            c.wait_for_workers(2, timeout=180)
        engine = DaskEngine(cluster.address).open()
        assert len(engine.workers) == 2 and all(a.startswith("tcp://127.0.0.1:") for a in engine.workers)
        pids = {w.pid: w for w in cluster.workers}
        got: list[int] = []
        fn = functools.partial(marked_call, evaluate_point, str(marker), 0)
        killed: list[int] = []

        def kill_when_marked() -> None:
            wait_for(lambda: marker.exists() and marker.stat().st_size > 0, "the marked point started")
            pid = int(marker.read_text())
            assert pid in pids, (pid, list(pids))
            os.kill(pid, signal.SIGKILL)
            pids[pid].wait(timeout=60)
            killed.append(pid)

        killer = threading.Thread(target=kill_when_marked, daemon=True)
        killer.start()
        rows = run_parallel(fn, _tasks(), engine=engine, on_result=lambda i, r: got.append(r["index"]))
        killer.join(timeout=60)
    assert killed, "the marked worker was not killed"
    assert sorted(got) == [0, 1, 2]  # every point once
    assert _same(rows) == local_rows


class _Cluster:
    """A client stand-in whose workers report the given identities (the refusal's logic only)."""

    def __init__(self, identities: dict[str, dict[str, str]]) -> None:
        self.identities = identities

    def run(self, fn):
        return self.identities


def test_a_mixed_cluster_is_refused_naming_the_worker() -> None:
    mine = code_identity()
    assert len(mine["source_sha256"]) == 64 and mine["version"]
    same = {"tcp://127.0.0.1:1": dict(mine)}
    assert check_workers(_Cluster(same)) == same
    other = {**same, "tcp://127.0.0.1:2": {**mine, "source_sha256": "0" * 64}}
    with pytest.raises(EngineError, match=r"mixed cluster.*tcp://127\.0\.0\.1:2"):
        check_workers(_Cluster(other))
    # a task sent by a client with other code refuses to run on this worker
    with pytest.raises(EngineError, match="same vmehil"):
        _run_task(evaluate_point, _tasks()[0], "unused", {**mine, "version": "0.0.0"})
