"""Writing the servo loop's black box (:mod:`servo.blackbox`) when a run stops.

On every stop — fault, exception, signal, end — the command writes the box into the report
directory, or with none into ``./vmehil-blackbox/<rig>-<UTC time>/`` (``--blackbox DIR`` or
``$VMEHIL_BLACKBOX``: another folder; ``off``: nothing): ``blackbox.mcap`` (with the ``trace``
extra; else ``blackbox.npz``, said in one line) and ``blackbox.png``, the seconds around the stop
(with matplotlib). The run JSON names the data file as ``final_stop.blackbox``.

The signals are the signal catalog's (:mod:`vmehil.scope.catalog`) and the MCAP is written by the
trace files' writer (:func:`write_mcap`): one channel per group — ``/j1`` (the controller's view of
joint j1: target, position, velocity, error, torque and current commands, integrators, Kp_eff,
switch-off and stop state) and ``/drv/j1`` (its lines: amplifier enable, holding brake, amplifier
fault) per joint — JSON messages ``{"tick", "t_s", <leaf>: value, ...}`` with JSON Schemas, log
times on the loop's clock (tick × period, ns); the stop (tick, reason, cause) in the file's
``vmehil`` metadata record (``blackbox = 1``). The live view (:mod:`vmehil.live`) serves the same
channels.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import sys
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from servo.blackbox import JOINT_SIGNALS, STOP_STATES, BlackBoxSnapshot
from vmehil.scope.catalog import Signal, build_catalog
from vmehil.writers.files import save_figure, write_atomic

__all__ = ["BLACKBOX_ENV", "DEFAULT_DIR", "BoxRows", "blackbox_folder", "box_signals", "save_blackbox",
           "write_blackbox", "write_mcap"]

#: where a run with no report directory writes its black box (a folder per run inside)
DEFAULT_DIR = "vmehil-blackbox"
#: environment variable: the black box's folder (instead of ./vmehil-blackbox), or ``off``
BLACKBOX_ENV = "VMEHIL_BLACKBOX"
#: seconds of the box shown before the stop in the PNG (all of it when shorter)
PNG_BEFORE_S = 3.0


def blackbox_folder(choice: str | None, report: str | None, rig: str, now: datetime | None = None) -> Path | None:
    """Where this run's box goes: ``choice`` (``--blackbox``; else ``$VMEHIL_BLACKBOX``): ``off``
    → ``None``; a folder → ``<folder>/<rig>-<UTC time>``; none given: the report directory, or
    ``./vmehil-blackbox/<rig>-<UTC time>``."""
    choice = choice if choice is not None else os.environ.get(BLACKBOX_ENV) or None
    if choice == "off":
        return None
    if choice is None and report:
        return Path(report)
    stamp = (now or datetime.now(UTC)).strftime("%Y%m%dT%H%M%SZ")
    return Path(choice or DEFAULT_DIR) / f"{rig}-{stamp}"


def save_blackbox(loop: Any, *, rig: str, choice: str | None, report: str | None,
                  final_stop: dict[str, Any] | None, folder: Path | None = None) -> Path | None:
    """The end of a run: write ``loop``'s black box where :func:`blackbox_folder` says (``folder``:
    there instead) and name it in ``final_stop`` as ``blackbox``. A box that cannot be written is
    one line on stderr, never the run's failure (its stop is done, its JSON still to write)."""
    box = getattr(loop, "blackbox", None)
    if box is None:
        return None
    folder = folder if folder is not None else blackbox_folder(choice, report, rig)
    if folder is None:
        return None
    snap = box.snapshot()
    stop_tick = getattr(loop, "stop_tick", None)
    if stop_tick is not None and stop_tick != snap.stop_tick:  # a stop after the last tick the box saw
        snap = dataclasses.replace(snap, stop_tick=int(stop_tick))
    try:
        path = write_blackbox(snap, folder, rig=rig, stop=final_stop)
    except (OSError, ValueError) as e:
        print(f"black box: not written to {folder}: {type(e).__name__}: {e}", file=sys.stderr)
        return None
    if final_stop is not None:
        final_stop["blackbox"] = str(path)
    note = " (.npz: MCAP needs the 'trace' extra: pip install 'vmehil[trace]')" if path.suffix == ".npz" else ""
    print(f"black box: {path}{note}", file=sys.stderr)
    return path


def box_signals(names: tuple[str, ...] | list[str]) -> list[Signal]:
    """The box's signals, from the one signal catalog (:mod:`vmehil.scope.catalog`): per joint its
    own group (``j1.target_rad`` … ``j1.stop_state``) and its lines (``drv.j1.amp_enable``, …)."""
    catalog = build_catalog(list(names))
    out = []
    for j in names:
        out += [catalog.by_name[f"{j}.{leaf}"] for leaf, g, *_ in JOINT_SIGNALS if g == "ctrl"]
        out.append(catalog.by_name[f"{j}.stop_state"])
        out += [catalog.by_name[f"drv.{j}.{leaf}"] for leaf, g, *_ in JOINT_SIGNALS if g == "drv"]
    return out


class BoxRows:
    """The box's rows as the trace writers take them: ``{signal name: value}`` (NaN → ``None``,
    levels as booleans, the stop state as an integer), and by group for the live view."""

    def __init__(self, names: tuple[str, ...] | list[str], period_s: float) -> None:
        self.period_s = period_s
        self.signals = box_signals(names)
        index = {leaf: i for i, (leaf, *_rest) in enumerate(JOINT_SIGNALS)}
        joint = {name: j for j, name in enumerate(names)}
        self._plan = [(s.name, s.kind, -1 if s.leaf == "stop_state" else index[s.leaf],
                       joint[s.group.removeprefix("drv.")]) for s in self.signals]
        groups: dict[str, list[Signal]] = {}
        for sig in self.signals:
            groups.setdefault(sig.group, []).append(sig)
        self.groups = groups

    def row(self, state: int, values: np.ndarray) -> dict[str, Any]:
        """One tick's row (``values``: signals × joints, :data:`servo.blackbox.JOINT_SIGNALS`)."""
        cols = values.T.tolist()
        out: dict[str, Any] = {}
        for name, kind, i, j in self._plan:
            if i < 0:
                out[name] = state
                continue
            v = cols[j][i]
            out[name] = None if v != v else (bool(v) if kind == "b" else v)
        return out


def _meta(snap: BlackBoxSnapshot, rig: str, stop: Mapping[str, Any] | None) -> dict[str, str]:
    stop = stop or {}
    return {"blackbox": "1", "rig": rig, "period_s": repr(snap.period_s),
            "stop_tick": "" if snap.stop_tick is None else str(snap.stop_tick),
            "stop_reason": str(stop.get("reason") or ""), "stop_cause": str(stop.get("cause") or "")}


def write_mcap(path: Path, snap: BlackBoxSnapshot, meta: Mapping[str, str]) -> Path:
    """The box as MCAP through the trace files' writer (:class:`vmehil.scope.mcap_writer.McapTraceWriter`:
    a channel per group, JSON Schemas; ``meta`` in its ``vmehil`` metadata record)."""
    from vmehil.option_groups.trace_options import package_version
    from vmehil.scope.mcap_writer import McapTraceWriter

    rows = BoxRows(snap.names, snap.period_s)
    period_ns = round(snap.period_s * 1e9)
    w = McapTraceWriter(path, rows.signals, dict(meta), package_version(), period_ns)
    try:
        for r in range(snap.t.size):
            k = int(snap.tick[r])
            w.write_tick(k, k * period_ns, rows.row(int(snap.stop_state[r]), snap.joints[r]))
    finally:
        w.close()
    return path


def _write_npz(path: Path, snap: BlackBoxSnapshot, meta: Mapping[str, str]) -> Path:
    buf = io.BytesIO()
    np.savez_compressed(buf, t=snap.t, tick=snap.tick, stop_state=snap.stop_state, joints=snap.joints,
                        names=np.array(snap.names), signals=np.array([leaf for leaf, *_ in JOINT_SIGNALS]),
                        meta=np.array(json.dumps(dict(meta))))
    return write_atomic(path, buf.getvalue())


def _have(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is not None


def write_blackbox(snap: BlackBoxSnapshot, folder: Path, *, rig: str, stop: Mapping[str, Any] | None) -> Path:
    """Write the box into ``folder``: MCAP (or ``.npz`` without the ``trace`` extra) and a PNG
    around the stop (with matplotlib). Returns the data file."""
    folder.mkdir(parents=True, exist_ok=True)
    meta = _meta(snap, rig, stop)
    if _have("mcap"):
        data = write_mcap(folder / "blackbox.mcap", snap, meta)
    else:
        data = _write_npz(folder / "blackbox.npz", snap, meta)
    if _have("matplotlib"):
        write_png(folder / "blackbox", snap, rig=rig, stop=stop)
    return data


def write_png(path: Path, snap: BlackBoxSnapshot, *, rig: str, stop: Mapping[str, Any] | None) -> Path:
    """The seconds around the stop: per joint the error, velocity and torque command; the lines
    (enables, brakes released, amplifier faults) and the stop state. ``path`` without suffix."""
    # the figure without pyplot, legends placed, no tight bounding box: the PNG is written on every
    # stop, so what it adds to the end of a run is kept small (pyplot's import, "best" legends and
    # a tight box's second draw cost more than the drawing itself)
    from matplotlib.figure import Figure

    t = snap.t
    t_stop = snap.stop_tick * snap.period_s if snap.stop_tick is not None else None
    keep = t >= (t_stop - PNG_BEFORE_S) if t_stop is not None else np.ones(t.shape, bool)
    t = t[keep]
    fig = Figure(figsize=(9, 9))
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.06, top=0.94, hspace=0.12)
    ax = fig.subplots(4, 1, sharex=True)
    for j, name in enumerate(snap.names):
        ax[0].plot(t, np.degrees(snap.signal("error_rad")[keep, j]), lw=0.9, label=name)
        ax[1].plot(t, np.degrees(snap.signal("velocity_rad_s")[keep, j]), lw=0.9)
        ax[2].plot(t, snap.signal("torque_nm")[keep, j], lw=0.9)
    ax[0].set_ylabel("error θd−θ (°)")
    ax[1].set_ylabel("velocity (°/s)")
    ax[2].set_ylabel("torque cmd (N·m)")
    ax[0].legend(loc="upper left", fontsize=7, ncol=4)
    lines = ax[3]
    lines.step(t, np.nanmean(snap.signal("amp_enable")[keep], axis=1), where="post", label="enables (fraction high)")
    lines.step(t, np.nanmean(snap.signal("brake_released")[keep], axis=1), where="post",
               label="brakes released (fraction)")
    lines.step(t, np.nanmax(np.nan_to_num(snap.signal("amp_fault")[keep]), axis=1, initial=0.0), where="post",
               label="any amplifier fault")
    lines.step(t, snap.stop_state[keep] / (len(STOP_STATES) - 1), where="post", ls="--",
               label="stop state (0 running … 1 stopped)")
    lines.set_ylabel("lines")
    lines.set_xlabel("loop time (s)")
    lines.legend(loc="center left", fontsize=7)
    for a in ax:
        if t_stop is not None:
            a.axvline(t_stop, color="r", lw=0.8)
        a.grid(True, alpha=0.3)
    s = stop or {}
    why = s.get("cause") or s.get("reason") or "no stop"
    fig.suptitle(f"{rig} black box: {why}" + (f" at {t_stop:.3f} s" if t_stop is not None else ""))
    return save_figure(fig, path, dpi=90, tight=False)[0]
