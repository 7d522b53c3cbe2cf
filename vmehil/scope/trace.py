"""A trace: the chosen signals written tick by tick to one or more files, each within a size bound.

:class:`Trace` is a runner's after-tick hook (``runner.after_tick``): after each tick it asks the
:class:`~vmehil.scope.sources.Sampler` for the tick's values and the bus cycles since the last
one, and hands them to every writer still writing. A file that reaches the bound
(``--trace-max-mb``) is closed there, valid and readable, and the trace says so in one line on
stderr; the loop runs on. A file that cannot be written (a full disk) stops the same way.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TextIO

from vmehil.errors import CliError
from vmehil.scope.catalog import Signal
from vmehil.scope.sources import BusCycle, Sampler

__all__ = ["FORMATS", "Trace", "TraceWriter", "format_of", "open_writer"]


class TraceWriter(Protocol):
    """One trace file's writer (:mod:`~vmehil.scope.mcap_writer`, :mod:`~vmehil.scope.vcd_writer`,
    :mod:`~vmehil.scope.table_writer`)."""

    path: Path
    format: str

    def write_tick(self, tick: int, t_ns: int, row: dict[str, Any]) -> None: ...

    def write_cycles(self, cycles: Sequence[BusCycle]) -> None: ...

    def size_bytes(self) -> int: ...

    def close(self) -> None: ...


#: suffix → the format's name (the writer: :func:`open_writer`)
FORMATS = {".mcap": "mcap", ".vcd": "vcd", ".parquet": "parquet", ".csv": "csv"}


def format_of(path: str | Path, flag: str = "--trace-out") -> str:
    """The format a trace file's suffix names; refuses any other suffix."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise CliError(f"{flag} {path}: the suffix names the format: one of {', '.join(FORMATS)}")
    return FORMATS[suffix]


def open_writer(path: Path, signals: Sequence[Signal], meta: dict[str, str], version: str,
                period_ns: int) -> TraceWriter:
    """The writer of ``path``'s format (imported here: the 'trace' extra's libraries)."""
    fmt = format_of(path)
    if fmt == "mcap":
        from vmehil.scope.mcap_writer import McapTraceWriter
        return McapTraceWriter(path, signals, meta, version, period_ns)
    if fmt == "vcd":
        from vmehil.scope.vcd_writer import VcdTraceWriter
        return VcdTraceWriter(path, signals, meta, version)
    from vmehil.scope.table_writer import TableTraceWriter
    return TableTraceWriter(path, signals, meta, version)


@dataclass
class _File:
    writer: TraceWriter
    ticks: int = 0
    cycles: int = 0
    stopped_at_tick: int | None = None
    stopped_why: str | None = None


class Trace:
    """Writes ``sampler``'s signals to ``paths`` (each file at most ``max_bytes``)."""

    def __init__(self, sampler: Sampler, paths: Sequence[Path], *, meta: dict[str, str], max_bytes: int,
                 version: str, err: TextIO | None = None) -> None:
        self.sampler = sampler
        self.max_bytes = max_bytes
        self.meta = meta
        self._err = err
        self.files: list[_File] = []
        try:
            for p in paths:
                self.files.append(_File(open_writer(Path(p), sampler.signals, meta, version, sampler.period_ns)))
        except BaseException:
            self.close()
            raise
        self.last_tick: int | None = None

    def attach(self, runner: Any) -> Callable[[Any], None]:
        """Trace after each of ``runner``'s ticks (returns the hook, for removal)."""
        runner.after_tick.append(self.on_tick)
        return self.on_tick

    def on_tick(self, loop: Any) -> None:
        live = [f for f in self.files if f.stopped_at_tick is None]
        if not live:
            self.sampler.cycles()  # nobody writes them: not kept either
            return
        k, t_ns, row = self.sampler.row(loop)
        self.write_row(k, t_ns, row, self.sampler.cycles())

    def write_row(self, k: int, t_ns: int, row: dict[str, Any], cycles: Sequence[BusCycle] = ()) -> None:
        """Write one tick's values (and the bus cycles since the last) to every file still writing;
        a source other than a loop (the coordinator's plant exchanges) calls it directly."""
        live = [f for f in self.files if f.stopped_at_tick is None]
        self.last_tick = k
        for f in live:
            try:
                f.writer.write_tick(k, t_ns, row)
                if cycles:
                    f.writer.write_cycles(cycles)
            except OSError as e:
                self._stop(f, k, f"could not be written ({e})")
                continue
            f.ticks += 1
            f.cycles += len(cycles)
            if f.writer.size_bytes() >= self.max_bytes:
                self._stop(f, k, f"reached --trace-max-mb {self.max_bytes / 1e6:g}")

    def _stop(self, f: _File, tick: int, why: str) -> None:
        f.stopped_at_tick, f.stopped_why = tick, why
        try:
            f.writer.close()
        except OSError:
            pass
        print(f"trace: {f.writer.path} {why} at tick {tick}: writing stopped there (the loop runs on)",
              file=self._err or sys.stderr)

    def close(self) -> None:
        """Write the cycles after the last tick (the final stop's), close every file, and stop
        observing."""
        try:
            cycles = self.sampler.cycles()
            for f in self.files:
                if f.stopped_at_tick is None:
                    try:
                        if cycles:
                            f.writer.write_cycles(cycles)
                            f.cycles += len(cycles)
                    finally:
                        f.writer.close()
        finally:
            self.sampler.close()

    def summary(self) -> dict[str, Any]:
        """For the run's JSON (``trace``): what was written where."""
        files = []
        for f in self.files:
            paths = list(getattr(f.writer, "paths", [f.writer.path]))
            files.append({"path": str(f.writer.path), "format": f.writer.format,
                          "bytes": sum(p.stat().st_size for p in paths if p.exists()),
                          "ticks": f.ticks, "bus_cycles": f.cycles, "stopped_at_tick": f.stopped_at_tick,
                          "stopped": f.stopped_why, "also": [str(p) for p in paths[1:]],
                          "left_out": len(getattr(f.writer, "left_out", ()))})
        return {"spec": self.meta.get("spec"), "signals": len(self.sampler.signals), "max_mb": self.max_bytes / 1e6,
                "files": files}
