"""The table writer of a trace: Parquet (pyarrow) or CSV, for pandas.

One row per tick: ``tick``, ``t_s`` and a column per chosen per-tick signal, named as in the
catalog (``j1.position_rad``); a missing value is null (CSV: empty). Bus cycles, when chosen, are
a table of their own beside it (one row per cycle): ``trace.parquet`` → ``trace.bus.parquet``.
Parquet rows go out as a row group every :data:`ROWS_PER_GROUP` ticks; CSV rows as they come.
A CSV starts with one comment line (``# written_by=vmehil …``): ``pandas.read_csv(path,
comment="#")``.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

from vmehil.scope.catalog import Signal
from vmehil.scope.sources import BusCycle

__all__ = ["MARK", "ROWS_PER_GROUP", "TableTraceWriter", "bus_path"]

MARK = "written_by=vmehil"  #: in the Parquet footer's metadata / the CSV's first line
ROWS_PER_GROUP = 1024
_BUS_COLUMNS = BusCycle._fields
_BUS_KINDS = {"tick": "i", "t_ns": "i", "space": "i", "address": "i", "width": "i", "write": "b", "value": "i",
              "block": "b", "berr": "b", "cycle": "i"}


def bus_path(path: Path) -> Path:
    """Where the bus cycles of the table ``path`` go: ``x.parquet`` → ``x.bus.parquet``."""
    return path.with_name(f"{path.stem}.bus{path.suffix}")


class _Sink:
    """One table file: Parquet or CSV by the suffix, rows appended as dicts of plain values."""

    def __init__(self, path: Path, columns: dict[str, str], meta: dict[str, str]) -> None:
        self.path = path
        self.columns = columns
        self.rows = 0
        self._f: IO[Any]
        if path.suffix == ".parquet":
            self._f = path.open("wb")
            import pyarrow as pa
            import pyarrow.parquet as pq

            types = {"f": pa.float64(), "i": pa.int64(), "b": pa.bool_()}
            self._pa = pa
            self._schema = pa.schema([(c, types[k]) for c, k in columns.items()],
                                     metadata={"vmehil": MARK, **{f"vmehil.{k}": v for k, v in meta.items()}})
            self._pq = pq.ParquetWriter(self._f, self._schema, compression="zstd")
            self._rows: list[Sequence[Any]] = []
            self._row_bytes = 2.0 * len(columns)  # compressed, before the first row group says
            self._csv = None
        else:
            text = path.open("w", newline="", encoding="utf-8")
            self._f = text
            text.write(f"# {MARK} " + " ".join(f"{k}={v}" for k, v in meta.items()) + "\n")
            self._csv = csv.writer(text)
            self._csv.writerow(list(columns))

    def add(self, values: Sequence[Any]) -> None:
        """One row, its values in the order of ``columns`` (``None``: no value)."""
        self.rows += 1
        if self._csv is not None:
            self._csv.writerow(values)  # None is written empty, a level True/False
            return
        self._rows.append(values)
        if len(self._rows) >= ROWS_PER_GROUP:
            self._flush()

    def _flush(self) -> None:
        if self._csv is None and self._rows:
            at = self._f.tell()
            cols = dict(zip(self.columns, (list(c) for c in zip(*self._rows, strict=True)), strict=True))
            self._pq.write_table(self._pa.Table.from_pydict(cols, schema=self._schema))
            self._row_bytes = (self._f.tell() - at) / len(self._rows)
            self._rows = []

    def size_bytes(self) -> int:
        """CSV: the bytes written. Parquet: those, the rows not yet out at the last row group's
        bytes a row, and the footer the close adds (its schema: about 100 bytes a column)."""
        if self._csv is not None:
            return self._f.tell()
        return self._f.tell() + round(len(self._rows) * self._row_bytes) + 100 * len(self.columns)

    def close(self) -> None:
        if self._f.closed:
            return
        try:
            if self._csv is None:
                self._flush()
                self._pq.close()
        finally:
            self._f.close()


class TableTraceWriter:
    """Writes one trace to ``path`` (``.parquet`` or ``.csv``) and its bus cycles beside it."""

    def __init__(self, path: str | Path, signals: Sequence[Signal], meta: dict[str, str], version: str) -> None:
        self.path = Path(path)
        self.format = self.path.suffix[1:]
        self._names = [s.name for s in signals if s.per_tick]
        columns = {"tick": "i", "t_s": "f", **{s.name: s.kind for s in signals if s.per_tick}}
        self._ticks = _Sink(self.path, columns, {**meta, "version": version})
        self._bus = (_Sink(bus_path(self.path), {c: _BUS_KINDS[c] for c in _BUS_COLUMNS}, {**meta, "version": version})
                     if any(not s.per_tick for s in signals) else None)

    @property
    def paths(self) -> list[Path]:
        return [self.path] + ([self._bus.path] if self._bus is not None else [])

    def write_tick(self, tick: int, t_ns: int, row: dict[str, Any]) -> None:
        get = row.get
        self._ticks.add([tick, t_ns * 1e-9, *[get(n) for n in self._names]])

    def write_cycles(self, cycles: Sequence[BusCycle]) -> None:
        if self._bus is not None:
            for c in cycles:
                self._bus.add(c)  # its fields are the bus table's columns, in order

    def size_bytes(self) -> int:
        return self._ticks.size_bytes() + (self._bus.size_bytes() if self._bus is not None else 0)

    def close(self) -> None:
        try:
            self._ticks.close()
        finally:
            if self._bus is not None:
                self._bus.close()
