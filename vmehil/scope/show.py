"""``vmehil trace show``: read a trace file back and plot it, for those with no viewer.

The reading goes through the format's own library (the ``mcap`` reader, pyarrow's Parquet
reader, the standard library's csv), never through our writers; the plot is matplotlib's, one
panel per group (``j1``, ``truth.j1``, ``net.j1``), time on the loop's clock.
"""

from __future__ import annotations

import csv
import json
import struct
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vmehil.errors import CliError
from vmehil.scope.catalog import Catalog, Signal

__all__ = ["DEFAULT_SIGNALS", "Series", "plot_series", "read_series", "signal_names", "unreadable_trace"]

#: what ``trace show`` plots without ``--signals``: where the joints were meant to be and were
DEFAULT_SIGNALS = "*.target_rad,*.position_rad,truth.*.theta_rad"
_PLOTTED = 24  #: at most this many signals in one figure (a SPEC choosing more is refused)


@dataclass
class Series:
    """The chosen signals of one trace file: name → (t_s, values)."""

    path: Path
    data: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


def _format(path: Path) -> str:
    fmt = path.suffix.lower()[1:]
    if fmt not in ("mcap", "parquet", "csv"):
        raise CliError(f"vmehil trace show {path}: reads .mcap, .parquet and .csv traces (a .vcd opens in "
                       "GTKWave or PulseView: docs/scope.md)")
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    return fmt


def _reader_errors() -> tuple[type[BaseException], ...]:
    """What the formats' readers raise on a file that is not a trace (bad magic, cut off, another
    file renamed): the error classes of the readers that are installed."""
    errors: list[type[BaseException]] = [ValueError, KeyError, IndexError, EOFError, struct.error]
    try:
        from mcap.exceptions import McapError
    except ImportError:  # the trace extra is missing: only CSV is read
        pass
    else:
        errors.append(McapError)
    return tuple(errors)


@contextmanager
def unreadable_trace(path: Path, fmt: str) -> Iterator[None]:
    """A file the format's reader cannot read is the user's input, not a bug: one line, exit 2
    (before: ``unexpected error: InvalidMagic``, exit 3)."""
    try:
        yield
    except CliError:
        raise
    except _reader_errors() as e:
        raise CliError(f"vmehil trace show {path}: not a readable .{fmt} trace ({type(e).__name__}: {e})") from e


def signal_names(path: Path) -> list[str]:
    """The per-tick signals a trace file holds (the bus cycles are not plotted)."""
    fmt = _format(path)
    with unreadable_trace(path, fmt):
        return _signal_names(path, fmt)


def _signal_names(path: Path, fmt: str) -> list[str]:
    if fmt == "mcap":
        from mcap.reader import make_reader

        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
        if summary is None:
            raise CliError(f"vmehil trace show {path}: no summary section (a trace cut off before it was closed?)")
        names = []
        for ch in sorted(summary.channels.values(), key=lambda c: c.id):
            if ch.topic == "/bus":
                continue
            group = ch.topic[1:].replace("/", ".")
            props = json.loads(summary.schemas[ch.schema_id].data)["properties"]
            names += [f"{group}.{leaf}" for leaf in props if leaf not in ("tick", "t_s")]
        return names
    if fmt == "parquet":
        import pyarrow.parquet as pq

        return [c for c in pq.read_schema(path).names if c not in ("tick", "t_s")]
    with path.open(newline="", encoding="utf-8") as f:
        header = next(csv.reader(line for line in f if not line.startswith("#")), [])
    if "t_s" not in header:  # every trace CSV has the loop's time (docs/scope.md)
        raise CliError(f"vmehil trace show {path}: not a trace written by --trace (no t_s column)")
    return [c for c in header if c not in ("tick", "t_s")]


def _chosen(path: Path, spec: str | None) -> list[str]:
    names = signal_names(path)
    catalog = Catalog(Signal(n, "f", "", "") for n in names)
    try:
        chosen = [s.name for s in catalog.select(spec or DEFAULT_SIGNALS, flag="--signals")]
    except ValueError:
        if spec is not None:
            raise
        chosen = names[:8]  # a trace without the joints' positions: its first signals
    if len(chosen) > _PLOTTED:
        raise CliError(f"--signals: {len(chosen)} signals chosen; plot at most {_PLOTTED} in one figure")
    return chosen


def read_series(path: str | Path, spec: str | None = None) -> Series:
    """The signals ``spec`` chooses (``--signals`` grammar: the trace SPEC's) from ``path``."""
    p = Path(path)
    fmt = _format(p)
    wanted = _chosen(p, spec)
    with unreadable_trace(p, fmt):
        return _read_series(p, fmt, wanted)


def _read_series(p: Path, fmt: str, wanted: list[str]) -> Series:
    out = Series(p)
    if fmt == "mcap":
        from mcap.reader import make_reader

        groups: dict[str, list[str]] = {}
        for n in wanted:
            g, _, leaf = n.rpartition(".")
            groups.setdefault("/" + g.replace(".", "/"), []).append(leaf)
        t: dict[str, list[float]] = {topic: [] for topic in groups}
        v: dict[str, list[float]] = {n: [] for n in wanted}
        with p.open("rb") as f:
            for _schema, channel, message in make_reader(f).iter_messages(topics=list(groups)):
                msg = json.loads(message.data)
                t[channel.topic].append(message.log_time * 1e-9)
                group = channel.topic[1:].replace("/", ".")
                for leaf in groups[channel.topic]:
                    x = msg.get(leaf)
                    v[f"{group}.{leaf}"].append(np.nan if x is None else float(x))
        for n in wanted:
            g = "/" + n.rpartition(".")[0].replace(".", "/")
            out.data[n] = (np.asarray(t[g]), np.asarray(v[n], float))
        return out
    if fmt == "parquet":
        import pyarrow.parquet as pq

        table = pq.read_table(p, columns=["t_s", *wanted]).to_pydict()
        ts = np.asarray(table["t_s"], float)
        for n in wanted:
            out.data[n] = (ts, np.array([np.nan if x is None else float(x) for x in table[n]]))
        return out
    with p.open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(line for line in f if not line.startswith("#")))
    ts = np.array([float(r["t_s"]) for r in rows])
    for n in wanted:
        out.data[n] = (ts, np.array([float(r[n]) if r[n] != "" else np.nan for r in rows]))
    return out


def plot_series(series: Series, out: str | Path) -> Path:
    """One PNG: a panel per group, its signals as lines over the loop's time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[str, list[str]] = {}
    for n in series.data:
        groups.setdefault(n.rpartition(".")[0], []).append(n)
    fig, axes = plt.subplots(len(groups), 1, figsize=(10, 2.2 * len(groups) + 0.8), sharex=True, squeeze=False)
    for ax, (group, names) in zip(axes[:, 0], groups.items(), strict=True):
        for n in names:
            t, y = series.data[n]
            ax.plot(t, y, lw=1.0, label=n.rpartition(".")[2])
        ax.set_ylabel(group)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=7)
    axes[-1, 0].set_xlabel("loop time (s)")
    fig.suptitle(str(series.path.name))
    fig.tight_layout()
    path = Path(out)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def show(path: str | Path, signals: str | None, out: str | Path | None) -> tuple[Path, Sequence[str]]:
    """Read ``path``, plot what ``signals`` chooses to ``out`` (default: beside it, ``.png``)."""
    series = read_series(path, signals)
    target = Path(out) if out is not None else Path(path).with_suffix(".png")
    return plot_series(series, target), list(series.data)
