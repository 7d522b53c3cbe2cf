"""``vmehil trace show FILE [--signals SPEC] [--out PNG]``: plot a trace file (docs/scope.md).

For those with no viewer at hand (Foxglove, PlotJuggler, GTKWave): reads an ``.mcap``,
``.parquet`` or ``.csv`` trace written by ``--trace`` and draws the chosen signals, one panel per
group, to a PNG (default: beside the file).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("trace", help="look at a trace file written by --trace (docs/scope.md)")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    s = actions.add_parser("show", help="plot a trace file (.mcap, .parquet, .csv) to a PNG")
    s.add_argument("file", metavar="FILE", help="the trace file")
    s.add_argument("--signals", metavar="SPEC", default=None,
                   help="the signals to plot, in --trace's grammar (default: *.target_rad,*.position_rad,"
                        "truth.*.theta_rad); list: print the file's signal names and exit")
    s.add_argument("--out", dest="png", metavar="PNG", default=None, help="the figure (default: FILE with .png)")
    s.set_defaults(func=show, options=TraceShowOptions.from_args)


@dataclass(frozen=True)
class TraceShowOptions:
    """``vmehil trace show``'s options."""

    file: str
    signals: str | None = None
    png: str | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> TraceShowOptions:
        return cls(file=args.file, signals=args.signals, png=args.png)


def show(opts: TraceShowOptions) -> int:
    from vmehil.commands import refuse_without

    listing = opts.signals == "list"  # as `--trace list`: the names the SPEC chooses from
    extras = ([] if listing else ["plots"]) + (["trace"] if not opts.file.lower().endswith(".csv") else [])
    if any(refuse_without("vmehil trace show", extra) for extra in extras):
        return 2
    if listing:
        from pathlib import Path

        from vmehil.scope.show import signal_names

        for name in signal_names(Path(opts.file)):
            print(name)
        return 0
    from vmehil.scope.show import show as plot

    path, names = plot(opts.file, opts.signals, opts.png)
    print(f"trace show: {len(names)} signals from {opts.file} to {path}", file=sys.stderr)
    return 0
