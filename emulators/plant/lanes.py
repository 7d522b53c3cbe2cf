"""The plant in lane mode (batched lockstep, issue #34; :mod:`hal.lanes`).

:meth:`emulators.plant.Plant.from_lanes` stacks B scalar plants of n joints into one plant of
B·n joints, lane-major (joint ``j`` of lane ``b`` at ``b*n + j``), whose period is one call of the
compiled kernel (:mod:`emulators.plant.numba_kernel`) over every joint. This module holds what
that plant steps with:

* :class:`LaneKernelConsts`: the kernel's parameter matrix, encoder constants and flags, taken
  column by column from the scalar plants' own (so every lane's constants are its scalar
  plant's bits; nothing is recomputed over the B·n joints);
* :class:`LaneStepper`: :meth:`Plant.step_period` of the stacked plant: the enable watchdogs'
  events (:class:`emulators.plant.amplifier.LaneEnableWatchdog`) cut each lane's period into
  segments as the scalar plant does, the holding brakes move, the noise streams draw, then the
  kernel integrates.

Why the results are the scalar ones bit for bit: the kernel loops over joints and computes each
from its own column alone (its parameters, state, command and segment enables) and from values
the whole call shares: the flags ``F`` (a plant's "any joint compliant", "every joint's
stick/slip step direct", ...: they select the arithmetic, and are per scalar plant) and the
segment boundaries (``seg_start``/``seg_cmd``, per plant: its watchdog's). So lanes are called
together only where both agree: normally every lane in one call; when a lane's flags or its
watchdog's segmenting differ, one call per group of lanes that share them (on gathered copies
of their columns). The kernel has no cross-joint reduction and no vector loop over joints, so
a joint's numbers do not depend on where it sits in the call (tests/emulators/test_plant_lanes.py
checks a 7-joint call against a 7·B-joint one).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from emulators.plant import kernel_layout as _k
from emulators.signals import QuadratureEvents
from hal.lanes import LaneSet


def lane_events(events: Sequence[QuadratureEvents]) -> QuadratureEvents:
    """One joint's lane-mode :class:`QuadratureEvents` from its B scalar ones (lane order):
    ``counts``, ``illegal``, ``phase`` int64 arrays (B,), ``index_offsets`` a tuple of B tuples."""
    counts: Any = np.array([e.counts for e in events], dtype=np.int64)
    illegal: Any = np.array([e.illegal for e in events], dtype=np.int64)
    offsets: Any = tuple(tuple(e.index_offsets) for e in events)
    phase: Any = np.array([e.phase for e in events], dtype=np.int64)
    return QuadratureEvents(counts=counts, illegal=illegal, index_offsets=offsets, phase=phase)


def event_of_lane(ev: QuadratureEvents, b: int) -> QuadratureEvents:
    """Lane ``b``'s scalar :class:`QuadratureEvents` of a lane-mode one."""
    offsets: Any = ev.index_offsets
    return QuadratureEvents(counts=int(np.asarray(ev.counts)[b]), illegal=int(np.asarray(ev.illegal)[b]),
                            index_offsets=tuple(int(o) for o in offsets[b]), phase=int(np.asarray(ev.phase)[b]))


def _groups(keys: Sequence[Any]) -> list[list[int]]:
    """The lanes by equal key, in the order of each key's first lane."""
    out: dict[Any, list[int]] = {}
    for b, key in enumerate(keys):
        out.setdefault(key, []).append(b)
    return list(out.values())


class LaneKernelConsts:
    """What the kernel reads for one step length ``h``, for B stacked plants: the columns of each
    lane's scalar plant's own constants (``plants[b]._step_consts(h)``), and its flags per lane.

    Args:
        plants: the B scalar plants (lane order); their constants are built here if need be
            (they depend on the parameters only, and on the environment's torques, which the
            stacked plant passes in :meth:`set_external`).
        h: the substep (s).
    """

    def __init__(self, plants: Sequence[Any], h: float) -> None:
        cs = []
        for p in plants:
            c = p._step_consts(h)
            if c.P is None:
                c.kernel_arrays(p)
            cs.append(c)
        self.h = h
        self.n_lanes = len(plants)
        self.n = plants[0].n_joints
        self._scalar = cs
        self.P = np.ascontiguousarray(np.concatenate([c.P for c in cs], axis=1))
        self.enci = np.ascontiguousarray(np.concatenate([c.enci for c in cs], axis=1), dtype=np.int64)
        self.F = np.ascontiguousarray(np.stack([c.F for c in cs]), dtype=np.int64)  #: (B, N_FLAGS)
        self._buffers: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.flag_groups: list[list[int]] = [list(range(self.n_lanes))]

    def set_external(self, plant: Any) -> None:
        """The stacked plant's environment torques (per joint, B·n) changed: each lane's columns
        and flags follow, as :meth:`_StepConsts.set_external` does for a scalar plant."""
        P, F, n = self.P, self.F, self.n
        P[_k.EXT_TORQUE] = plant.external_torque_nm
        P[_k.CONTACT_K] = plant.contact_k_nm_per_rad
        P[_k.CONTACT_RAD] = plant.contact_rad
        F[:, _k.F_EXTERNAL] = np.any(np.asarray(plant.external_torque_nm).reshape(-1, n) != 0.0, axis=1)
        F[:, _k.F_CONTACT] = np.any(np.asarray(plant.contact_k_nm_per_rad).reshape(-1, n) != 0.0, axis=1)
        self.flag_groups = _groups([tuple(row) for row in F.tolist()])

    def buffers(self, n_sub: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Scratch for periods of ``n_sub`` substeps: x4 positions, index offsets (room for the
        largest lane's), and each joint's room (its scalar plant's: more pulses is what makes
        the scalar plant raise)."""
        b = self._buffers.get(n_sub)
        if b is None:
            rooms = [c.kernel_buffers(self.n, n_sub)[1].shape[1] for c in self._scalar]
            room = np.repeat(np.array(rooms, dtype=np.int64), self.n)
            b = self._buffers[n_sub] = (np.zeros(n_sub + 1), np.zeros((self.n_lanes * self.n, max(rooms)),
                                                                      dtype=np.int64), room)
        return b


class LaneStepper:
    """:meth:`Plant.step_period` of a stacked plant (installed by :meth:`Plant.from_lanes`).

    ``sensors_type``: the class of the answer (:class:`emulators.plant.PlantSensors`; passed in so
    that this module does not import the plant's). The answer is the scalar answers stacked:
    per-joint arrays of B·n values lane-major, ``encoder`` one lane-mode
    :class:`QuadratureEvents` per joint of a lane (n of them), ``truth`` per joint lane-major.
    """

    def __init__(self, plant: Any, lanes: LaneSet, sensors_type: Callable[..., Any]) -> None:
        self.plant = plant
        self.lanes = lanes
        self.sensors_type = sensors_type
        self.B = plant.n_lanes
        self.n = plant.lane_joints
        #: the scalar plants' per-lane constants by step length
        self.consts: dict[float, LaneKernelConsts] = plant._consts
        #: per lane its segments of the period being cut: first substep, command index
        self._seg_start = np.full((self.B, 3), -1, dtype=np.int64)
        self._seg_cmd = np.full((self.B, 3), -1, dtype=np.int64)
        self._seg_enable = np.zeros((3, self.B * self.n), dtype=bool)
        self._no_index = ((),) * self.B

    def lane_consts(self, h: float) -> LaneKernelConsts:
        c = self.consts.get(h)
        if c is None:
            c = self.consts[h] = LaneKernelConsts(self.plant.lane_plants, h)
            c.set_external(self.plant)
        return c

    # ---- one period ----------------------------------------------------------------------
    def step(self, cmd: Any, period_s: float, delay_s: float = 0.0) -> Any:
        """:meth:`Plant.step_period` for every lane (``cmd``: per-joint arrays of B·n values,
        lane-major; ``watchdog_line`` a bool for every lane or (B,))."""
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        p = self.plant
        B, n = self.B, self.n
        N = B * n
        n_sub = max(1, round(period_s * p.rate_hz))
        h = period_s / n_sub
        n_old = min(n_sub, max(0, round(delay_s / h)))
        c = self.lane_consts(h)
        prev = p._prev_cmd
        wd = p.watchdog
        t0 = p.time_s
        new_enable = np.asarray(cmd.amp_enable, dtype=bool)
        prev_enable = np.asarray(prev.amp_enable, dtype=bool)
        reset_edge = np.ascontiguousarray(np.asarray(cmd.fault_reset, dtype=bool)
                                          & ~np.asarray(prev.fault_reset, dtype=bool))
        # ---- the watchdogs' and brakes' events cut each lane's period (Plant._step_compiled)
        seg_start, seg_cmd, seg_enable = self._seg_start, self._seg_cmd, self._seg_enable
        seg_start.fill(-1)
        seg_cmd.fill(-1)
        k_seg = np.zeros(B, dtype=np.int64)
        lane_ix = np.arange(B)
        held, held_k = prev_enable, 0
        s_out = wd.expiry_substep(t0, h, n_sub)
        brakes = p.brakes
        has_brakes = p.has_brakes
        brake_on = brakes.begin(t0, h) if has_brakes else brakes.present
        s = 0
        while True:
            changed = np.full(B, s == 0)
            if s == n_old:
                wd.command(cmd.watchdog_line, new_enable, prev_enable, t0 + s * h)
                s_out = wd.expiry_substep(t0, h, n_sub)
                held, held_k = new_enable, 1
                changed[:] = True
                if has_brakes:
                    brakes.event(s, self._brake_lines(cmd, t0 + s * h))
            out = s_out == s
            if out.any():
                changed |= wd.expire(held, out)
                if has_brakes:  # the pump feeds the brakes' lines too (other lanes: unchanged)
                    brakes.event(s, brakes.line & ~np.repeat(out, n))
            if s >= n_sub:
                break
            if changed.any():
                ks = k_seg[changed]
                rows = lane_ix[changed]
                seg_start[rows, ks] = s
                seg_cmd[rows, ks] = held_k
                eff = (held & (wd.cause == 0)).reshape(B, n)
                seg_enable.reshape(3, B, n)[ks, rows] = eff[rows]
                k_seg[changed] += 1
            nxt = n_sub
            if s < n_old < nxt:
                nxt = n_old
            later = s_out[s_out > s]
            if later.size:
                nxt = min(nxt, int(later.min()))
            s = nxt
        if has_brakes:
            brakes.finish(n_sub)
        # ---- the kernel's inputs, every lane side by side
        cmd_f, cmd_b, noise = _k.kernel_inputs(prev, cmd, p._noise, N)
        X = p._bind_state()
        st = p.amp_state
        O = np.empty((_k.O_ROWS, N))
        Bo = np.empty((_k.B_ROWS, N), dtype=bool)
        E = np.empty((_k.E_ROWS, N), dtype=np.int64)
        x4, idx, room = c.buffers(n_sub)
        kernel = p._kernel_fn
        args = (h, n_sub, n_old, cmd_f, cmd_b, reset_edge, X, st, noise, p._held_v, x4, O, Bo, E, idx, brake_on,
                brakes.flips)
        uniform = bool((k_seg == k_seg[0]).all() and (seg_start == seg_start[0]).all()
                       and (seg_cmd == seg_cmd[0]).all())
        if uniform and len(c.flag_groups) == 1:
            k = int(k_seg[0])
            kernel(c.P, c.enci, c.F[0], h, n_sub, n_old, cmd_f, cmd_b, seg_start[0, :k], seg_cmd[0, :k],
                   seg_enable[:k], reset_edge, X, st.fault, st.cause, st.saturated, noise, p._held_v, x4, O, Bo, E,
                   idx, brake_on, brakes.flips)
        else:
            groups = c.flag_groups if uniform else _groups(
                [(fk, tuple(seg_start[b].tolist()), tuple(seg_cmd[b].tolist()))
                 for b, fk in enumerate(self._flag_keys(c))])
            for lanes_g in groups:
                self._call_group(kernel, c, lanes_g, int(k_seg[lanes_g[0]]), *args)
        p.at_stop = Bo[_k.B_AT_STOP]
        p._prev_cmd = copy_command(cmd)
        p.time_s += period_s
        # ---- the answer
        over = E[_k.E_NIDX] > room
        if over.any():  # the scalar plant raises (RuntimeError) for such a lane
            self.lanes.eject(over.reshape(B, n).any(axis=1), "plant kernel: more index pulses in one period "
                                                               "than it has room for")
        enc = np.ascontiguousarray(E[[_k.E_COUNTS, _k.E_ILLEGAL, _k.E_PHASE, _k.E_NIDX]].reshape(4, B, n)
                                   .transpose(0, 2, 1))
        counts, illegal, phase, nidx = enc
        events = []
        pulsed = nidx.any(axis=1).tolist()
        for j in range(n):
            offsets: Any = self._no_index
            if pulsed[j]:
                ks = np.minimum(nidx[j], idx.shape[1]).tolist()
                offsets = tuple(tuple(idx[b * n + j, :kb].tolist()) if kb > 0 else () for b, kb in enumerate(ks))
            events.append(QuadratureEvents(counts=counts[j], illegal=illegal[j], index_offsets=offsets,
                                           phase=phase[j]))
        return _k.kernel_sensors(self.sensors_type, O, Bo, events, p.time_s, N, wd.effective(new_enable), st.cause, wd,
                                 brakes.engaged)

    def _flag_keys(self, c: LaneKernelConsts) -> list[int]:
        """Per lane the index of its flag group."""
        keys = [0] * self.B
        for g, lanes_g in enumerate(c.flag_groups):
            for b in lanes_g:
                keys[b] = g
        return keys

    def _call_group(self, kernel: Any, c: LaneKernelConsts, lanes_g: list[int], k: int, h: float, n_sub: int,
                    n_old: int, cmd_f: np.ndarray, cmd_b: np.ndarray, reset_edge: np.ndarray, X: np.ndarray,
                    st: Any, noise: np.ndarray, held_v: np.ndarray, x4: np.ndarray, O: np.ndarray, Bo: np.ndarray,
                    E: np.ndarray, idx: np.ndarray, brake_on: np.ndarray, flips: np.ndarray) -> None:
        """One kernel call for the lanes ``lanes_g`` (same flags, same segmenting), on contiguous
        copies of their columns; the state and outputs are put back."""
        n = self.n
        b0 = lanes_g[0]
        cols = (np.asarray(lanes_g, dtype=np.int64)[:, None] * n + np.arange(n)).ravel()
        m = cols.size
        C = np.ascontiguousarray
        Xg = C(X[:, cols])
        fault, cause, sat = C(st.fault[cols]), C(st.cause[cols]), C(st.saturated[cols])
        Og = np.empty((_k.O_ROWS, m))
        Bg = np.empty((_k.B_ROWS, m), dtype=bool)
        Eg = np.empty((_k.E_ROWS, m), dtype=np.int64)
        idxg = np.zeros((m, idx.shape[1]), dtype=np.int64)
        kernel(C(c.P[:, cols]), C(c.enci[:, cols]), c.F[b0], h, n_sub, n_old, C(cmd_f[:, :, cols]),
               C(cmd_b[:, :, cols]), self._seg_start[b0, :k], self._seg_cmd[b0, :k],
               C(self._seg_enable[:k][:, cols]), C(reset_edge[cols]), Xg, fault, cause, sat, C(noise[:, cols]),
               C(held_v[:, cols]), x4, Og, Bg, Eg, idxg, C(brake_on[cols]), C(flips[:, cols]))
        X[:, cols] = Xg
        st.fault[cols] = fault
        st.cause[cols] = cause
        st.saturated[cols] = sat
        O[:, cols] = Og
        Bo[:, cols] = Bg
        E[:, cols] = Eg
        idx[cols] = idxg

    def _brake_lines(self, cmd: Any, t_s: float) -> np.ndarray:
        """:meth:`Plant._brake_lines` per lane: low where the lane's pump is out, or its amplifier
        is latched off."""
        wd = self.plant.watchdog
        return (np.asarray(cmd.holding_brake, dtype=bool) & (wd.cause == 0)
                & np.repeat(wd.alive(t_s), self.n))


def copy_command(cmd: Any) -> Any:
    """:meth:`PlantCommand.copy` of a lane-mode command (its watchdog line may be a (B,) array)."""
    line = cmd.watchdog_line
    return type(cmd)(
        amp_command_v=np.array(cmd.amp_command_v, dtype=float),
        amp_enable=np.array(cmd.amp_enable, dtype=bool),
        fault_reset=np.array(cmd.fault_reset, dtype=bool),
        pwm_duty=np.array(cmd.pwm_duty, dtype=float),
        pwm_direction=np.array(cmd.pwm_direction, dtype=bool),
        brake=np.array(cmd.brake, dtype=bool),
        watchdog_line=np.array(line, dtype=bool) if isinstance(line, np.ndarray) else bool(line),
        holding_brake=np.array(cmd.holding_brake, dtype=bool),
    )
