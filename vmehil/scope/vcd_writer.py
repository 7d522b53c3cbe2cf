"""The VCD writer of a trace (pyvcd), for GTKWave and sigrok/PulseView: the bus cycles and the
digital lines.

What goes in: the chosen signals that are levels or counts (catalog kinds ``b`` and ``i``:
enables, brakes, fault lines, the watchdog line, integrator switch-off, the stop state, the
decoders' per-period counts, index pulses and flags, the IRQ acknowledges, the driver's counts)
and the bus cycles; numbers with a fraction (volts, radians) stay in the MCAP, Parquet or CSV
file. Scopes follow the groups (``vmehil.net.j1``, ``vmehil.bus``); time in ns on the loop's
simulated clock: a tick's values at ``tick × period``, each bus cycle at its end. The emulated
decoders keep per-period summaries, not A/B edges, so an encoder shows as its count per period.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vcd import VCDWriter

from vmehil.scope.catalog import Signal
from vmehil.scope.sources import BusCycle

__all__ = ["MARK", "VcdTraceWriter"]

MARK = "written_by=vmehil"  #: in the header's comment: the file is vmehil's
#: the bus group's VCD variables: (field, var type, size)
_BUS_VARS = {"space": ("integer", 8), "address": ("wire", 32), "width": ("integer", 8), "write": ("wire", 1),
             "value": ("wire", 32), "block": ("wire", 1), "berr": ("wire", 1), "cycle": ("integer", 32)}


class VcdTraceWriter:
    """Writes one trace's levels, counts and bus cycles to ``path`` (``.vcd``)."""

    format = "vcd"

    def __init__(self, path: str | Path, signals: Sequence[Signal], meta: dict[str, str], version: str) -> None:
        self.path = Path(path)
        self._f = self.path.open("w", encoding="ascii", newline="\n")
        about = " ".join(f"{k}={v}" for k, v in meta.items())
        self._w = VCDWriter(self._f, timescale="1 ns", comment=f"{MARK} vmehil {version} {about}",
                            version=f"vmehil {version}")
        self._vars: list[tuple[str, Any]] = []
        self._bus: list[tuple[str, Any]] = []
        for s in signals:
            if not s.per_tick:
                kind, size = _BUS_VARS[s.leaf]
                self._bus.append((s.leaf, self._w.register_var(f"vmehil.{s.group}", s.leaf, kind, size=size)))
            elif s.digital:
                kind, size = ("wire", 1) if s.kind == "b" else ("integer", 32)
                self._vars.append((s.name, self._w.register_var(f"vmehil.{s.group}", s.leaf, kind, size=size)))
        #: the chosen signals a VCD does not carry (numbers with a fraction)
        self.left_out = tuple(s.name for s in signals if s.per_tick and not s.digital)
        self._t = 0
        self._last: dict[str, Any] = {}
        self._bus_last: list[Any] = [None] * len(BusCycle._fields)
        self.changes = 0

    def _time(self, t_ns: int) -> int:
        # VCD time never goes back: a value due before the last change written is shown with it
        self._t = max(self._t, int(t_ns))
        return self._t

    def write_tick(self, tick: int, t_ns: int, row: dict[str, Any]) -> None:
        if not self._vars:
            return
        t = self._time(t_ns)
        change, last = self._w.change, self._last
        for name, var in self._vars:
            v = row.get(name)
            if v is not None and last.get(name) != v:  # most lines hold: no call for them
                last[name] = v
                change(var, t, int(v) & 0xFFFFFFFF if not isinstance(v, bool) else v)
        self.changes += 1

    def write_cycles(self, cycles: Sequence[BusCycle]) -> None:
        if not self._bus:
            return
        change, last = self._w.change, self._bus_last
        fields = [(BusCycle._fields.index(leaf), var) for leaf, var in self._bus]
        for c in cycles:
            t = self._time(c.t_ns)
            for i, var in fields:
                v = c[i]
                if last[i] != v:  # the fields a cycle shares with the one before: no call
                    last[i] = v
                    change(var, t, v)
        self.changes += len(cycles)

    def size_bytes(self) -> int:
        return self._f.tell()

    def close(self) -> None:
        if self._f.closed:
            return
        try:
            self._w.close()
        finally:
            self._f.close()
