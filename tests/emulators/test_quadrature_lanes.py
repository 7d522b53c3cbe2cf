"""Lane mode of the quadrature decoder board and its driver (batched lockstep, issue #34).

B boards and drivers, each set up as a scalar rig sets them up (with different values), are
stacked with ``from_lanes`` and driven through the servo tick's decoder program (servo/io.py:
``update`` of quad0 then quad1; where a reading finds ILLEGAL the scalar tick clears it, the lane
tick leaves the lanes that found it, as ``JointIO`` in lanes does); B more boards
and drivers built the same way run the same program alone (the scalar twins). After every step
every live lane equals its twin bit for bit: the readings, the board's counters, latches, flags
and registers, the driver's unwrapping and velocity state, the bus clock and the cycle counters.
The lanes expected to be ejected are found from the twins alone: a twin that raised, or whose
cycle counters left the majority's (it made a cycle the others did not). A counter that wraps in
some lanes only leaves none: the driver writes the wrap flags back on every read, set or not.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import pytest

from emulators.crate import Crate
from emulators.plant.lanes import lane_events
from emulators.quadrature import BOARD_MAP, QuadratureBoard
from emulators.signals import QuadratureEvents
from hal.lanes import LaneSet, lane
from hal.quadrature import QuadratureDriver, QuadratureError
from hal.vme.types import Width

PERIOD_S = 0.008
PERIOD_NS = 8_000_000
#: jpl-arm's decoders (emulators/presets/jpl-arm.toml): name, base, slot, channel → net, x4 counts/rev
BOARDS = (
    ("quad0", 0x5000, 6, {0: "j1.encoder", 1: "j2.encoder", 2: "j3.encoder", 3: "j4.encoder"},
     {0: 200000.0, 1: 200000.0, 2: 160000.0, 3: 160000.0}),
    ("quad1", 0x5100, 7, {0: "j5.encoder", 1: "j6.encoder", 2: "hand.encoder"},
     {0: 160000.0, 1: 100000.0, 2: 20000.0}),
)
NETS = [net for *_, nets, _ in BOARDS for net in nets.values()]
#: the velocity estimate's ticks without a count before it reads 0: short, so that the noise's
#: quiet spells (x1: a few x4 counts either way often leave the counter still) reach it
STOP_TICKS = 6


def _lane_crate(crates: list[Crate]) -> Crate:
    """The crate of lanes of ``crates`` (lane order), each board stacked by its type's ``from_lanes``."""
    return Crate.from_lanes(crates, LaneSet(len(crates)))


def _reg(crate: Crate, base: int, name: str, value: Any) -> None:
    r = BOARD_MAP[name]
    crate.write(base + r.offset, value, space="A16", width=r.width)


def _setup(b: int, max_counts_per_tick: int | None = None) -> tuple[Crate, dict[str, QuadratureDriver]]:
    """Lane ``b``'s rig: both decoders installed, every channel's mode, index arm and preset set
    (the same cycles in every lane, different values), then the drivers built as servo/io.py
    builds them (errors reported, not raised)."""
    crate = Crate("rig")
    drivers = {}
    for name, base, slot, nets, _ in BOARDS:
        crate.install(QuadratureBoard(name, nets=nets, sample_hz=1e6), base=base, space="A16", slot=slot)
    for k, (name, base, _, nets, cpr) in enumerate(BOARDS):
        for ch in nets:
            mode = (2, 1, 0, 2)[(b + ch + k) % 4]  # x4, x2, x1 (hold: below, in the board's own test)
            arm = 0x10 if (b + ch) % 3 == 0 else 0
            _reg(crate, base, f"CH{ch}_CTL", arm | mode)
            preset = (0, 0x000100, 0x0000FF, 0)[(b + 2 * ch + k) % 4]
            _reg(crate, base, f"CH{ch}_PRE_HI", preset >> 16)
            _reg(crate, base, f"CH{ch}_PRE_LO", preset & 0xFFFF)
            _reg(crate, base, f"CH{ch}_CMD", 0x4 if preset else 0x0)
        scale = 1.0 + 0.125 * b  # a calibrated scaling per lane
        drivers[name] = QuadratureDriver(crate, base, counts_per_rev={c: v * scale for c, v in cpr.items()},
                                         channels=sorted(nets), errors="report",
                                         max_counts_per_tick=max_counts_per_tick, stop_ticks=STOP_TICKS)
    return crate, drivers


def _bits(x: Any) -> Any:
    """A value as something equal only to the same bits (floats by their hex, -0.0 and NaN included)."""
    if isinstance(x, float | np.floating):
        return float(x).hex()
    if isinstance(x, bool | np.bool_):
        return bool(x)
    return int(x)


def _same(lane_value: Any, b: Any, twin_value: Any) -> bool:
    v = lane(lane_value, int(b))
    if isinstance(v, np.ndarray):  # a 0-d array: its element
        v = v[()]
    return type(_bits(v)) is type(_bits(twin_value)) and _bits(v) == _bits(twin_value)


class Batch:
    """B stacked rigs and B scalar twins, run through the decoder program of a servo tick."""

    def __init__(self, n: int, max_counts_per_tick: int | None = None) -> None:
        rigs = [_setup(b, max_counts_per_tick) for b in range(n)]
        self.twins = [_setup(b, max_counts_per_tick) for b in range(n)]
        self.crate = _lane_crate([c for c, _ in rigs])
        lanes = self.crate.lanes
        assert lanes is not None
        self.lanes = lanes
        self.drivers = {name: QuadratureDriver.from_lanes([d[name] for _, d in rigs], self.crate)
                        for name, *_ in BOARDS}
        self.n = n
        self.tick = 0
        self.readings: dict[str, Any] = {}
        self.twin_readings: list[dict[str, Any]] = [{} for _ in range(n)]
        self.twin_errors: list[str | None] = [None] * n

    def step(self, counts: np.ndarray, illegal: np.ndarray, phase: np.ndarray,
             offsets: list[list[tuple[int, ...]]]) -> None:
        """One tick: align the clock, publish each net's events (``counts[b, i]`` of net ``i``),
        read every decoder, clear ILLEGAL where a reading found it."""
        self.tick += 1
        self.lanes.tick = self.tick
        t_ns = self.tick * PERIOD_NS
        self.crate.advance_to(t_ns)
        events = [[QuadratureEvents(int(counts[b, i]), int(illegal[b, i]), offsets[b][i], int(phase[b, i]))
                   for i in range(len(NETS))] for b in range(self.n)]
        for i, net in enumerate(NETS):  # as the harness in lanes publishes them
            self.crate.signals.publish_quadrature(net, lane_events([events[b][i] for b in range(self.n)]))
        self.readings = {name: drv.update(PERIOD_S) for name, drv in self.drivers.items()}
        for name, r in self.readings.items():
            for ch, x in r.items():  # its scalar run clears ILLEGAL: a cycle of those lanes only
                self.lanes.eject(x.status.illegal, f"{name} channel {ch}: ILLEGAL clear")
        for b, (crate, drivers) in enumerate(self.twins):  # the scalar program (servo/io.py's read)
            crate.advance_to(t_ns)
            for i, net in enumerate(NETS):
                crate.signals.publish_quadrature(net, events[b][i])
            try:
                self.twin_readings[b] = {name: drv.update(PERIOD_S) for name, drv in drivers.items()}
            except QuadratureError as e:
                self.twin_errors[b] = self.twin_errors[b] or type(e).__name__
                continue
            for name, r in self.twin_readings[b].items():
                for ch, x in r.items():
                    if x.status.illegal:
                        drivers[name].clear_illegal(ch)

    def expected_alive(self, alive: np.ndarray) -> np.ndarray:
        """The lanes still followed, from the twins: those that raised, and those whose cycle
        counters differ from the majority of the others', are left."""
        snaps = [tuple(sorted(c.counter_snapshot().items())) for c, _ in self.twins]
        keep = alive & np.array([e is None for e in self.twin_errors])
        majority, _ = Counter(snaps[b] for b in np.flatnonzero(keep)).most_common(1)[0]
        return keep & np.array([s == majority for s in snaps])

    def check_lanes_equal_twins(self) -> None:
        """Every live lane equals its twin: readings, board state, driver state, clock, counters."""
        for b in np.flatnonzero(self.lanes.alive):
            crate, drivers = self.twins[b]
            assert self.crate.clock.now_ns == crate.clock.now_ns
            assert self.crate.counter_snapshot() == crate.counter_snapshot()
            for name, *_ in BOARDS:
                for ch, x in self.twin_readings[b][name].items():
                    got = self.readings[name][ch]
                    for f in ("channel", "raw", "counts", "position_rad", "velocity_counts_s", "velocity_rad_s"):
                        assert _same(getattr(got, f), b, getattr(x, f)), (self.tick, b, name, ch, f)
                    for f in ("index", "illegal", "overflow", "underflow", "a", "b", "raw"):
                        assert _same(getattr(got.status, f), b, getattr(x.status, f)), (self.tick, b, name, ch, f)
                    t, lt = drivers[name]._track[ch], self.drivers[name]._lane_track[ch]
                    for f in ("raw", "counts", "zero", "tick_counts", "change_counts", "ticks_since_change",
                              "velocity"):
                        assert _same(getattr(lt, f), b, getattr(t, f)), (self.tick, b, name, ch, f)
                board, twin = self.crate.board(name), crate.board(name)
                assert isinstance(board, QuadratureBoard) and isinstance(twin, QuadratureBoard)
                for reg, value in twin.regs.items():
                    assert _same(board.regs[reg], b, value), (self.tick, b, name, reg)
                for c in range(4):
                    lc, sc = board.lane_ch[c], twin.ch[c]
                    for f in ("counter", "acc", "ol", "idx", "status", "phase"):
                        assert _same(getattr(lc, f), b, getattr(sc, f)), (self.tick, b, name, c, f)
                    for k, v in sc.stats.items():
                        assert _same(lc.stats[k], b, v), (self.tick, b, name, c, k)


def _noise(rngs: list[np.random.Generator], n_nets: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """Each lane's own events for one tick, from its own generator: on most ticks no count, else
    up to 6 either way (so the estimator sees quiet spells, 1/T and Δ/dt), a random A/B phase,
    now and then an index pulse."""
    n = len(rngs)
    counts = np.array([np.where(r.random(n_nets) < 0.6, 0, r.integers(-6, 7, n_nets)) for r in rngs], dtype=np.int64)
    phase = np.array([r.integers(0, 4, n_nets) for r in rngs], dtype=np.int64)
    offsets = [[(int(r.integers(-2, 3)),) if r.random() < 0.15 else () for _ in range(n_nets)] for r in rngs]
    return counts, np.zeros((n, n_nets), dtype=np.int64), phase, offsets


def test_lanes_with_different_event_streams_equal_their_scalar_twins_and_only_diverging_lanes_are_ejected():
    batch = Batch(4)
    rngs = [np.random.default_rng([34, b]) for b in range(4)]
    alive = np.ones(4, dtype=bool)
    ejected_at: dict[int, int] = {}
    for k in range(1, 81):
        counts, illegal, phase, offsets = _noise(rngs, len(NETS))
        if k == 1:
            counts += 5000  # away from the 24-bit wrap: the noise alone never crosses it
        elif k in (10, 30):
            counts += -10000 if k == 10 else 10000  # every lane crosses the wrap: every lane clears
        elif k == 50:
            counts[3, 1] -= 20000  # lane 3 alone crosses (UNDERFLOW): every read clears the flags, no divergence
        elif k == 65:
            illegal[2, 4] = 1  # lane 2 alone: ILLEGAL, which the servo tick clears (a cycle of lane 2's only)
        batch.step(counts, illegal, phase, offsets)
        if k == 50:  # lane 3's twin found UNDERFLOW there, the others none
            assert [batch.twin_readings[b]["quad0"][1].status.underflow for b in range(4)] == [False] * 3 + [True]
        expected = batch.expected_alive(alive)
        for b in np.flatnonzero(alive & ~expected):
            ejected_at[int(b)] = k
        alive = expected
        assert np.array_equal(batch.lanes.alive, alive), k
        batch.check_lanes_equal_twins()
    assert ejected_at == {2: 65}
    assert batch.lanes.first_tick == {2: 65}
    assert "ILLEGAL clear" in batch.lanes.reasons[2]
    # set-up: 6 writes a channel (CTL, PRE_HI, PRE_LO, CMD; the driver's latch and flag clear); a
    # tick: 2 latches and a flag clear per channel
    assert [batch.twins[b][0].counters["write.A16.D16"] for b in (0, 1, 3)] == [7 * 6 + 80 * (2 + 7)] * 3
    assert any(batch.readings[name][ch].status.index[0] for name, *_ in BOARDS for ch in batch.readings[name])


def test_lanes_whose_twins_raise_are_ejected_and_a_wrap_in_some_lanes_only_ejects_none():
    batch = Batch(4, max_counts_per_tick=20000)
    rngs = [np.random.default_rng([35, b]) for b in range(4)]
    alive = np.ones(4, dtype=bool)
    for k in range(1, 21):
        counts, illegal, phase, offsets = _noise(rngs, len(NETS))
        if k == 1:
            counts += 5000
        elif k == 5:
            counts[:3, 0] -= 10000  # lanes 0..2 cross the wrap; lane 3 does not (no lane is left for it)
        elif k == 10:
            counts[2, 3] += 90000  # lane 2 (x2 there): a count jump beyond the limit (CountJumpError)
        elif k == 15:
            counts[1, 5] += 9_000_000  # lane 1: > a quarter range, no wrap flag (TrackingLostError)
        batch.step(counts, illegal, phase, offsets)
        alive = batch.expected_alive(alive)
        assert np.array_equal(batch.lanes.alive, alive), k
        batch.check_lanes_equal_twins()
    assert batch.twin_errors == [None, "TrackingLostError", "CountJumpError", None]
    assert batch.lanes.first_tick == {2: 10, 1: 15}
    assert "CountJumpError" in batch.lanes.reasons[2]
    assert "TrackingLostError" in batch.lanes.reasons[1]


def test_lane_board_registers_equal_scalar_boards_under_lane_valued_writes_and_events():
    """The board alone through the bus: every register written with per-lane values (CTL modes
    including hold, index arm, presets, commands, global latch, W1C), events with wraps, illegal
    samples and index pulses, and every readable register read back (D16 and D8)."""
    n = 4
    base = 0x5000
    nets = {0: "a", 1: "b", 2: "c", 3: "d"}
    crates = [Crate("one") for _ in range(2 * n)]
    for c in crates:
        c.install(QuadratureBoard("q", nets=nets), base=base, space="A16", slot=5)
    lanes_crate, twins = _lane_crate(crates[:n]), crates[n:]
    rng = np.random.default_rng(36)
    writable = {"CTL": 0x13, "PRE_HI": 0xFF, "PRE_LO": 0xFFFF, "CMD": 0x7, "STATUS": 0xF}
    readable = ("CTL", "STATUS", "OL_HI", "OL_LO", "CNT_HI", "CNT_LO", "IDX_HI", "IDX_LO", "PRE_HI", "PRE_LO")
    for step in range(300):
        op = rng.integers(0, 4)
        ch = int(rng.integers(0, 4))
        if op == 0:  # a register write, its value per lane (or one value for every lane, a plain int)
            name = list(writable)[rng.integers(0, len(writable))]
            values = rng.integers(0, writable[name] + 1, n)
            if rng.random() < 0.3:
                values[:] = values[0]
                _reg(lanes_crate, base, f"CH{ch}_{name}", int(values[0]))
            else:
                _reg(lanes_crate, base, f"CH{ch}_{name}", values)
            for b, c in enumerate(twins):
                _reg(c, base, f"CH{ch}_{name}", int(values[b]))
        elif op == 1:  # the global latch, a D8 write of CTL's low byte
            values = rng.integers(0, 16, n)
            low = rng.integers(0, 0x14, n)
            ctl = base + BOARD_MAP[f"CH{ch}_CTL"].offset + 1
            writes = [(lanes_crate, values, low)] + [(t, int(values[b]), int(low[b])) for b, t in enumerate(twins)]
            for c, gv, lv in writes:
                c.write(base + BOARD_MAP["GCMD"].offset, gv, space="A16", width=Width.D16)
                c.write(ctl, lv, space="A16", width=Width.D8)
        elif op == 2:  # one interval's events on one channel, different per lane
            counts = rng.integers(-70000, 70000, n) * (rng.random(n) < 0.5) + rng.integers(-5, 6, n)
            illegal = (rng.random(n) < 0.1).astype(np.int64)
            phase = rng.integers(0, 4, n)
            offsets = tuple(tuple(sorted(int(x) for x in rng.integers(-9, 10, rng.integers(0, 3)))) for _ in range(n))
            alike = rng.random() < 0.2  # now and then the same events in every lane
            if alike:
                counts, illegal, phase = (np.full(n, x[0]) for x in (counts, illegal, phase))
                offsets = (offsets[0],) * n
            each = [QuadratureEvents(int(counts[b]), int(illegal[b]), offsets[b], int(phase[b])) for b in range(n)]
            # lane-mode events, or (alike) a plain scalar object: every lane's events
            events = each[0] if alike and rng.random() < 0.5 else lane_events(each)
            lanes_crate.signals.publish_quadrature(nets[ch], events)
            for b, c in enumerate(twins):
                c.signals.publish_quadrature(nets[ch], each[b])
        else:  # read every readable register of the channel, D16, and the OL bytes D8
            for name in readable:
                r = BOARD_MAP[f"CH{ch}_{name}"]
                got = lanes_crate.read(base + r.offset, space="A16", width=r.width)
                for b, c in enumerate(twins):
                    assert _same(got, b, c.read(base + r.offset, space="A16", width=r.width)), (step, name, b)
            for off in (0x09, 0x0A, 0x0B):
                a = base + 0x20 * (ch + 1) + off
                got = lanes_crate.read(a, space="A16", width=Width.D8)
                for b, c in enumerate(twins):
                    assert _same(got, b, c.read(a, space="A16", width=Width.D8)), (step, off, b)
        assert all(lanes_crate.clock.now_ns == c.clock.now_ns for c in twins)
        assert all(lanes_crate.counter_snapshot() == c.counter_snapshot() for c in twins)
    assert lanes_crate.lanes is not None and lanes_crate.lanes.n_alive == n
    board = lanes_crate.board("q")
    assert isinstance(board, QuadratureBoard)
    for b, c in enumerate(twins):  # the state behind the registers too: accumulators, statistics
        twin = c.board("q")
        assert isinstance(twin, QuadratureBoard)
        for ch in range(4):
            for f in ("counter", "acc", "ol", "idx", "status", "phase"):
                assert _same(getattr(board.lane_ch[ch], f), b, getattr(twin.ch[ch], f)), (b, ch, f)
            for k, v in twin.ch[ch].stats.items():
                assert _same(board.lane_ch[ch].stats[k], b, v), (b, ch, k)


def test_stacking_refuses_what_lanes_do_not_run_and_lane_mode_is_chosen_once():
    crates = [Crate("one") for _ in range(2)]
    for c in crates:
        c.install(QuadratureBoard("q", nets={0: "a"}), base=0x5000, space="A16", slot=5)
    crates[1].board("q").inject("glitch", channel=0)
    with pytest.raises(NotImplementedError, match="fault"):
        QuadratureBoard.from_lanes([c.board("q") for c in crates], crates[0])
    crates[1].board("q").clear_fault()
    lanes_crate = _lane_crate(crates)
    with pytest.raises(NotImplementedError, match="per instance"):
        lanes_crate.board("q").inject("glitch", channel=0)
    drivers = [QuadratureDriver(c, 0x5000, counts_per_rev=2000.0, channels=[0]) for c in crates]
    other = QuadratureDriver(crates[1], 0x5000, counts_per_rev=2000.0, channels=[0, 1])
    with pytest.raises(NotImplementedError, match="set up differently"):
        QuadratureDriver.from_lanes([drivers[0], other], lanes_crate)
    with pytest.raises(ValueError, match="bus of lanes"):
        QuadratureDriver.from_lanes(drivers, crates[0])
    drv = QuadratureDriver.from_lanes(drivers, lanes_crate)
    with pytest.raises(NotImplementedError, match="home_at_index"):
        drv.home_at_index(0)
    # the scalar objects keep their class's methods: lane mode is bound on the stacked objects only
    assert "update" in drv.__dict__ and not any("update" in d.__dict__ for d in drivers)
    assert "apply_events" in lanes_crate.board("q").__dict__ and "apply_events" not in crates[0].board("q").__dict__
