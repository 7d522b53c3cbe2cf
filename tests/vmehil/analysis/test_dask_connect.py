"""Connecting to a Dask scheduler is bounded and typed (#30 item 11): a port that accepts and
never answers, a port that answers garbage, and a tls:// or other address without what it needs
are each an EngineError, in bounded time. Fake servers listen on 127.0.0.1 only."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

pytest.importorskip("distributed")

from vmehil.analysis.dask_engine import DaskEngine
from vmehil.analysis.parallel import EngineError


@contextmanager
def fake_server(answer: bytes | None) -> Iterator[str]:
    """A TCP server on 127.0.0.1 that accepts, then sends ``answer`` (None: nothing, ever)."""
    srv = socket.create_server(("127.0.0.1", 0))
    conns: list[socket.socket] = []
    done = threading.Event()

    def serve() -> None:
        srv.settimeout(0.05)
        while not done.is_set():
            try:
                c, _ = srv.accept()
            except OSError:
                continue
            conns.append(c)
            if answer is not None:
                c.sendall(answer)

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    try:
        yield f"tcp://127.0.0.1:{srv.getsockname()[1]}"
    finally:
        done.set()
        t.join()
        for c in conns:
            c.close()
        srv.close()


def test_a_port_that_accepts_and_never_answers_is_refused_after_the_connect_timeout() -> None:
    with fake_server(None) as address:
        with pytest.raises(EngineError, match="no Dask scheduler answered at .* within 1 s"):
            DaskEngine(address, connect_timeout_s=1.0).open()


def test_a_port_that_answers_garbage_is_not_a_dask_scheduler() -> None:
    # a frame count and lengths of 2^64 - 1: Dask's decoder tried to allocate exbibytes
    with fake_server(b"\xff" * 64) as address:
        with pytest.raises(EngineError, match="is not a Dask scheduler"):
            DaskEngine(address, connect_timeout_s=5.0).open()


def test_tls_without_tls_settings_and_other_protocols_are_refused_in_one_line() -> None:
    with pytest.raises(EngineError, match="tls:// needs Dask's TLS settings"):
        DaskEngine("tls://127.0.0.1:1").open()
    with pytest.raises(EngineError, match="give tcp://HOST:PORT"):
        DaskEngine("ucx://127.0.0.1:1").open()
