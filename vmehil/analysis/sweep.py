"""Gain sweeps: many gain sets, each analysed (sampled margins) and simulated (full stack).

Gain sets come from a grid (:func:`parse_grid`, ``"kp=80:140:4,kv=30:70:5"``: 4 values from 80 to
140 and 5 from 30 to 70, all combinations; ``"kvi=800;1000;1200"`` lists values; a single value
fixes a gain) or a list (:func:`load_gains_file`, CSV with a header naming some of kp, kpi, kv,
kvi, or TOML ``[[gains]]`` tables). Gains not given keep the joint's rig values.

Each point (:func:`evaluate_point`, a plain top-level function so it pickles to any worker): the
verdict of :mod:`servo.gain_guard` (columns ``stable`` and ``unstable_reason``: an unstable point
is classified, not refused — only values no gain may have, e.g. negative, refuse the sweep);
sampled and continuous margins; unless the guard refuses the point or the sampled linear loop is
unstable, one full-stack run with the integrators kept on (switch-off disabled unless the task asks
for it, so the limit cycle the gains produce shows):
limit-cycle amplitude and frequency (as ``vmehil run``), tracking error of the standard move and
settling time after it (:mod:`vmehil.analysis.simulate`).

Execution (:func:`evaluate_points`): an engine of :mod:`vmehil.analysis.parallel` — by default
the local process pool of ``jobs`` workers, or Dask (:class:`vmehil.analysis.dask_engine.DaskEngine`,
``--engine dask``). A task carries everything a worker needs as content: the rig file's TEXT
(:attr:`SweepTask.rig`, parsed once on the client, with a tolerance sample's drawn plant values
applied, and the servo's typed settings, :attr:`SweepTask.servo`: nothing is read from a disk on
the worker, nothing re-parsed per point), the gains, the simulation settings with their seed, and for a tolerance
study the drawn plant values (:mod:`vmehil.analysis.tolerance`). So every engine gives the same
rows. Results are handed to ``on_result`` as they complete; the CLI rewrites CSV and JSON
atomically at most once a second (:class:`BatchedWrites`: a 400-point sweep rewrote them 400
times, O(n²) work in the parent that competes with the workers), and at the end or on
interruption with every row, so an interrupted sweep (SIGINT) leaves files with every completed
row, and ``--resume`` computes only the missing points. On interruption the running tasks are
told to stop (polled every tick), pending points are cancelled and :class:`SweepInterrupted`
carries the finished rows.
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import math
import time
import tomllib
from collections.abc import Callable, Iterable
from concurrent.futures import Executor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hal.config import ConfigError, ConfigTable, load_toml, read_limited
from servo.control.errors import GainError, GainSyntaxError
from servo.control.gains import GAIN_NAMES, Gains, gain_items
from servo.gain_guard import check_values
from servo.rig import RigSpec, rig_from_table
from servo.settings import ServoSettings
from vmehil.analysis.parallel import Engine, EngineError, ParallelInterrupted, run_parallel, stop_requested
from vmehil.analysis.simulate import SimSettings
from vmehil.errors import VmehilError

DEFAULT_GRID = "kp=80:140:3,kvi=600:1400:3"  #: 9 points: about 40 s on 2 busy cores

#: CSV columns, in order.
COLUMNS = ("index", *GAIN_NAMES, "status", "stable", "unstable_reason", "sampled_stable", "phase_margin_deg",
           "gain_margin_db",
           "crossover_hz", "bandwidth_hz", "continuous_phase_margin_deg", "lc_amplitude_deg", "lc_frequency_hz",
           "lc_amplitude_pot_deg", "rms_tracking_error_deg", "max_tracking_error_deg", "max_tracking_error_true_deg",
           "settling_time_s",
           "final_error_deg", "fault", "wall_s", "switch_off", "sample")


class SweepError(VmehilError, ValueError):
    """A malformed grid or gains file."""


class SweepResultError(EngineError):
    """A worker's result is not a row of this sweep (:func:`check_row`): refused, the sweep stops,
    the rows that finished before it are kept."""


class SweepInterrupted(VmehilError):
    """The sweep was interrupted; ``rows`` holds the points that finished."""

    def __init__(self, rows: list[dict[str, Any]]) -> None:
        super().__init__(f"sweep interrupted after {len(rows)} point(s)")
        self.rows = rows


# ------------------------------------------------------------------------- gain sets


#: the most points one sweep runs (each is a full-stack simulation of seconds; 10⁵ is hours of work):
#: the grid's size, and the product gain sets × switch-off modes × tolerance samples
#: (:func:`check_sweep_size`)
MAX_GRID_POINTS = 100_000


def check_sweep_size(gain_sets: int, modes: int = 1, samples: int = 1) -> int:
    """The number of points of a sweep, refused (:class:`SweepError`, one line) beyond
    :data:`MAX_GRID_POINTS` — checked on the product before any task is made, so that no factor
    within its own limit makes the whole unbounded (10⁵ gain sets × 10⁵ samples was 10¹⁰ tasks)."""
    total = gain_sets * modes * samples
    if total > MAX_GRID_POINTS:
        parts = [f"{gain_sets:,} gain sets"] + ([f"{modes} switch-off modes"] if modes > 1 else []) + \
            ([f"{samples:,} samples"] if samples > 1 else [])
        raise SweepError(f"the sweep has {' × '.join(parts)} = {total:,} points; at most {MAX_GRID_POINTS:,} "
                         "are run in one sweep (each is a full-stack simulation): use fewer values or samples")
    return total


def _axis(name: str, text: str) -> list[float]:
    text = text.strip()
    try:
        if ":" in text:
            parts = text.split(":")
            if len(parts) != 3:
                raise SweepError(f"grid axis {name}={text!r}: write start:stop:count, e.g. {name}=80:140:4")
            a, b, n = float(parts[0]), float(parts[1]), int(parts[2])
            if not 1 <= n <= MAX_GRID_POINTS:
                raise SweepError(f"grid axis {name}={text!r}: the count must be within 1..{MAX_GRID_POINTS}")
            vals = [a] if n == 1 else list(np.linspace(a, b, n))
        else:
            vals = [float(v) for v in text.split(";") if v.strip()]
    except ValueError as e:
        if isinstance(e, SweepError):
            raise
        raise SweepError(f"grid axis {name}={text!r} is not start:stop:count or v1;v2;… numbers") from None
    if not vals:
        raise SweepError(f"grid axis {name} has no values")
    vals = [float(v) for v in vals]
    for v in vals:
        check_values({name: v})  # no gain may be negative, NaN, subnormal, beyond the limits: refuse the grid
    return vals


def parse_grid(specs: str | Iterable[str]) -> dict[str, list[float]]:
    """Grid axes from ``"kp=80:140:4,kv=30:70:5"`` text (or several such strings)."""
    if isinstance(specs, str):
        specs = [specs]
    axes: dict[str, list[float]] = {}
    for spec in specs:
        try:
            items = gain_items(spec)  # the one gain-text grammar; the values are axes, parsed here
        except GainSyntaxError as e:
            raise SweepError(f"grid: {e}; an axis is gain=start:stop:count or gain=v1;v2;…, e.g. kp=80:140:4") from e
        for key, val, _token in items:
            if key in axes:
                raise SweepError(f"gain {key} appears twice in the grid")
            axes[key] = _axis(key, val)
    if not axes:
        raise SweepError("the grid is empty; give e.g. --grid kp=80:140:4,kv=30:70:5")
    total = math.prod(len(v) for v in axes.values())
    if total > MAX_GRID_POINTS:
        raise SweepError(f"the grid has {total:,} points; at most {MAX_GRID_POINTS:,} are swept in one run "
                         "(each point is a full-stack simulation): use fewer values per axis")
    return axes


def grid_points(axes: dict[str, list[float]], base: Gains[float]) -> list[dict[str, float]]:
    """Every combination of the axes (in order, the last axis fastest) over the ``base`` gains."""
    names = list(axes)
    return [base.replace(**dict(zip(names, combo, strict=True))).as_dict()
            for combo in itertools.product(*(axes[k] for k in names))]


def load_gains_file(path: str | Path, base: Gains[float]) -> list[dict[str, float]]:
    """Gain sets from a CSV (header with some of kp, kpi, kv, kvi) or TOML (``[[gains]]``) file."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"gains file {p} does not exist")
    rows: list[dict[str, Any]] = []
    if p.suffix.lower() == ".toml":
        root = load_toml(p)
        try:
            tables = root.tables("gains")
        except ConfigError as e:
            raise SweepError(f"{p}: expected [[gains]] tables with kp/kpi/kv/kvi ({e})") from None
        rows = [dict(t.data) for t in tables]
    else:
        try:
            text = read_limited(p, what="a gains file").decode("utf-8")
        except UnicodeDecodeError as e:
            raise SweepError(f"{p}: not a UTF-8 CSV file ({e})") from None
        with io.StringIO(text, newline="") as f:
            reader = csv.DictReader(f)
            if not reader.fieldnames:
                raise SweepError(f"{p}: empty CSV; the first line names the gains (kp,kpi,kv,kvi)")
            unknown = [c for c in reader.fieldnames if c.strip().lower() not in GAIN_NAMES]
            if unknown:
                raise SweepError(f"{p}: unknown column(s) {', '.join(unknown)}; use kp, kpi, kv, kvi")
            for line, r in enumerate(reader, start=2):
                try:
                    rows.append({k.strip().lower(): float(v) for k, v in r.items() if v not in (None, "")})
                except ValueError:
                    raise SweepError(f"{p} line {line}: {r} has a value that is not a number") from None
    if not rows:
        raise SweepError(f"{p}: no gain sets")
    out = []
    for i, r in enumerate(rows):
        try:
            out.append(Gains.from_mapping(check_values(r), base=base).as_dict())
        except GainError as e:
            raise SweepError(f"{p} gain set {i + 1}: {e}") from e
    return out


# ------------------------------------------------------------------------ one point


@dataclass(frozen=True)
class SweepTask:
    """One point to evaluate: the joint (rig file path, 1-based number), full gain set, settings,
    and where the plant runs (``link_factory``, see :func:`vmehil.analysis.simulate.simulate`; it is
    pickled to the worker, so a CAN factory there opens its own bus — and its own node on
    ``virtual``). ``rig``: the parsed rig (:func:`task_rig`: a tolerance sample's drawn plant
    values already applied; then ``rig_path`` only names it, no worker reads it); ``servo``: the
    servo's typed settings of the rig (:func:`servo.settings.servo_settings`, parsed once on the
    client; the point's ``gains`` are applied to ``joint`` on the worker); ``switch_off``: the
    integrator switch-off of the simulated run; ``plant``: the drawn plant values (SI, by
    :data:`vmehil.analysis.tolerance.PARAMETERS` name, for the row: they are in ``rig``),
    applied to the emulated plant only; ``sample``: its number."""

    index: int
    rig_path: str
    joint: int
    gains: dict[str, float]
    sim: SimSettings = field(default_factory=SimSettings)
    simulate: bool = True
    link_factory: Callable[[str, int], Any] | None = None  #: picklable; None = in-process plant
    rig: RigSpec | None = None
    servo: ServoSettings | None = None
    switch_off: bool = False
    plant: dict[str, float] = field(default_factory=dict)
    sample: int | None = None


def rig_text(path: str | Path) -> str:
    """The content of a rig file (a preset name or a path), as a task carries it."""
    from emulators.presets import resolve_rig

    return resolve_rig(path).read_text(encoding="utf-8")


def text_sha256(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def task_rig(text: str, path: str | Path, joint: int = 1, plant: dict[str, float] | None = None) -> RigSpec:
    """The rig a task carries: parsed from its ``text`` (``path`` names it in errors), with a
    tolerance sample's drawn ``plant`` values applied to ``joint``'s plant tables (the servo's
    tables are never touched)."""
    data = tomllib.loads(text)
    if plant:
        from vmehil.analysis.tolerance import apply_plant_values

        data = apply_plant_values(data, joint, plant)
    return rig_from_table(ConfigTable(data, str(path)), path)


def task_columns(task: SweepTask) -> tuple[str, ...]:
    """The row's columns: :data:`COLUMNS`, then one per varied plant parameter."""
    from vmehil.analysis.tolerance import PARAMETERS

    return (*COLUMNS, *(PARAMETERS[k].column for k in task.plant))


def evaluate_point(task: SweepTask) -> dict[str, Any]:
    """Margins and (unless unstable) a full-stack run for one gain set; a flat, JSON/CSV-ready row."""
    t0 = time.perf_counter()
    if task.plant and task.rig is None:
        raise ValueError("a sweep task with plant values carries its rig (task_rig)")
    row = _evaluate(task)
    row["wall_s"] = time.perf_counter() - t0
    return row


def _evaluate(task: SweepTask) -> dict[str, Any]:
    row, jp = _prepare(task)
    if jp is None:
        return _columns(row, task)
    from vmehil.analysis.simulate import simulate

    stop = stop_requested()
    r = simulate(jp, switch_off=task.switch_off, settings=task.sim, traces=False, stop=stop,
                 link_factory=task.link_factory)
    return _complete(row, task, r, stop is not None and stop())


def _columns(row: dict[str, Any], task: SweepTask) -> dict[str, Any]:
    return {k: row.get(k) for k in task_columns(task)}


def _prepare(task: SweepTask) -> tuple[dict[str, Any], Any]:
    """A point's row before its run: gains, margins, the guard's verdict; and the joint to simulate
    (``None``: not simulated, the row's ``status`` says why)."""
    from vmehil.analysis.rigparams import load_joint
    from vmehil.analysis.tolerance import PARAMETERS
    from vmehil.analysis.tuning import margins_summary

    row: dict[str, Any] = {"index": task.index, **{k: float(task.gains[k]) for k in GAIN_NAMES},
                           "switch_off": task.switch_off, "sample": task.sample,
                           **{PARAMETERS[k].column: float(v) for k, v in task.plant.items()}}
    jp = load_joint(task.rig if task.rig is not None else task.rig_path, task.joint, gains=task.gains,
                    servo=task.servo)
    # the servo's own verdict, for the loop simulated here (integrators on; switch-off as the task says)
    verdict = jp.verdict(switch_off=task.switch_off)
    m = margins_summary(jp.cfg)
    s, c = m["sampled"], m["continuous"]
    row.update({"stable": verdict.ok, "unstable_reason": None if verdict.ok else verdict.reason,
                "sampled_stable": bool(s["stable"]), "phase_margin_deg": s["phase_margin_deg"],
                "gain_margin_db": s["gain_margin_db"], "crossover_hz": s["crossover_hz"],
                "bandwidth_hz": s["bandwidth_hz"], "continuous_phase_margin_deg": c["phase_margin_deg"]})
    row.update(dict.fromkeys(_SIM_KEYS))
    row["fault"] = None
    if not verdict.ok:
        row["status"] = f"{verdict.kind} (servo.gain_guard): not simulated"
    elif not s["stable"]:
        row["status"] = "unstable (sampled linear loop with the rig's sensor and amplifier lags): not simulated"
    elif not task.simulate:
        row["status"] = "margins only"
    else:
        return row, jp
    return row, None


_SIM_KEYS = ("lc_amplitude_deg", "lc_frequency_hz", "lc_amplitude_pot_deg", "rms_tracking_error_deg",
             "max_tracking_error_deg", "max_tracking_error_true_deg", "settling_time_s", "final_error_deg")


def _complete(row: dict[str, Any], task: SweepTask, r: dict[str, Any], interrupted: bool) -> dict[str, Any]:
    """The row of a simulated point from its run's figures ``r``."""
    if interrupted:
        row["status"] = "interrupted"
        return _columns(row, task)
    row.update({"lc_amplitude_deg": r["amplitude_deg"], "lc_frequency_hz": r["frequency_hz"],
                "lc_amplitude_pot_deg": r["amplitude_pot_deg"],
                "rms_tracking_error_deg": r["rms_tracking_error_servo_deg"],
                "max_tracking_error_deg": r["max_tracking_error_servo_deg"],
                "max_tracking_error_true_deg": r["max_tracking_error_deg"],
                "settling_time_s": r["settling_time_s"], "final_error_deg": r["final_error_deg"]})
    if r["fault"]:
        row["fault"] = f"{r['fault']['cause']} at {r['fault']['time_s']:.2f} s"
        row["status"] = "fault"
    else:
        row["status"] = "ok"
    return _columns(row, task)


def evaluate_batch(tasks: list[SweepTask]) -> list[dict[str, Any]]:
    """:func:`evaluate_point` for every task, the full-stack runs in lockstep in this process
    (:mod:`vmehil.analysis.batch`): each row equals the one :func:`evaluate_point` makes, ``wall_s``
    aside (the batch's wall time shared equally among its points)."""
    from vmehil.analysis.batch import collector_spared, simulate_batch
    from vmehil.analysis.simulate import SimRun

    t0 = time.perf_counter()
    for task in tasks:
        if task.plant and task.rig is None:
            raise ValueError("a sweep task with plant values carries its rig (task_rig)")
        if task.link_factory is not None:
            raise ValueError("a batched sweep runs its plants in-process (no --plant can)")
    prepared = [_prepare(task) for task in tasks]
    rows: list[dict[str, Any] | None] = [None if jp is not None else _columns(row, task)
                                         for (row, jp), task in zip(prepared, tasks, strict=True)]
    todo = [i for i, (_row, jp) in enumerate(prepared) if jp is not None]
    stop = stop_requested()
    runs: list[Any] = []
    with collector_spared() as built:  # half of a build's time is the collector's otherwise
        try:
            for i in todo:
                runs.append(SimRun(prepared[i][1], tasks[i].switch_off, tasks[i].sim))
        except BaseException:
            for r in runs:
                r.close()
            raise
        built()
        figures = simulate_batch(runs, stop=stop)
    interrupted = stop is not None and stop()
    for i, r in zip(todo, figures, strict=True):
        rows[i] = _complete(prepared[i][0], tasks[i], r, interrupted)
    wall = (time.perf_counter() - t0) / max(1, len(tasks))
    out = []
    for row in rows:
        assert row is not None
        row["wall_s"] = wall
        out.append(row)
    return out


# ------------------------------------------------------------------------ its result

_TEXT_COLUMNS = frozenset({"status", "unstable_reason", "fault"})
_BOOL_COLUMNS = frozenset({"stable", "sampled_stable"})
#: measured columns that cannot be negative (amplitudes, frequencies, errors as magnitudes, times)
_NON_NEGATIVE = frozenset({"crossover_hz", "bandwidth_hz", "lc_amplitude_deg", "lc_frequency_hz",
                           "lc_amplitude_pot_deg", "rms_tracking_error_deg", "max_tracking_error_deg",
                           "max_tracking_error_true_deg", "settling_time_s", "wall_s"})
MAX_TEXT_CHARS = 1000  #: the longest status, reason or fault text a row may carry


def check_row(row: Any, task: SweepTask) -> dict[str, Any]:
    """``row`` if it is the row :func:`evaluate_point` makes for ``task``, else
    :class:`SweepResultError` saying why: a dict of exactly the task's columns; its ``index``,
    gains, ``switch_off``, ``sample`` and plant values those of the task (so a row is never
    counted for another point, and a worker cannot put values in the sweep that it was not asked
    for); ``status`` a text; every measured value ``None`` or a finite number (the margins are
    ``None`` where a margin does not exist, never NaN or ∞), the magnitudes ≥ 0. A worker runs the
    same code (the identity check), but its process is not ours: a preload or a broken worker can
    rewrite what it sends."""
    def refuse(why: str) -> SweepResultError:
        return SweepResultError(f"the result for point {task.index} was refused: {why}")

    if not isinstance(row, dict):
        raise refuse(f"not a row but a {type(row).__name__}")
    columns = task_columns(task)
    if set(row) != set(columns):
        missing, extra = sorted(set(columns) - set(row)), sorted(map(str, set(row) - set(columns)))
        raise refuse("columns " + "; ".join(x for x in (missing and f"missing {', '.join(missing)}",
                                                        extra and f"unknown {', '.join(extra)}") if x))
    from vmehil.analysis.tolerance import PARAMETERS

    expected: dict[str, Any] = {"index": task.index, **{k: float(task.gains[k]) for k in GAIN_NAMES},
                                "switch_off": task.switch_off, "sample": task.sample,
                                **{PARAMETERS[k].column: float(v) for k, v in task.plant.items()}}
    for k, want in expected.items():
        got = row[k]
        if type(got) is not type(want) or got != want:
            raise refuse(f"{k} = {got!r}, but the point has {want!r}")
    for k in columns:
        if k in expected:
            continue
        v = row[k]
        if k in _TEXT_COLUMNS:
            if not (isinstance(v, str) or (v is None and k != "status")) or (v is not None and len(v) > MAX_TEXT_CHARS):
                raise refuse(f"{k} = {_short(v)} is not a text")
        elif k in _BOOL_COLUMNS:
            if not (v is None or isinstance(v, bool)):
                raise refuse(f"{k} = {_short(v)} is not true/false")
        elif v is not None:
            if not (isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)):
                raise refuse(f"{k} = {_short(v)} is not a finite number")
            if k in _NON_NEGATIVE and v < 0:
                raise refuse(f"{k} = {v!r} is negative")
    return row


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


# --------------------------------------------------------------------------- running


def evaluate_points(tasks: list[SweepTask], *, executor: Executor | None = None, jobs: int | None = None,
                    engine: Engine | None = None, done: Iterable[dict[str, Any]] = (),
                    on_result: Callable[[dict[str, Any], list[dict[str, Any]]], None] | None = None,
                    on_idle: Callable[[], None] | None = None, batch: int = 1) -> list[dict[str, Any]]:
    """Evaluate ``tasks`` in parallel (:func:`run_parallel`); returns the rows sorted by index.

    ``batch``: points per engine task; above 1 each task is :func:`evaluate_batch` of up to that
    many points (their runs in lockstep in one worker; the same rows), 1 is one point per task.

    ``engine``: where (:mod:`vmehil.analysis.parallel`; default a process pool of ``jobs`` workers,
    or over ``executor``, any :class:`concurrent.futures.Executor` the caller owns). ``done``: rows
    already computed (``--resume``): the tasks of their indices are not run again and they are part
    of the rows handed on. ``on_result(row, rows_so_far)`` is called in the calling thread as each
    point completes, once per index; ``on_idle()`` at least every 0.1 s while points run
    (:func:`run_parallel`). A ``KeyboardInterrupt`` (SIGINT) stops the workers, cancels
    the rest and raises :class:`SweepInterrupted` with the finished rows. Every result is checked
    (:func:`check_row`) against the task it was computed for: a refused one stops the sweep with
    :class:`SweepResultError`, after every good row of the same batch was handed on.
    """
    by_index: dict[int, dict[str, Any]] = {r["index"]: r for r in done}
    todo = [t for t in tasks if t.index not in by_index]

    def rows() -> list[dict[str, Any]]:
        return [by_index[i] for i in sorted(by_index)]

    def got(position: int, row: Any) -> None:
        row = check_row(row, todo[position])  # the row of that point, and sane values
        if row["index"] in by_index:  # a point is counted once, whatever the engine reports
            return
        by_index[row["index"]] = row
        if on_result is not None:
            on_result(row, rows())

    try:
        if batch <= 1:
            run_parallel(evaluate_point, todo, executor=executor, jobs=jobs, engine=engine, on_result=got,
                         finished=_finished, on_idle=on_idle)
        else:
            from vmehil.analysis.batch import split

            batches = split(range(len(todo)), batch)

            def got_batch(position: int, result: Any) -> None:
                first = batches[position]
                if not isinstance(result, list) or len(result) != len(first):
                    raise SweepResultError(f"the result for batch {position + 1} is not a list of "
                                           f"{len(first)} rows")
                for i, row in zip(first, result, strict=True):
                    if _finished(row):  # a point the interruption cut short is left for --resume
                        got(i, row)

            run_parallel(evaluate_batch, [[todo[i] for i in b] for b in batches], executor=executor, jobs=jobs,
                         engine=engine, on_result=got_batch, finished=lambda r: r is not None, on_idle=on_idle)
    except ParallelInterrupted:
        raise SweepInterrupted(rows()) from None
    return rows()


def _finished(row: Any) -> bool:
    """Not cut short by an interruption (``None``: never started; an ``interrupted`` row). Anything
    else is a result, checked by :func:`check_row`."""
    return row is not None and not (isinstance(row, dict) and row.get("status") == "interrupted")


# ------------------------------------------------------------------------------ files


class BatchedWrites:
    """Results written at most every ``every_s`` seconds: :meth:`result` after each point (writes
    when the last write is that old), :meth:`idle` while points run (writes rows still waiting
    once it is), :meth:`flush` at the end (writes what waits). ``write(rows)`` gets every row so
    far. A completed point is on disk within ``every_s`` (+ the engine's 0.1 s poll) of its end."""

    def __init__(self, write: Callable[[list[dict[str, Any]]], None], every_s: float = 1.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._write = write
        self.every_s = every_s
        self._clock = clock
        self._last = clock()
        self._rows: list[dict[str, Any]] | None = None  #: rows not yet written
        self.writes = 0

    def result(self, rows: list[dict[str, Any]]) -> None:
        self._rows = rows
        self.idle()

    def idle(self) -> None:
        if self._rows is not None and self._clock() - self._last >= self.every_s:
            self.flush()

    def flush(self) -> None:
        if self._rows is None:
            return
        rows, self._rows = self._rows, None
        self._write(rows)
        self.writes += 1
        self._last = self._clock()



def rows_csv(rows: list[dict[str, Any]], columns: Iterable[str] = COLUMNS) -> str:
    """CSV of ``rows``: ``columns``, then any other key the rows have (a tolerance study's plant
    values), in order of appearance."""
    cols = list(columns)
    for r in rows:
        cols += [k for k in r if k not in cols]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else _csv_value(r[k])) for k in cols})
    return buf.getvalue()


def _csv_value(v: Any) -> Any:
    if isinstance(v, float):
        return f"{v:.6g}" if math.isfinite(v) else ""
    return v


def settings_dict(sim: SimSettings) -> dict[str, Any]:
    return asdict(sim)
