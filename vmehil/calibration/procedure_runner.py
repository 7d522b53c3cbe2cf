"""Run calibration procedures: results table against tolerances, one write.

:func:`run_procedures` runs the named procedures in order on one context. After each
successful procedure its entries are merged into ``ctx.store`` (so ``dac`` measures with the
``adc`` result, and the servo loop of ``pot`` runs with the amplifier and encoder results).
The file is written once, at the end, and only if every procedure ran to completion and
passed (or ``write_on_fail`` is set): a procedure that raises or is interrupted leaves the old
file in force. When no entry changed (``friction`` writes none) nothing is written: no file is
rewritten with only a new timestamp, and no header-only file is created.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from vmehil.calibration.base import CalibrationContext, Procedure, ProcedureResult
from vmehil.calibration.procedures import ALL, PROCEDURES, procedures_for_all
from vmehil.calibration.store import CalibrationStore
from vmehil.errors import CliError, VmehilError


@dataclass
class ProcedureRunOutcome:
    results: list[ProcedureResult] = field(default_factory=list)
    written: Path | None = None
    #: where the file that ``written`` replaced was kept (``.prev``); None when there was none
    previous: Path | None = None
    error: str | None = None
    #: a typed abort's own sentence (ours: a ``VmehilError``), without the procedure and the class
    #: ``error`` puts before it; None when nothing aborted or the error was not ours (a bug)
    reason: str | None = None
    #: every procedure passed but none changed an entry (``friction`` writes none): nothing written
    unchanged: bool = False

    @property
    def passed(self) -> bool:
        return self.error is None and all(r.passed for r in self.results)

    def as_dict(self) -> dict[str, Any]:
        return {"passed": self.passed, "written": str(self.written) if self.written else None,
                "unchanged": self.unchanged, "error": self.error,
                "procedures": {r.procedure: r.as_dict() for r in self.results}}


def _same_entries(a: CalibrationStore, b: CalibrationStore) -> bool:
    """True when ``a`` and ``b`` would write the same file apart from its ``written`` timestamp."""
    return replace(a, written="-").to_toml() == replace(b, written="-").to_toml()


def resolve_procedure_names(name: str) -> list[str]:
    """``all`` → every procedure of ``calibrate all`` in its order; otherwise the one name."""
    if name == ALL:
        return [p.name for p in procedures_for_all()]
    if name not in PROCEDURES:
        raise CliError(f"unknown calibration procedure {name!r}; choose from {ALL}, {', '.join(PROCEDURES.names())}")
    return [name]


def procedure_results_table(results: list[ProcedureResult]) -> str:
    """Plain-text table of every check: item, value, tolerance, pass/FAIL."""
    rows = [("procedure", "item", "value", "tolerance", "result")]
    for r in results:
        for c in r.checks:
            tol = ("true" if c.kind == "bool" else (f"≤ {c.limit:.4g}" if c.kind == "max" else f"≥ {c.limit:.4g}"))
            val = ("yes" if c.value else "no") if c.kind == "bool" else f"{c.value:+.4g}"
            unit = f" {c.unit}" if c.unit and c.kind != "bool" else ""
            rows.append((r.procedure, c.item, val + unit, tol + unit, "pass" if c.passed else "FAIL"))
        for s in r.skipped:
            rows.append((r.procedure, s, "", "", "skipped"))
    widths = [max(len(row[i]) for row in rows) for i in range(5)]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def run_procedures(ctx: CalibrationContext, names: list[str], *, out_path: str | Path | None,
                   write_on_fail: bool = False, before_write: Callable[[], None] | None = None,
                   factories: Mapping[str, Callable[[], Procedure]] | None = None) -> ProcedureRunOutcome:
    """Run ``names`` in order; merge results into ``ctx.store``; write ``out_path`` once at the end.

    ``factories`` builds some procedures differently from the table (``--points`` of ``pot``)."""
    outcome = ProcedureRunOutcome()
    base_store = ctx.store
    merged = base_store
    for k, name in enumerate(names):
        factory = (factories or {}).get(name) or PROCEDURES[name].factory
        proc = factory()
        ctx.say(f"[{k + 1}/{len(names)}] {name}: {proc.title}")
        try:
            result = proc.run(ctx)
        except Exception as e:
            outcome.error = f"{name}: {type(e).__name__}: {e}"
            outcome.reason = str(e) if isinstance(e, VmehilError) else None
            ctx.say(f"  {name} failed: {e}; the calibration file is left unchanged")
            return outcome
        outcome.results.append(result)
        if result.update is not None:
            merged = merged.merged(result.update)
            ctx.store = merged
            ctx.refresh_positioner()
        ctx.say(f"  {name}: {'pass' if result.passed else 'FAIL'} "
                f"({sum(c.passed for c in result.checks)}/{len(result.checks)} checks)")
    ctx.say("")
    ctx.say(procedure_results_table(outcome.results))
    if out_path is not None and outcome.error is None and _same_entries(merged, base_store):
        # nothing to write: rewriting the file would change its timestamp only, and with no file
        # yet it would create one with a header and no entries
        outcome.unchanged = True
        state = "unchanged" if Path(out_path).exists() else "not created"
        ctx.say(f"no calibration entry changed: {out_path} {state}")
    elif out_path is not None and (outcome.passed or write_on_fail):
        if before_write is not None:
            before_write()
        outcome.written = merged.save(out_path)
        outcome.previous = merged.previous
        kept = f"previous kept as {outcome.previous.name}" if outcome.previous else "there was no previous file"
        ctx.say(f"calibration written to {outcome.written} ({kept})")
    elif out_path is not None:
        ctx.say(f"checks failed: {out_path} left unchanged (use --write-on-fail to write anyway)")
    return outcome
