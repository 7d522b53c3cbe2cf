"""``--live [HOST:PORT]``: the loop's channels served live over the Foxglove WebSocket protocol.

The same channels as the black box's MCAP (:mod:`vmehil.reports.blackbox`: ``/j1`` and ``/drv/j1``
per joint, JSON with JSON Schemas, named as the trace files name them), served by foxglove-sdk's
WebSocket server (the ``trace`` extra), so Foxglove opens ``ws://HOST:PORT`` and plots them while
the loop runs
(docs/scope.md, "Live view"). The rows come from the loop's black box after each tick
(``runner.after_tick``): the live view adds no bus access, and nothing is encoded while no
client is subscribed.

Decimated to :data:`LIVE_RATE_HZ` of loop time (every 5th tick at 125 Hz): what a plot panel
draws smoothly; a tick whose stop state changed (a stop beginning, the power going off) is always
sent, and the last row when the live view closes. Loopback only unless ``--live-allow-remote``.

A RUN_EXTENSIONS module of ``vmehil run`` (``add_arguments`` also adds ``--blackbox``, the
same option group; ``prepare`` starts the server before the rig is built, ``attach`` hooks it to
the runner); ``vmehil console`` opens it with :func:`open_live`.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any, Protocol

from vmehil.errors import CliError
from vmehil.option_groups.scope_options import ScopeOptions, add_scope_arguments
from vmehil.reports.blackbox import BoxRows

__all__ = ["LIVE_RATE_HZ", "LiveView", "add_arguments", "attach", "open_live", "prepare"]

#: messages per second of loop time on each channel (plus every change of the stop state)
LIVE_RATE_HZ = 25.0
#: seconds the server stays up after the last row when a client is subscribed (the run has ended)
LINGER_S = 0.2


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_scope_arguments(p)


class RunNeeds(Protocol):
    """What of ``vmehil run``'s options the live view reads."""

    @property
    def scope(self) -> ScopeOptions: ...


class LiveView:
    """A foxglove-sdk WebSocket server with the loop's channels; :meth:`after_tick` publishes."""

    def __init__(self, host: str, port: int, names: list[str] | tuple[str, ...], period_s: float,
                 rate_hz: float = LIVE_RATE_HZ) -> None:
        import foxglove

        from vmehil.scope.mcap_writer import group_schema, topic_of

        self._ctx = foxglove.Context()  # its own: two views in one process do not share channels
        self.names = tuple(names)
        self._rows = BoxRows(self.names, period_s)
        # (channel, its leaves and their signal names), as the trace files' writer lays them out
        self._channels = [(foxglove.Channel(topic_of(group), schema=group_schema(group, sigs), context=self._ctx),
                           tuple((s.leaf, s.name) for s in sigs)) for group, sigs in self._rows.groups.items()]
        try:
            self._server = foxglove.start_server(name="vmehil", host=host, port=port, context=self._ctx)
        except RuntimeError as e:  # foxglove-sdk's FoxgloveError: the port is taken, the host not ours
            raise CliError(f"--live {host}:{port}: {e}") from None
        self.host = host
        self.port = int(self._server.port)
        self.every = max(1, round(1.0 / (rate_hz * period_s)))
        self.rate_hz = 1.0 / (self.every * period_s)
        self.period_ns = round(period_s * 1e9)
        self._last_tick = -1
        self._last_state = -1
        self.sent = 0  #: rows published (each on every channel)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def after_tick(self, loop: Any) -> None:
        box = loop.blackbox
        row = box.latest() if box is not None else None
        if row is None:
            return
        tick, t, state, values = row
        if tick == self._last_tick:  # the box froze after the stop: nothing new
            return
        if tick % self.every == 0 or state != self._last_state:
            self._publish(tick, t, state, values)

    def _publish(self, tick: int, t: float, state: int, values: Any) -> None:
        self._last_tick, self._last_state = tick, state
        if not any(ch.has_sinks() for ch, _ in self._channels):  # nobody subscribed: nothing to encode
            return
        ns = tick * self.period_ns
        row = self._rows.row(state, values)
        t_s = ns * 1e-9
        for ch, fields in self._channels:
            if ch.has_sinks():
                ch.log({"tick": tick, "t_s": t_s, **{leaf: row[name] for leaf, name in fields}}, log_time=ns)
        self.sent += 1

    def finish(self, loop: Any) -> None:
        """The run has ended: publish its last row (when not yet sent) — and, when a client is
        subscribed, give it :data:`LINGER_S` to leave (the server sends from its own threads)."""
        box = loop.blackbox
        row = box.latest() if box is not None else None
        if row is not None and row[0] != self._last_tick:
            self._publish(*row)
        if any(ch.has_sinks() for ch, _ in self._channels):
            time.sleep(LINGER_S)

    def close(self) -> None:
        """Stop the server (its clients see the connection close)."""
        self._server.stop()

    def announce(self) -> None:
        print(f"live: {self.url} (Foxglove WebSocket; {self.rate_hz:g} Hz of loop time per channel)",
              file=sys.stderr, flush=True)


class _Attached:
    """The live view of a run: its last row sent after the run (the server is the preparation's)."""

    def __init__(self, view: LiveView, loop: Any) -> None:
        self.view, self.loop = view, loop

    def close(self) -> None:
        self.view.finish(self.loop)


def open_live(scope: ScopeOptions, names: list[str] | tuple[str, ...], period_s: float) -> LiveView | None:
    """Start the live view ``--live`` asks for (``None`` without it): the server is up and its
    address printed on stderr (port 0: the one chosen) before the amplifiers are enabled; a port
    that cannot be had is a :class:`~vmehil.errors.CliError` (exit 2). Hook :meth:`LiveView.after_tick`
    to the runner; :meth:`LiveView.finish` after the run, then :meth:`LiveView.close`."""
    address = scope.live_address()
    if address is None:
        return None
    view = LiveView(address[0], address[1], names, period_s)
    view.announce()
    return view


class _Prepared:
    """``vmehil run``'s preparation: the server, started before the rig is built."""

    def __init__(self, view: LiveView) -> None:
        self.view = view
        self.defaults: dict[str, Any] = {}

    def close(self) -> None:
        self.view.close()


def prepare(run: RunNeeds, rig: Any) -> _Prepared | None:
    view = open_live(run.scope, [j.name for j in rig.joints], rig.period_s)
    return None if view is None else _Prepared(view)


def attach(run: RunNeeds, system: Any, loop: Any, runner: Any, prepared: _Prepared | None = None) -> _Attached | None:
    if prepared is None:
        return None
    runner.after_tick.append(prepared.view.after_tick)
    return _Attached(prepared.view, loop)
