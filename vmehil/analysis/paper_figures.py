"""The README's "What it reproduces" table, re-run: each JPL figure from the command printed next
to it, on a fresh clone's state, in the README's order (``vmehil reproduce``, ``make reproduce``).

Every step is the ``vmehil`` command a user types, run as its own process in one temporary
directory (nothing in the caller's directory is read or written) with ``--json`` added to read
its figures and ``--quiet``; ``VMEHIL_CALIBRATION_DIR`` points into the temporary directory, so
the steps start with **no calibration file**, as on a fresh clone:

1. ``vmehil run --no-integrator-switch-off`` — the limit cycle (uncalibrated pots);
2. ``vmehil run`` — the switch-off cure (uncalibrated pots);
3. ``vmehil calibrate friction --joint 1`` — running torque, ripple, breakout (writes no file);
4. ``vmehil calibrate pot --auto`` — the pot residual, pots calibrated from nominal converters
   (``calibrate all`` calibrates the ADCs first and gives a smaller residual; this is the figure
   of ``pot`` alone).

A figure is in the paper's band (:data:`BANDS`) or the command exits 1. The output breakout is
derived (N × the measured input breakout), not measured at the output: said in its row.

The rig is ``jpl-arm`` (every step's default) unless one is given (``vmehil reproduce --rig
jpl-arm-vmic``): then every step names it (:meth:`Step.on_rig`). The bands are the paper's,
whatever the rig: a rig reproduces the paper or it does not.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from emulators.presets import DEFAULT_RIG


@dataclass(frozen=True)
class Step:
    """One command of the table: what the README prints (``argv``) and its JSON file's name."""

    name: str
    argv: tuple[str, ...]
    json_name: str

    @property
    def command(self) -> str:
        return "vmehil " + " ".join(self.argv)

    def on_rig(self, rig: str | None) -> Step:
        """This step on ``rig`` (a preset name, or a file path made absolute: the steps run in a
        temporary directory); None: the default rig, the step as it is."""
        if rig is None:
            return self
        return Step(self.name, (*self.argv, "--rig", rig), self.json_name)


STEPS: tuple[Step, ...] = (
    Step("limit_cycle", ("run", "--no-integrator-switch-off"), "run_no_switch_off.json"),
    Step("switch_off", ("run",), "run.json"),
    Step("friction", ("calibrate", "friction", "--joint", "1"), "friction.json"),
    Step("pot", ("calibrate", "pot", "--auto"), "pot.json"),
)


@dataclass(frozen=True)
class Band:
    """``lo <= value <= hi`` (either bound may be None: open), in ``unit``."""

    quantity: str
    lo: float | None
    hi: float | None
    unit: str

    def holds(self, value: float | None) -> bool:
        if value is None:
            return False
        return (self.lo is None or value >= self.lo) and (self.hi is None or value <= self.hi)

    def text(self) -> str:
        unit = self.unit if self.unit == "°" else " " + self.unit
        if self.lo is None:
            return f"< {self.hi:g}{unit}"
        if self.hi is None:
            return f"> {self.lo:g}{unit}"
        return f"{self.lo:g}–{self.hi:g}{unit}"


@dataclass(frozen=True)
class Figure:
    """One row of the table: the paper's words, the band, the step and how to read the value(s)."""

    key: str
    what: str
    paper: str
    step: str
    bands: tuple[Band, ...]
    read: Callable[[dict[str, Any]], tuple[float | None, ...]]
    show: Callable[[tuple[float | None, ...]], str]
    note: str = ""


def _j1(run: dict[str, Any]) -> dict[str, Any]:
    return run["joints"][0]


def _friction(d: dict[str, Any]) -> dict[str, Any]:
    return d["procedures"]["friction"]


def _fmt(v: float | None, spec: str) -> str:
    return "—" if v is None else format(v, spec)


#: The paper's bands (issue 20): limit cycle 0.5–1.0° at 1–3 Hz; switch-off < 0.1°; running
#: torque 19–29 oz-in with a ripple amplitude of 3–7 oz-in (the paper's ±5); ripple 4–6 Hz;
#: breakout 5–9 oz-in in, 450–750 oz-in out; pot < 3 arcmin.
FIGURES: tuple[Figure, ...] = (
    Figure("limit_cycle", "limit cycle, link 1, paper gains (true angle)",
           "±¾° at 1–3 Hz", "limit_cycle",
           (Band("amplitude", 0.5, 1.0, "°"), Band("frequency", 1.0, 3.0, "Hz")),
           lambda d: (_j1(d)["limit_cycle"]["amplitude_deg"], _j1(d)["limit_cycle"]["frequency_hz"]),
           lambda v: f"±{_fmt(v[0], '.2f')}° at {_fmt(v[1], '.2f')} Hz"),
    Figure("switch_off", "integrator switch-off: link 1 in the hold",
           "cycle removed", "switch_off", (Band("half peak-to-peak", None, 0.1, "°"),),
           lambda d: (_j1(d)["limit_cycle"]["amplitude_deg"],),
           lambda v: f"±{_fmt(v[0], '.3f')}°"),
    Figure("running_torque", "running torque, joint 1 (0.06 Hz, ±0.4 rad)", "24 ± 5 oz-in", "friction",
           (Band("mean", 19.0, 29.0, "oz-in"), Band("ripple amplitude", 3.0, 7.0, "oz-in")),
           lambda d: (_friction(d)["running_torque_oz_in"]["mean"],
                      _friction(d)["running_torque_oz_in"]["ripple_amplitude"]),
           lambda v: f"{_fmt(v[0], '.1f')} ± {_fmt(v[1], '.1f')} oz-in"),
    Figure("ripple", "friction ripple", "≈5 Hz", "friction", (Band("frequency", 4.0, 6.0, "Hz"),),
           lambda d: (_friction(d)["ripple_frequency_hz"],),
           lambda v: f"{_fmt(v[0], '.2f')} Hz"),
    Figure("breakout_input", "breakout, input shaft", "5–9 oz-in", "friction",
           (Band("breakout", 5.0, 9.0, "oz-in"),),
           lambda d: (_friction(d)["breakout_input_oz_in"],),
           lambda v: f"{_fmt(v[0], '.2f')} oz-in"),
    Figure("breakout_output", "breakout, output shaft (DERIVED)", "≈600 oz-in (torque gauge)", "friction",
           (Band("breakout", 450.0, 750.0, "oz-in"),),
           lambda d: (_friction(d)["breakout_output_oz_in"],),
           lambda v: f"{_fmt(v[0], '.0f')} oz-in",
           note="DERIVED, not measured: N × the measured input breakout (the paper used a torque gauge on the "
                "output shaft; the model has no output-side friction, docs/friction.md)"),
    Figure("pot", "pot residual, 9 points (worst joint rms)", "3 arcmin ≈ 1 mm",
           "pot", (Band("residual rms", None, 3.0, "arcmin"),),
           lambda d: (d["procedures"]["pot"]["residual_rms_arcmin"],),
           lambda v: f"≤ {_fmt(v[0], '.2f')} arcmin rms"),
)


def bands_text(bands: tuple[Band, ...]) -> str:
    """The band column: an amplitude *at* a frequency; two figures of one unit named, e.g. the
    running torque's mean and ripple (``19–29 oz-in, ripple 3–7 oz-in``)."""
    if len(bands) == 2 and bands[1].unit == "Hz":
        return " at ".join(b.text() for b in bands)
    return ", ".join(b.text() if i == 0 else f"{b.quantity.split()[0]} {b.text()}" for i, b in enumerate(bands))


@dataclass
class Row:
    figure: Figure
    values: tuple[float | None, ...]
    ours: str
    in_band: bool
    error: str | None = None

    def as_dict(self, command: str) -> dict[str, Any]:
        f = self.figure
        return {"key": f.key, "figure": f.what, "paper": f.paper, "ours": self.ours, "command": command,
                "values": {b.quantity: v for b, v in zip(f.bands, self.values, strict=False)},
                "bands": {b.quantity: {"lo": b.lo, "hi": b.hi, "unit": b.unit, "text": b.text()} for b in f.bands},
                "in_band": self.in_band, "derived": bool(f.note), "note": f.note or None, "error": self.error}


def evaluate(measured: dict[str, dict[str, Any] | None]) -> list[Row]:
    """The table's rows from each step's JSON (``None``: the step failed): value(s), our text and
    whether every value lies in its band. A missing key or step makes the figure out of band."""
    rows = []
    for f in FIGURES:
        data = measured.get(f.step)
        if data is None:
            rows.append(Row(f, (), "—", False, f"step {f.step} gave no JSON"))
            continue
        try:
            values = f.read(data)
        except (KeyError, IndexError, TypeError) as e:
            rows.append(Row(f, (), "—", False, f"{type(e).__name__}: {e} in the JSON of {f.step}"))
            continue
        ok = all(b.holds(v) for b, v in zip(f.bands, values, strict=False))
        rows.append(Row(f, values, f.show(values), ok))
    return rows


def table(rows: list[Row], commands: dict[str, str]) -> str:
    """paper / ours / band / command side by side, one line per figure, and the derived note."""
    head = ("figure", "paper", "ours", "band", "in band", "command")
    body = [(r.figure.what, r.figure.paper, r.ours, bands_text(r.figure.bands),
             "yes" if r.in_band else "NO", commands[r.figure.step]) for r in rows]
    widths = [max(len(x[c]) for x in (head, *body)) for c in range(len(head))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(x, widths, strict=True)).rstrip() for x in (head, *body)]
    lines.insert(1, "  ".join("-" * w for w in widths))
    notes = [f"{r.figure.key}: {r.figure.note}" for r in rows if r.figure.note]
    notes += [f"{r.figure.key}: {r.error}" for r in rows if r.error]
    return "\n".join(lines + notes)


@dataclass
class StepRun:
    step: Step
    returncode: int
    wall_s: float
    data: dict[str, Any] | None
    stderr_tail: str


def run_step(step: Step, workdir: Path, *, seed: int, env: dict[str, str]) -> StepRun:
    """Run one step as ``python -m vmehil <argv> --seed N --json <file> --quiet`` in ``workdir``."""
    out = workdir / step.json_name
    argv = [sys.executable, "-m", "vmehil", *step.argv, "--seed", str(seed), "--json", str(out), "--quiet"]
    t0 = time.perf_counter()
    proc = subprocess.run(argv, cwd=workdir, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          text=True, check=False)
    wall = time.perf_counter() - t0
    data = None
    if out.exists():
        try:
            data = json.loads(out.read_text())
        except ValueError:
            data = None
    tail = "\n".join(proc.stderr.strip().splitlines()[-5:])
    return StepRun(step, proc.returncode, wall, data, tail)


def reproduce(*, seed: int = 0, rig: str | None = None, say: Callable[[str], None] = print,
              advance: Callable[[], None] = lambda: None) -> dict[str, Any]:
    """Run :data:`STEPS` (on ``rig``: :meth:`Step.on_rig`) in a temporary directory (removed
    afterwards) and evaluate the figures. ``say`` gets a line per step; ``advance`` is called
    after each step (a progress bar)."""
    runs: list[StepRun] = []
    steps = tuple(s.on_rig(rig) for s in STEPS)
    with tempfile.TemporaryDirectory(prefix="vmehil-reproduce-") as tmp:
        work = Path(tmp)
        env = {**os.environ, "VMEHIL_CALIBRATION_DIR": str(work / "calibration")}
        for k, step in enumerate(steps):
            say(f"[{k + 1}/{len(steps)}] {step.command} …")
            r = run_step(step, work, seed=seed, env=env)
            runs.append(r)
            status = "ok" if r.returncode == 0 else f"exit status {r.returncode}"
            failed = r.returncode not in (0, 1)  # 1: checks failed, the JSON holds the figures
            say(f"      {status}, {r.wall_s:.1f} s" + (f"\n      {r.stderr_tail}" if failed else ""))
            advance()
    measured = {r.step.name: r.data for r in runs}
    rows = evaluate(measured)
    commands = {s.name: s.command for s in steps}
    return {
        "seed": seed,
        "rig": rig or DEFAULT_RIG,
        "state": "no calibration file (a fresh clone), every step in one temporary directory, in this order",
        "steps": [{"name": r.step.name, "command": r.step.command, "exit_status": r.returncode,
                   "wall_s": round(r.wall_s, 2)} for r in runs],
        "figures": [r.as_dict(commands[r.figure.step]) for r in rows],
        "passed": all(r.in_band for r in rows),
        "table": table(rows, commands),
    }
