"""Where each signal of the catalog is observed, without adding a bus cycle.

* the controller's signals (``J.*``): the loop's per-tick record (:attr:`servo.loop.ServoLoop.last`)
  and the law's state (integrators, switch-off state, Kp_eff); the stop state from the loop;
* the drivers' values (``drv.J.*``): the tick's :class:`servo.io.Measurement` as the drivers gave
  it, and what :class:`servo.io.JointIO` last wrote (DAC volts, brake lines);
* the nets (``net.*``): the crate's :class:`emulators.signals.Signals` after the tick's exchange
  (analog volts, digital levels); a quadrature net's per-period summary by a listener on it;
* the plant's truth (``truth.J.*``): the plant boundary's ``truth()``;
* the IRQ lines (``irq.IRQn``): the crate's acknowledge counters, per tick;
* the bus cycles (``bus.*``): the crate's cycle tap (:meth:`emulators.crate.Crate.set_cycle_tap`).

Reading any of these is a Python attribute read: the boards see no cycle, the clock does not
move (the behaviour fingerprint is unchanged with a trace on).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from vmehil.scope.catalog import TRUTH, Catalog, Signal, build_catalog

__all__ = ["BusCycle", "Sampler", "catalog_of", "plant_catalog", "sampler_for", "tap_exchanges"]

Row = dict[str, Any]


class BusCycle(NamedTuple):
    """One bus cycle as the trace records it (the ``bus`` group's fields)."""

    tick: int  #: the tick in which it ran (before the first: the first's)
    t_ns: int  #: simulated time at its end
    space: int  #: 16, 24 or 32
    address: int
    width: int  #: 8, 16 or 32 bits
    write: bool
    value: int
    block: bool
    berr: bool
    cycle: int  #: its number in the trace, from 0


def _stop_state(loop: Any) -> int:
    """0 servoing, 1 decelerating, 2 holding, 3 stopped (catalog: ``J.stop_state``)."""
    if not loop.enabled:
        return 3
    if loop.stopping is not None:
        return 1
    cat = loop.stop_category
    return 2 if cat is not None and int(cat) == 2 else 0


def _scalar(kind: str, v: Any) -> Any:
    """A plain Python value of ``kind`` (``None``: no value: a NaN, or nothing recorded)."""
    if v is None:
        return None
    if kind == "f":
        x = float(v)
        return x if math.isfinite(x) else None
    if kind == "i":
        x = float(v)
        return int(x) if math.isfinite(x) else None
    return bool(v)


def catalog_of(system: Any, names: Sequence[str], *, truth: bool | None = None) -> Catalog:
    """The catalog of a loop of joints ``names`` on ``system``: an emulated rig (``crate``) has
    nets, IRQs and the bus, and the truth where its plant runs in this process (``truth``: say so
    instead); another has the controller's and the drivers' signals."""
    crate = getattr(system, "crate", None)
    if crate is None:
        return build_catalog(names)
    sig = crate.signals
    quad = [n for n in sig.listened() if n not in sig.analog and n not in sig.digital and n.endswith("encoder")]
    if truth is None:
        truth = getattr(system, "plant", None) is not None
    return build_catalog(names, analog_nets=sig.analog, digital_nets=sig.digital, quadrature_nets=quad,
                         truth=truth, irq=True, bus=True)


@dataclass
class Sampler:
    """Reads the chosen signals after each tick: :meth:`row` (the per-tick ones), :meth:`cycles`
    (the bus cycles since the last call). Built by :func:`sampler_for`."""

    signals: tuple[Signal, ...]
    period_ns: int
    _readers: tuple[Callable[[Any, Row], None], ...] = ()
    _cycles: list[BusCycle] | None = None
    #: called once by :meth:`close` (the observation undone: a tap removed)
    on_close: Callable[[], None] | None = None
    _tick: int = 0

    @property
    def per_tick(self) -> tuple[Signal, ...]:
        return tuple(s for s in self.signals if s.per_tick)

    @property
    def traces_bus(self) -> bool:
        return self._cycles is not None

    def row(self, loop: Any) -> tuple[int, int, Row]:
        """``(tick, t_ns, {name: value})`` of the tick the loop has just run."""
        k = int(loop.last.get("tick", loop.tick_count - 1)) if loop.last else loop.tick_count - 1
        self._tick = k + 1  # cycles from here on belong to the next tick
        out: Row = {}
        for read in self._readers:
            read(loop, out)
        return k, k * self.period_ns, out

    def cycles(self) -> list[BusCycle]:
        """The bus cycles recorded since the last call, oldest first."""
        got = self._cycles
        if not got:
            return []
        self._cycles = []
        return got

    def close(self) -> None:
        """Stop observing (the crate's tap off)."""
        if self.on_close is not None:
            self.on_close()
            self.on_close = None


def sampler_for(signals: Sequence[Signal], system: Any, loop: Any) -> Sampler:
    """A sampler of ``signals`` (from :func:`catalog_of`'s catalog) on ``system`` and ``loop``:
    only what is chosen is read each tick."""
    chosen = tuple(signals)
    names = list(loop.names)
    index = {n: i for i, n in enumerate(names)}
    sampler = Sampler(chosen, round(loop.period_s * 1e9))
    sampler._tick = loop.tick_count  # a cycle belongs to the tick it runs in (or the next to come)
    readers: list[Callable[[Any, Row], None]] = []
    by_group: dict[str, list[Signal]] = {}
    for s in chosen:
        if s.per_tick:
            by_group.setdefault(s.group, []).append(s)
    controller = [(index[g], sigs) for g, sigs in by_group.items() if g in index]
    if controller:
        readers.append(_controller_reader(controller))
    drivers = [(index[g[4:]], sigs) for g, sigs in by_group.items() if g.startswith("drv.") and g[4:] in index]
    if drivers:
        readers.append(_driver_reader(drivers, loop.io))
    truth = [(index[g[6:]], sigs) for g, sigs in by_group.items() if g.startswith("truth.") and g[6:] in index]
    if truth:
        readers.append(_truth_reader(truth, system))
    crate = getattr(system, "crate", None)
    if crate is not None:
        nets = [s for s in chosen if s.per_tick and s.name.startswith("net.")]
        if nets:
            readers.append(_net_reader(nets, crate.signals))
        irq = [s for s in chosen if s.group == "irq"]
        if irq:
            readers.append(_irq_reader(irq, crate))
        if any(not s.per_tick for s in chosen):
            _tap_bus(sampler, crate)
    sampler._readers = tuple(readers)
    return sampler


def _controller_reader(joints: list[tuple[int, list[Signal]]]) -> Callable[[Any, Row], None]:
    leaves = {s.leaf for _i, sigs in joints for s in sigs}
    flat = [(s.name, s.leaf, s.kind, i) for i, sigs in joints for s in sigs]
    record = {"target_rad": "theta_d", "target_rad_s": "omega_d", "position_rad": "theta",
              "velocity_rad_s": "omega", "torque_nm": "torque", "current_cmd_a": "current_cmd",
              "current_a": "current", "kp_eff": "kp_eff"}

    def read(loop: Any, out: Row) -> None:
        last = loop.last
        law = loop.law
        state = getattr(law, "state", None)
        cols: dict[str, Any] = {}
        for leaf in leaves:
            if leaf in record:
                cols[leaf] = last.get(record[leaf])
            elif leaf == "error_rad":
                d, p = last.get("theta_d"), last.get("theta")
                cols[leaf] = None if d is None or p is None else np.asarray(d) - np.asarray(p)
            elif leaf == "integral_e":
                cols[leaf] = None if state is None else state.ie
            elif leaf == "integral_edot_rad":
                cols[leaf] = None if state is None else state.iv
            elif leaf == "integrating":
                cols[leaf] = None if state is None else state.integrating
        stop = _stop_state(loop)
        for name, leaf, kind, i in flat:
            if leaf == "stop_state":
                out[name] = stop
                continue
            col = cols.get(leaf)
            out[name] = None if col is None else _scalar(kind, col[i])

    return read


def _driver_reader(joints: list[tuple[int, list[Signal]]], io: Any) -> Callable[[Any, Row], None]:
    fields = {"pot_v": "pot_v", "enc_counts": "encoder_counts", "enc_illegal": "encoder_illegal",
              "amp_fault": "fault"}
    flat = [(s.name, s.leaf, s.kind, i) for i, sigs in joints for s in sigs]

    def read(loop: Any, out: Row) -> None:
        m = loop.last.get("measurement")
        for name, leaf, kind, i in flat:
            if leaf in fields:
                col = None if m is None else getattr(m, fields[leaf])
                out[name] = None if col is None or len(col) <= i else _scalar(kind, col[i])
            elif leaf == "dac_v":
                out[name] = _scalar("f", io.last_dac_volts[i])
            elif leaf == "brake_released":
                out[name] = bool(io.brake_released[i])

    return read


def _truth_reader(joints: list[tuple[int, list[Signal]]], system: Any) -> Callable[[Any, Row], None]:
    keys = {leaf: key for leaf, key, *_ in TRUTH}
    flat = [(s.name, keys[s.leaf], s.kind, i) for i, sigs in joints for s in sigs]

    def read(loop: Any, out: Row) -> None:
        truth = system.truth() or {}
        for name, key, kind, i in flat:
            col = truth.get(key)
            out[name] = None if col is None else _scalar(kind, col[i])

    return read


def _net_reader(nets: list[Signal], signals: Any) -> Callable[[Any, Row], None]:
    analog, digital = signals.analog, signals.digital
    plain = [(s.name, s.name[4:], s.kind) for s in nets
             if (s.kind == "f" and s.name[4:] in analog) or (s.kind == "b" and s.name[4:] in digital)]
    done = {name for name, _net, _kind in plain}
    quad = [(s.name, s.group[4:], s.leaf) for s in nets if s.name not in done]  # a quadrature net's summary
    seen: dict[str, Any] = {}
    for net in sorted({net for _name, net, _leaf in quad}):
        signals.subscribe(net, lambda name, events: seen.__setitem__(name, events))

    def read(loop: Any, out: Row) -> None:
        for name, net, kind in plain:
            if kind == "f":
                v = analog.get(net)
                out[name] = None if v is None or not math.isfinite(v) else float(v)
            else:
                out[name] = bool(digital.get(net, False))
        for name, net, leaf in quad:
            ev = seen.get(net)
            if ev is None:
                out[name] = 0 if leaf != "phase" else None
            elif leaf == "index":
                out[name] = len(ev.index_offsets)
            else:
                out[name] = int(getattr(ev, leaf))
        seen.clear()  # a period with no summary published counted nothing

    return read


def _irq_reader(lines: list[Signal], crate: Any) -> Callable[[Any, Row], None]:
    keys = [(s.name, "iack." + s.leaf) for s in lines]
    before = {key: crate.counters.get(key, 0) for _n, key in keys}

    def read(loop: Any, out: Row) -> None:
        counters = crate.counters
        for name, key in keys:
            now = counters.get(key, 0)
            out[name] = now - before[key]
            before[key] = now

    return read


def _tap_bus(sampler: Sampler, crate: Any) -> None:
    sampler._cycles = []
    n = [0]

    def tap(t_ns: int, am: Any, address: int, width: Any, write: bool, value: int, berr: bool) -> None:
        cycles = sampler._cycles
        if cycles is None:
            return
        cycles.append(BusCycle(sampler._tick, t_ns, int(am.space.name[1:]), address, 8 * int(width), write, value,
                               bool(am.block), berr, n[0]))
        n[0] += 1

    crate.set_cycle_tap(tap)
    sampler.on_close = lambda: crate.set_cycle_tap(None)


# --- the coordinator's plant exchanges (vmehil coordinate: no loop, no crate) -------------------
#: PlantCommand's fields → the joint's net (JointNets' field)
_COMMAND_NETS = (("amp_command_v", "amp_command", "f"), ("amp_enable", "amp_enable", "b"),
                 ("fault_reset", "amp_reset", "b"), ("pwm_duty", "pwm", "f"), ("pwm_direction", "direction", "b"),
                 ("brake", "brake", "b"), ("holding_brake", "holding_brake", "b"))
#: PlantSensors' fields → the joint's net
_SENSOR_NETS = (("pot_v", "pot", "f"), ("tach_v", "tach", "f"), ("imon_v", "imon", "f"),
                ("amp_fault", "amp_fault", "b"))


def plant_catalog(rig: Any) -> Catalog:
    """What a coordinator sees of the plant it serves: each joint's nets, as the exchanged
    commands and sensor values carry them, and the plant's truth."""
    from vmehil.rig_setup.system import joint_nets

    analog: list[str] = []
    digital: list[str] = []
    quad: list[str] = []
    for j in joint_nets(rig):
        for _field, net, kind in (*_COMMAND_NETS, *_SENSOR_NETS):
            name = getattr(j, net)
            if name:
                (analog if kind == "f" else digital).append(name)
        if j.encoder:
            quad.append(j.encoder)
    return build_catalog([j.name for j in rig.joints], analog_nets=analog, digital_nets=digital,
                         quadrature_nets=quad, truth=True, controller=False)


def tap_exchanges(link: Any, signals: Sequence[Signal], rig: Any,
                  write: Callable[[int, int, Row], None]) -> Callable[[], None]:
    """Call ``write(step, t_ns, row)`` at each of ``link``'s exchanges: the step's commands with
    the sensor values and truth of the answer before it (what the nets held during that tick, as
    in a single run's trace). Returns the undo."""
    from vmehil.rig_setup.system import joint_nets

    period_ns = round(rig.period_s * 1e9)
    chosen = {s.name: s for s in signals}
    index = {j.name: i for i, j in enumerate(rig.joints)}
    cmd_fields, sens_fields, quad = [], [], []
    for j in joint_nets(rig):
        i = index[j.name]
        for field_, net, kind in _COMMAND_NETS:
            name = getattr(j, net)
            if name and f"net.{name}" in chosen:
                cmd_fields.append((f"net.{name}", field_, i, kind))
        for field_, net, kind in _SENSOR_NETS:
            name = getattr(j, net)
            if name and f"net.{name}" in chosen:
                sens_fields.append((f"net.{name}", field_, i, kind))
        if j.encoder:
            quad += [(s.name, i, s.leaf) for s in signals if s.group == f"net.{j.encoder}"]
    keys = {leaf: key for leaf, key, *_ in TRUTH}
    truth = [(s.name, keys[s.leaf], index[s.group[6:]], s.kind) for s in signals if s.group.startswith("truth.")]
    original = link.exchange
    state: dict[str, Any] = {"step": 0, "answer": None}

    def exchange(cmd: Any, period_s: float, delay_s: float) -> Any:
        k, prev = state["step"], state["answer"]
        row: Row = {name: _scalar(kind, getattr(cmd, f)[i]) if len(getattr(cmd, f)) > i else None
                    for name, f, i, kind in cmd_fields}
        for name, f, i, kind in sens_fields:
            row[name] = None if prev is None else _scalar(kind, getattr(prev, f)[i])
        for name, i, leaf in quad:
            ev = None if prev is None else prev.encoder[i]
            row[name] = (None if leaf == "phase" else 0) if ev is None else (
                len(ev.index_offsets) if leaf == "index" else int(getattr(ev, leaf)))
        t = {} if prev is None else prev.truth
        for name, key, i, kind in truth:
            col = t.get(key)
            row[name] = None if col is None else _scalar(kind, col[i])
        write(k, k * period_ns, row)
        state["step"] = k + 1
        answer = original(cmd, period_s, delay_s)
        state["answer"] = answer
        return answer

    link.exchange = exchange
    return lambda: link.__dict__.pop("exchange", None)
