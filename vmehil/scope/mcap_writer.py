"""The MCAP writer of a trace (the ``mcap`` library): one channel per group, JSON messages, each
channel with its JSON Schema, log times on the loop's clock.

A per-tick group ``g`` is the topic ``/g`` with the dots as slashes (``/j1``, ``/drv/j1``,
``/net/j1/encoder``): one message a tick, ``{"tick", "t_s", <leaf>: value, ...}``, logged at
``tick × period``. The bus is ``/bus``: one message a tick holding that tick's cycles as parallel
arrays (``{"tick", "t_s", "t_ns": [...], "address": [...], ...}``, ``t_ns`` each cycle's end on
the crate's simulated clock): a message per cycle cost the tick far more (the mcap library's work
per message; docs/scope.md, "Cost"), and the VCD has each cycle at its instant. A value the loop
did not have (a stopped tick's target, a NaN) is ``null``: JSON has no NaN, and the viewers
(Foxglove, PlotJuggler) read standard JSON.
Chunks (zstd, 256 KiB) go to the file as they fill: memory stays flat however long the run.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, Writer

from vmehil.scope.catalog import Signal
from vmehil.scope.sources import BusCycle

__all__ = ["MARK", "McapTraceWriter", "group_schema", "topic_of"]

MARK = "written_by=vmehil"  #: in the header's library field: the file is vmehil's (may be overwritten)
_JSON_TYPE = {"f": "number", "i": "integer", "b": "boolean"}


def topic_of(group: str) -> str:
    """The MCAP topic of a group: ``drv.j1`` → ``/drv/j1``."""
    return "/" + group.replace(".", "/")


def group_schema(group: str, signals: Sequence[Signal], *, events: bool = False) -> dict[str, Any]:
    """The JSON Schema of one group's messages (every field present; a value may be ``null``;
    ``events``: the bus, each field an array with one item per cycle of the tick)."""
    props: dict[str, Any] = {"tick": {"type": "integer", "description": "servo tick"},
                             "t_s": {"type": "number", "description": "tick × period, s"}}
    if events:
        props["t_ns"] = {"type": "array", "items": {"type": "integer"},
                         "description": "each cycle's end on the simulated clock, ns"}
    for s in signals:
        about = {"description": f"{s.doc} [{s.unit}]" if s.unit else s.doc}
        if events:
            props[s.leaf] = {"type": "array", "items": {"type": _JSON_TYPE[s.kind]}, **about}
        else:
            props[s.leaf] = {"type": [_JSON_TYPE[s.kind], "null"], **about}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": f"vmehil.{group}",
            "type": "object", "properties": props, "required": list(props), "additionalProperties": False}


class McapTraceWriter:
    """Writes one trace to ``path`` (``.mcap``). ``meta``: the run's description (rig, SPEC,
    period), stored as the file's ``vmehil`` metadata record."""

    format = "mcap"

    def __init__(self, path: str | Path, signals: Sequence[Signal], meta: dict[str, str], version: str,
                 period_ns: int) -> None:
        self.path = Path(path)
        self._period_ns = period_ns
        self._f = self.path.open("wb")
        self._w = Writer(self._f, chunk_size=1 << 18, compression=CompressionType.ZSTD)
        self._w.start(profile="", library=f"vmehil {version} ({MARK})")
        self._meta = meta
        groups: dict[str, list[Signal]] = {}
        for s in signals:
            groups.setdefault(s.group, []).append(s)
        self._channels: list[tuple[int, tuple[tuple[str, str], ...]]] = []
        self._summary = 512  #: the summary section the close will write (schemas, channels, statistics)
        self._bus: int | None = None
        for group, sigs in groups.items():
            events = not sigs[0].per_tick
            doc = json.dumps(group_schema(group, sigs, events=events)).encode()
            schema = self._w.register_schema(name=f"vmehil.{group}", encoding="jsonschema", data=doc)
            self._summary += len(doc) + 2 * len(group) + 96  # repeated in the summary, with the channel
            channel = self._w.register_channel(topic=topic_of(group), message_encoding="json", schema_id=schema)
            if events:
                self._bus = channel
                self._bus_fields = tuple(s.leaf for s in sigs)
            else:
                self._channels.append((channel, tuple((s.leaf, s.name) for s in sigs)))
        self.messages = 0
        # zstd on these messages: about 0.3 (measured); the first chunk out gives the real ratio
        self._flushed_at, self._unflushed, self._ratio = self._f.tell(), 0, 0.35

    def write_tick(self, tick: int, t_ns: int, row: dict[str, Any]) -> None:
        t_s = t_ns * 1e-9
        add = self._w.add_message
        for channel, fields in self._channels:
            msg: dict[str, Any] = {"tick": tick, "t_s": t_s}
            for leaf, name in fields:
                msg[leaf] = row.get(name)
            data = json.dumps(msg, allow_nan=False, separators=(",", ":")).encode()
            add(channel_id=channel, log_time=t_ns, publish_time=t_ns, sequence=tick & 0xFFFFFFFF, data=data)
            self._unflushed += len(data)
        self.messages += len(self._channels)

    def write_cycles(self, cycles: Sequence[BusCycle]) -> None:
        if self._bus is None or not cycles:
            return
        tick = max(cycles[0].tick, 0)
        t_ns = tick * self._period_ns
        msg: dict[str, Any] = {"tick": tick, "t_s": t_ns * 1e-9, "t_ns": [c.t_ns for c in cycles]}
        for f in self._bus_fields:
            i = BusCycle._fields.index(f)
            msg[f] = [c[i] for c in cycles]
        data = json.dumps(msg, separators=(",", ":")).encode()
        self._w.add_message(channel_id=self._bus, log_time=t_ns, publish_time=t_ns, sequence=tick & 0xFFFFFFFF,
                            data=data)
        self._unflushed += len(data)
        self.messages += 1

    def size_bytes(self) -> int:
        """The file's bytes, an estimate of the open chunk's (at the last chunk's compression) and of
        the summary the close adds: the bound is met near its size, not a chunk late."""
        at = self._f.tell()
        if at != self._flushed_at:  # a chunk went out: what it held is in ``at``
            if self._unflushed:
                self._ratio = min(1.0, (at - self._flushed_at) / self._unflushed)
            self._flushed_at, self._unflushed = at, 0
        return at + round(self._unflushed * self._ratio) + self._summary + 80 * (at >> 18)

    def close(self) -> None:
        if self._f.closed:
            return
        try:
            self._w.add_metadata("vmehil", {**self._meta, "written_by": "vmehil"})
            self._w.finish()
        finally:
            self._f.close()
