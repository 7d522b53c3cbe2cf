"""A Dask cluster that listens beyond loopback is named in a warning (docs/sweeps.md)."""

from __future__ import annotations

import warnings

import pytest

pytest.importorskip("distributed")

from distributed import Client, LocalCluster

from vmehil.analysis import dask_engine
from vmehil.analysis.dask_engine import ExposedClusterWarning, beyond_loopback, warn_if_exposed


def test_only_loopback_hosts_count_as_loopback() -> None:
    assert beyond_loopback(["127.0.0.1:8786", "127.3.2.1:1", "::1:9000", "[::1]:9000"]) == []
    assert beyond_loopback(["0.0.0.0:8787", ":::8788", "10.0.0.5:8786", "sched.example:1"]) == [
        "0.0.0.0:8787", ":::8788", "10.0.0.5:8786", "sched.example:1"]


@pytest.fixture(scope="module")
def loopback_client():
    # threads, not processes: the check runs in this process, so a test can stand in for it
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, host="127.0.0.1", protocol="tcp://",
                      dashboard_address=None) as cluster, Client(cluster) as client:
        yield client


def test_a_loopback_only_cluster_gives_no_warning(loopback_client) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExposedClusterWarning)
        warn_if_exposed(loopback_client, "tcp://127.0.0.1:0")


def test_a_cluster_listening_on_every_interface_is_named_in_a_warning(loopback_client, monkeypatch) -> None:
    # the recipe the docs had: `dask scheduler ... --no-dashboard` still listened on 0.0.0.0:8787
    monkeypatch.setattr(dask_engine, "_listening_sockets", lambda: ["127.0.0.1:41000", "0.0.0.0:8787"])
    with pytest.warns(ExposedClusterWarning, match=r"listens beyond loopback .*scheduler on 0\.0\.0\.0:8787"):
        warn_if_exposed(loopback_client, "tcp://127.0.0.1:41000")
