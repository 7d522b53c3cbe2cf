"""``--trace SPEC``, ``--trace-out PATH`` and ``--trace-max-mb MB``: one declaration for every
command that runs a loop (``run``, ``console``, ``unit``, ``coordinate``; docs/scope.md).

It is also one of ``vmehil run``'s extensions (``RUN_EXTENSIONS``): :func:`attach` starts the
trace once the loop is armed and the trace's summary joins the run's JSON (``trace``). The other
commands call :meth:`TraceOptions.start` where their runner exists.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from vmehil.errors import CliError
from vmehil.option_groups.cli_types import bounded_float

__all__ = ["DEFAULT_MAX_MB", "DEFAULT_NAME", "LIST", "TraceOptions", "add_arguments", "attach"]

DEFAULT_NAME = "trace.mcap"  #: the file of ``--trace`` without ``--trace-out``
DEFAULT_MAX_MB = 512.0
LIST = "list"  #: ``--trace list``: print the rig's signal names and exit


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("traces (docs/scope.md; the 'trace' extra)")
    g.add_argument("--trace", metavar="SPEC", default=None,
                   help="record these signals every tick: dotted names with wildcards, comma-separated "
                        "(j1.*,bus.*,net.j2.*; * everything; -NAME removes); 'list' prints the names")
    g.add_argument("--trace-out", metavar="PATH", action="append", default=None,
                   help="where (repeatable); the suffix names the format: .mcap, .vcd, .parquet, .csv "
                        f"(default: {DEFAULT_NAME} in the report directory, else here)")
    g.add_argument("--trace-max-mb", metavar="MB", type=bounded_float(0.001, 1e6, what="a size in MB"),
                   default=DEFAULT_MAX_MB,
                   help=f"stop writing a trace file (not the loop) once it holds this many MB (default "
                        f"{DEFAULT_MAX_MB:g})")


@dataclass(frozen=True)
class TraceOptions:
    """The trace a command writes: ``spec`` (``None``: none), its files and their size bound."""

    spec: str | None = None
    paths: tuple[Path, ...] = ()
    max_mb: float = DEFAULT_MAX_MB

    @classmethod
    def from_args(cls, args: argparse.Namespace, *, report_dir: str | None = None) -> TraceOptions:
        """``report_dir``: where ``trace.mcap`` goes without ``--trace-out`` (else the current
        directory)."""
        from vmehil.scope.trace import format_of

        spec = getattr(args, "trace", None)
        outs = getattr(args, "trace_out", None) or []
        if spec is None:
            if outs:
                raise CliError("--trace-out: give --trace SPEC too (the signals to record)")
            return cls(max_mb=getattr(args, "trace_max_mb", DEFAULT_MAX_MB))
        for o in outs:
            format_of(o)
        paths = tuple(Path(o) for o in outs)
        if not paths and spec != LIST:
            default = Path(report_dir or ".") / DEFAULT_NAME
            from vmehil.writers.output_paths import check_output_file

            if report_dir is None:  # in a report directory the file is the report's; here it is checked
                check_output_file(default, "--trace (its default file)")
            paths = (default,)
        return cls(spec=spec, paths=paths, max_mb=args.trace_max_mb)

    @property
    def wanted(self) -> bool:
        return self.spec is not None and self.spec != LIST

    @property
    def wants_list(self) -> bool:
        return self.spec == LIST

    def check(self, system: Any, names: Sequence[str]) -> None:
        """Refuse a SPEC that does not fit the rig (:class:`vmehil.scope.catalog.TraceSpecError`)
        before the loop is armed."""
        if self.wanted:
            from vmehil.scope.sources import catalog_of

            assert self.spec is not None
            catalog_of(system, names).select(self.spec)

    def start(self, system: Any, loop: Any, runner: Any, *, rig: str, seed: int | None = None,
              err: Any = None) -> Any:
        """Begin tracing ``loop`` on ``system`` after each of ``runner``'s ticks; returns the
        :class:`vmehil.scope.trace.Trace` (``close()`` it after the run), or ``None`` without
        ``--trace``."""
        if not self.wanted:
            return None
        assert self.spec is not None
        from vmehil.scope.sources import catalog_of, sampler_for
        from vmehil.scope.trace import Trace

        signals = catalog_of(system, loop.names).select(self.spec)
        meta = {"rig": rig, "spec": self.spec, "period_s": repr(loop.period_s)}
        if seed is not None:
            meta["seed"] = str(seed)
        sampler = sampler_for(signals, system, loop)
        trace = Trace(sampler, self.paths, meta=meta, max_bytes=round(self.max_mb * 1e6), version=package_version(),
                      err=err)
        trace.attach(runner)
        print(f"trace: {len(signals)} signals to {', '.join(str(p) for p in self.paths)}", file=err or sys.stderr)
        return trace


def package_version() -> str:
    """vmehil's installed version, for the files' headers (a trace's, the black box's)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("vmehil")
    except PackageNotFoundError:  # a source tree never installed
        return "(not installed)"


def list_signals(system: Any, names: Sequence[str], *, truth: bool | None = None) -> int:
    """``--trace list``: the signal names of a loop of joints ``names`` on ``system``, with their
    units and meanings, on stdout."""
    from vmehil.scope.sources import catalog_of

    print(catalog_of(system, names, truth=truth).listing())
    return 0


def list_rig_signals(rig: Any, *, seed: int) -> int:
    """``--trace list`` on a command that has not built its rig yet (``run``, ``console``): the
    rig's emulated build, listed with every joint, then closed."""
    from vmehil.rig_setup.system import build_emulated_rig

    system = build_emulated_rig(rig, seed=seed)
    try:
        return list_signals(system, [j.name for j in rig.joints])
    finally:
        system.close()


def start_on_plant(options: TraceOptions, link: Any, rig: Any, *, seed: int) -> Any:
    """Trace a coordinator's plant exchanges (``vmehil coordinate``): the nets the commands and
    answers carry and the plant's truth, one row per plant step; ``None`` without ``--trace``."""
    if not options.wanted:
        return None
    assert options.spec is not None
    from vmehil.scope.sources import Sampler, plant_catalog, tap_exchanges
    from vmehil.scope.trace import Trace

    signals = plant_catalog(rig).select(options.spec)
    sampler = Sampler(signals, round(rig.period_s * 1e9))
    trace = Trace(sampler, options.paths, meta={"rig": rig.name, "spec": options.spec, "period_s": repr(rig.period_s),
                                                "seed": str(seed), "source": "plant steps"},
                  max_bytes=round(options.max_mb * 1e6), version=package_version())
    sampler.on_close = tap_exchanges(link, signals, rig, trace.write_row)
    print(f"trace: {len(signals)} signals to {', '.join(str(p) for p in options.paths)}", file=sys.stderr)
    return trace


# --- as a `vmehil run` extension (vmehil.commands.run.RUN_EXTENSIONS) ----------------------------
class RunNeeds(Protocol):
    """What the trace reads of ``vmehil run``'s options."""

    @property
    def trace(self) -> TraceOptions: ...

    @property
    def seed(self) -> int: ...


class Attached:
    """A started trace as a run's attachment: closed after the run, its summary in the JSON."""

    def __init__(self, trace: Any) -> None:
        self.trace = trace

    def close(self) -> None:
        self.trace.close()

    def add_to_summary(self, summary: dict[str, Any]) -> None:
        summary["trace"] = self.trace.summary()


def attach(options: RunNeeds, system: Any, loop: Any, runner: Any, prepared: Any) -> Attached | None:
    trace = options.trace.start(system, loop, runner, rig=system.rig.name, seed=options.seed)
    return None if trace is None else Attached(trace)
