"""The MCAP writer of a trace (the ``mcap`` library): one channel per group, JSON messages, each
channel with its JSON Schema, log times on the loop's clock.

A per-tick group ``g`` is the topic ``/g`` with the dots as slashes (``/j1``, ``/drv/j1``,
``/net/j1/encoder``): one message a tick, ``{"tick", "t_s", <leaf>: value, ...}``, logged at
``tick × period``. The bus is ``/bus``: one message per cycle, logged at the cycle's end on the
crate's simulated clock. A value the loop did not have (a stopped tick's target, a NaN) is
``null``: JSON has no NaN, and the viewers (Foxglove, PlotJuggler) read standard JSON.
Chunks (zstd, 1 MiB) go to the file as they fill: memory stays flat however long the run.
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
    """The JSON Schema of one group's messages (every field present; a value may be ``null``)."""
    props: dict[str, Any] = {"tick": {"type": "integer", "description": "servo tick (-1: before the first)"}}
    if events:
        props["t_ns"] = {"type": "integer", "description": "simulated time at the cycle's end, ns"}
    else:
        props["t_s"] = {"type": "number", "description": "tick × period, s"}
    for s in signals:
        props[s.leaf] = {"type": [_JSON_TYPE[s.kind], "null"],
                         "description": f"{s.doc} [{s.unit}]" if s.unit else s.doc}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": f"vmehil.{group}",
            "type": "object", "properties": props, "required": list(props), "additionalProperties": False}


class McapTraceWriter:
    """Writes one trace to ``path`` (``.mcap``). ``meta``: the run's description (rig, SPEC,
    period), stored as the file's ``vmehil`` metadata record."""

    format = "mcap"

    def __init__(self, path: str | Path, signals: Sequence[Signal], meta: dict[str, str], version: str) -> None:
        self.path = Path(path)
        self._f = self.path.open("wb")
        self._w = Writer(self._f, chunk_size=1 << 20, compression=CompressionType.ZSTD)
        self._w.start(profile="", library=f"vmehil {version} ({MARK})")
        self._meta = meta
        groups: dict[str, list[Signal]] = {}
        for s in signals:
            groups.setdefault(s.group, []).append(s)
        self._channels: list[tuple[int, tuple[tuple[str, str], ...]]] = []
        self._bus: int | None = None
        for group, sigs in groups.items():
            events = not sigs[0].per_tick
            schema = self._w.register_schema(name=f"vmehil.{group}", encoding="jsonschema",
                                             data=json.dumps(group_schema(group, sigs, events=events)).encode())
            channel = self._w.register_channel(topic=topic_of(group), message_encoding="json", schema_id=schema)
            if events:
                self._bus = channel
                self._bus_fields = tuple(s.leaf for s in sigs)
            else:
                self._channels.append((channel, tuple((s.leaf, s.name) for s in sigs)))
        self.messages = 0

    def write_tick(self, tick: int, t_ns: int, row: dict[str, Any]) -> None:
        t_s = t_ns * 1e-9
        add = self._w.add_message
        for channel, fields in self._channels:
            msg = {"tick": tick, "t_s": t_s}
            for leaf, name in fields:
                msg[leaf] = row.get(name)
            add(channel_id=channel, log_time=t_ns, publish_time=t_ns, sequence=tick & 0xFFFFFFFF,
                data=json.dumps(msg, allow_nan=False, separators=(",", ":")).encode())
        self.messages += len(self._channels)

    def write_cycles(self, cycles: Sequence[BusCycle]) -> None:
        if self._bus is None:
            return
        fields = self._bus_fields
        add = self._w.add_message
        for c in cycles:
            full = c._asdict()
            msg = {"tick": c.tick, "t_ns": c.t_ns, **{f: full[f] for f in fields}}
            t = max(c.t_ns, 0)
            add(channel_id=self._bus, log_time=t, publish_time=t, sequence=c.cycle & 0xFFFFFFFF,
                data=json.dumps(msg, separators=(",", ":")).encode())
        self.messages += len(cycles)

    def size_bytes(self) -> int:
        return self._f.tell()

    def close(self) -> None:
        if self._f.closed:
            return
        try:
            self._w.add_metadata("vmehil", {**self._meta, "written_by": "vmehil"})
            self._w.finish()
        finally:
            self._f.close()
