"""The end of a `vmehil run`, emulated or on a real bus: summary, table, JSON and report, and the
exit status — one writer for both paths (a real-bus run wrote nothing, #30)."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from servo.interrupts import INTERRUPTS, interrupt_exit_status
from vmehil.exit_status import EXIT_FAULT, EXIT_STOP_INCOMPLETE
from vmehil.option_groups.realtime_options import realtime_settings_summary
from vmehil.writers.files import write_json

if TYPE_CHECKING:
    from vmehil.commands.run_options import RunOptions


def finish_run(opts: RunOptions, system, loop, runner, rig, attached: list, ended_by: BaseException | None) -> int:
    """Summary, table, JSON and report of a run that has ended; its exit status."""
    from servo.runner import RealtimeRunner
    from vmehil.reports.blackbox import save_blackbox
    from vmehil.reports.run_report import final_stop_line, summarize, table, write_report

    timing = runner.timing.summary(system.rig.period_s) if isinstance(runner, RealtimeRunner) else None
    summary = summarize(loop, rig=system.rig.name, seed=opts.seed, realtime=opts.realtime,
                        overruns=runner.overruns, timing=timing)
    for a in attached:
        add = getattr(a, "add_to_summary", None)
        if add is not None:
            add(summary)
    # every stop (fault, exception, signal, end) ends here: the last seconds before it, named in the JSON
    save_blackbox(loop, rig=system.rig.name, choice=opts.scope.blackbox, report=opts.report,
                  final_stop=summary.get("final_stop"))
    rt_settings = realtime_settings_summary(runner)
    if rt_settings is not None:
        summary["realtime_settings"] = rt_settings
        print(f"real-time settings: {rt_settings['described']}", file=sys.stderr)
    print(table(summary))
    stop_line = final_stop_line(loop.final_stop)
    if stop_line is not None:
        print(stop_line)
    if timing:
        print(f"timing: compute p50 {timing['compute_p50_ms']:.3f} ms, p99 {timing['compute_p99_ms']:.3f} ms; "
              f"lateness p99 {timing['lateness_p99_ms']:.3f} ms, max {timing['lateness_max_ms']:.3f} ms")
    if opts.json:
        write_json(opts.json, summary)
    if opts.report:
        files = write_report(loop, summary, opts.report)
        print(f"report: {len(files)} files in {opts.report}")
    system.close()
    return run_exit_status(loop, ended_by)


def run_exit_status(loop, ended_by: BaseException | None) -> int:
    """The documented exit statuses (docs/faults.md): 4 a safe stop that its read-back could not
    confirm, 130/143 ended by SIGINT/SIGTERM, 1 a fault stopped the run, 0 it ran to the end."""
    if loop.stop_incomplete:
        return EXIT_STOP_INCOMPLETE
    if ended_by is None:
        ended_by = getattr(loop, "interrupted_by", None)  # a signal held by a stop or while writing
    if isinstance(ended_by, INTERRUPTS):
        return interrupt_exit_status(ended_by)
    return EXIT_FAULT if loop.fault is not None else 0
