"""The VMIVME-3113A ADC board and its driver in lanes (issue #34): B = 4 jpl-arm-vmic racks' adc0
stacked (``Crate.from_lanes``, ``Vmivme3113aBoard.from_lanes``, ``Vmivme3113aDriver.from_lanes``),
driven through the servo tick's read next to 4 scalar twins built the same way; every lane must
equal its twin bit for bit (volts, codes, words, registers, sequencer, noise stream, clock, bus
counters); a lane whose input is NaN or inf (its scalar run raises there) is ejected and the others
still equal their twins.

Each instance's crate holds the rig file's 3113A only (as ``build_emulated_rig`` builds it: the
wired crate table, the references, the H-bridge noise coupling), and its driver is built as
``servo.io.JointIO`` builds it (the board type's driver factory): the other board types' lane forms
are other branches' work.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from emulators.crate import Crate
from emulators.crate_file import build_crate
from emulators.presets import resolve_rig
from emulators.vmivme3113a import Vmivme3113aBoard
from hal.adc_dac.calibration import Calibration
from hal.adc_dac.vmivme3113a import Vmivme3113aDriver
from hal.board_types import BOARD_TYPES
from hal.config import ConfigTable
from hal.lanes import LaneSet, lane, stack
from hal.vme.types import Width
from servo.rig import load_rig
from vmehil.rig_setup.system import _couple_hbridge_noise, publish_references, wired_crate_table

B = 4
SEEDS = (3, 11, 5, 29)
TICK_NS = 8_000_000
SPEC = load_rig(resolve_rig("jpl-arm-vmic"))
#: the servo tick's scan (servo.io: the last channel a joint pin uses on the board)
LAST = max(p.index for j in SPEC.joints for p in j.wiring.values() if p.board == "adc0")
#: a code boundary of the ±10 V range: (V − V₀)/LSB + ½ = 2047 exactly (LSB = 20 V / 4096), so the
#: doc's floor gives code 2047 (a round-half-even would give 2046)
BOUNDARY_V = -10.0 + 2046.5 * 20.0 / 4096
#: 3 ulps below the boundary of codes 2458 and 2459: (V − V₀)/LSB + ½ = 2458.99999…, so the doc's
#: floor gives 2458 (V·(1/LSB) instead of V/LSB rounds to 2459.0)
BELOW_BOUNDARY_V = 2.0043945312499987
CSR = 0x02  # docs/boards/vmivme-3113a.md, register table
CH0 = 0x80


class Rack:
    """One instance: the rig's 3113A in a crate, and its driver."""

    def __init__(self, seed: int, b: int | None = None) -> None:
        table = wired_crate_table(SPEC)
        table.data["crate"]["board"] = [bd for bd in table.data["crate"]["board"] if bd["name"] == "adc0"]
        self.crate = build_crate(ConfigTable(table.data, table.source), seed=seed)
        publish_references(self.crate, SPEC)
        _couple_hbridge_noise(self.crate, SPEC)
        board = self.crate.boards["adc0"]
        assert isinstance(board, Vmivme3113aBoard)
        self.board = board
        factory = BOARD_TYPES["vmivme-3113a"].load_driver()
        self.adc: Vmivme3113aDriver = factory(self.crate, board.base, space=board.space)
        for net in self.nets():
            self.crate.signals.set_analog(net, 0.0)  # every wired net exists from the start
        if b is not None:
            self.vary(b)
            self.set_up()

    def nets(self) -> list[str]:
        return sorted(n for n in self.board.wiring.values() if not n.startswith("ref."))

    def vary(self, b: int) -> None:
        """Lane ``b``'s own electronics: noise (none in lane 1: it never draws), offset and gain
        errors, its own calibration."""
        self.board.noise_rms_v = (0.001, 0.0, 0.003, 0.002)[b]
        if b == 1:  # an ideal board: no noise, no errors (its codes land exactly on code boundaries)
            self.board.offset_v = (0.0,) * 64
            self.board.gain_error = (0.0,) * 64
        if b == 3:
            self.board.offset_v = tuple(0.002 * (ch % 9 - 4) for ch in range(64))
            self.board.gain_error = tuple(0.0005 * (ch % 5) for ch in range(64))
        self.adc.calibration = Calibration(tuple(0.001 * b * (ch % 3) for ch in range(64)),
                                           tuple(1.0 + 0.0007 * b * (ch % 4) for ch in range(64)))

    def set_up(self) -> None:
        """Reads before the batch takes over: the lanes are stacked part-way through their noise
        blocks (lane 1: none drawn)."""
        for _ in range(2):
            self.crate.advance_to(self.crate.clock.now_ns + TICK_NS)
            self.adc.scan(LAST)


def _stacked(racks: list[Rack]) -> tuple[Crate, Vmivme3113aDriver]:
    lc = Crate.from_lanes([r.crate for r in racks], LaneSet(len(racks)))
    return lc, Vmivme3113aDriver.from_lanes([r.adc for r in racks], lc)


def _same_bits(a: Any, b: Any) -> bool:
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _assert_lane_is_twin(lc: Crate, twins: list[Rack], b: int) -> None:
    twin = twins[b]
    assert lc.clock.now_ns == twin.crate.clock.now_ns
    lb, tb = lc.boards["adc0"], twin.board
    assert isinstance(lb, Vmivme3113aBoard)
    assert {r: int(lane(v, b)) for r, v in lb.regs.items()} == tb.regs
    assert int(lane(lb.conversions, b)) == tb.conversions
    assert (lb._held, lb._done_before, lb._seen, lb._runs) == (tb._held, tb._done_before, tb._seen, tb._runs)
    assert lb._run is not None and tb._run is not None
    assert (lb._run.ident, lb._run.start_ns, lb._run.limit) == (tb._run.ident, tb._run.start_ns, tb._run.limit)
    assert lb.noise_state(b) == tb.noise_state(), f"lane {b}'s noise stream"
    for key, count in twin.crate.counters.items():
        assert lc.counters[key] == count, key


def _nets(rng: np.random.Generator, names: list[str], tick: int) -> list[dict[str, float]]:
    """Each lane's net values for one tick: some beyond the ±10 V rails, one net alike in every
    lane (a plain float in lanes), every net alike now and then."""
    out = []
    for _ in range(B):
        values = {n: float(rng.uniform(-11.0, 11.0)) for n in names}
        values["j1.pot"] = BOUNDARY_V
        values["j2.pot"] = BELOW_BOUNDARY_V
        out.append(values)
    if tick % 9 == 4:
        out = [dict(out[0]) for _ in range(B)]
    return out


@pytest.mark.filterwarnings("error")  # a dead lane's garbage must not even warn
def test_3113a_lanes_equal_their_scalar_twins_through_the_servo_read_and_bad_inputs_eject_their_lane() -> None:
    assert LAST == 22  # pots 0..6, tachs 8..13, current monitors 16..22 (the preset's wiring)
    twins = [Rack(s, b) for b, s in enumerate(SEEDS)]
    lc, drv = _stacked([Rack(s, b) for b, s in enumerate(SEEDS)])
    lanes = lc.lanes
    assert lanes is not None
    rng = np.random.default_rng(20261203)
    names = twins[0].nets()
    for b in range(B):
        _assert_lane_is_twin(lc, twins, b)
    nan_lane, nan_tick = 2, 31  # the scalar run's quantize raises ValueError (NaN)
    inf_lane, inf_tick = 3, 47  # the scalar run's math.floor raises OverflowError (inf)
    t = lc.clock.now_ns
    for tick in range(60):
        t += TICK_NS + (tick % 3) * 137_000  # the sequencer's phase moves from tick to tick
        values = _nets(rng, names, tick)
        if tick >= nan_tick:
            values[nan_lane]["j4.pot"] = float("nan")  # channel 3
        if tick >= inf_tick:
            values[inf_lane]["j2.tach"] = float("inf")  # channel 9
        for net in values[0]:
            lc.signals.analog[net] = stack([values[b][net] for b in range(B)])
        lc.advance_to(t)
        followed = [b for b in range(B) if lanes.alive[b]]
        for b in followed:
            twins[b].crate.signals.analog.update(values[b])
            twins[b].crate.advance_to(t)
        volts = drv.scan(LAST)  # servo.io JointIO.read: one scan of the board per tick
        assert volts.shape == (LAST + 1, B) and volts.dtype == np.float64
        for b in followed:
            if tick >= nan_tick and b == nan_lane:
                with pytest.raises(ValueError, match="NaN"):
                    twins[b].adc.scan(LAST)
                assert not lanes.alive[b] and "NaN" in lanes.reasons[b]
                continue
            if tick >= inf_tick and b == inf_lane:
                with pytest.raises(OverflowError):
                    twins[b].adc.scan(LAST)
                assert not lanes.alive[b] and "float range" in lanes.reasons[b]
                continue
            assert _same_bits(volts[:, b], twins[b].adc.scan(LAST)), (tick, b)
        followed = [b for b in range(B) if lanes.alive[b]]
        pots = drv.scan_counts(1)  # j1's and j2's pots again: held codes (no conversion ended since), or new ones
        for b in followed:
            assert _same_bits(pots[:, b], twins[b].adc.scan_counts(1)), (tick, b)
        assert list(pots[:, 1]) == [2047, 2458]  # the ideal lane at code boundaries: the doc's quantizer (floor)
        if tick % 4 == 1:  # every wired channel as raw codes (references, DAC loopback), a reference's volts
            codes = drv.scan_counts(31)
            assert codes.shape == (32, B) and codes.dtype == np.int64
            ref = drv.read_volts(28)
            for b in followed:
                assert _same_bits(codes[:, b], twins[b].adc.scan_counts(31)), (tick, b)
                assert _same_bits(np.float64(lane(ref, b)), np.float64(twins[b].adc.read_volts(28))), (tick, b)
        for b in followed:
            _assert_lane_is_twin(lc, twins, b)
    assert list(lanes.alive) == [True, True, False, False]
    assert set(lanes.reasons) == {nan_lane, inf_lane}
    adc0 = lc.boards["adc0"]
    assert isinstance(adc0, Vmivme3113aBoard) and adc0._lanes is not None
    assert isinstance(adc0._lanes.next, np.ndarray), "a lane without noise keeps its own (unused) index"
    assert twins[0].board.conversions > 60 * (LAST + 1)  # every read converted anew, with the noise


def test_each_lanes_data_format_is_its_own_and_a_lane_changing_mode_alone_is_ejected() -> None:
    twins = [Rack(s, b) for b, s in enumerate(SEEDS)]
    lc, drv = _stacked([Rack(s, b) for b, s in enumerate(SEEDS)])
    lanes = lc.lanes
    assert lanes is not None
    base = twins[0].board.base
    # FAIL_LED_OFF | autoscanning, lanes 1 and 3 with TWOS_COMPLEMENT (bit 12): no MODE change, no ejection
    csr = np.array([0x4000, 0x5000, 0x4000, 0x5000], dtype=np.int64)
    lc.write(base + CSR, csr)
    for b in range(B):
        twins[b].crate.write(base + CSR, int(csr[b]))
    assert lanes.alive.all()
    for tick in range(3):
        t = lc.clock.now_ns + TICK_NS
        values = _nets(np.random.default_rng(tick), twins[0].nets(), tick)
        for net in values[0]:
            lc.signals.analog[net] = stack([values[b][net] for b in range(B)])
        lc.advance_to(t)
        for b in range(B):
            twins[b].crate.signals.analog.update(values[b])
            twins[b].crate.advance_to(t)
        words = lc.read_block(base + CH0, 32, space="A16", width=Width.D16)  # raw words: each lane's format
        for b in range(B):
            twin_words = twins[b].crate.read_block(base + CH0, 32, space="A16", width=Width.D16)
            assert [int(lane(w, b)) for w in words] == twin_words, (tick, b)
            _assert_lane_is_twin(lc, twins, b)
    assert any(int(lane(w, 1)) & 0xF000 == 0xF000 for w in words)  # sign-extended negative codes
    # lane 2 alone leaves autoscanning (MODE 3, scan-and-poll): its scalar run stops its sequencer
    csr = np.array([0x4000, 0x4000, 0x40C0, 0x4000], dtype=np.int64)
    lc.write(base + CSR, csr)
    assert list(lanes.alive) == [True, True, False, True] and "MODE" in lanes.reasons[2]
    for b in (0, 1, 3):
        twins[b].crate.write(base + CSR, int(csr[b]))
    lc.advance_to(lc.clock.now_ns + TICK_NS)
    for b in (0, 1, 3):
        twins[b].crate.advance_to(lc.clock.now_ns)
    codes = drv.scan_counts(LAST)
    for b in (0, 1, 3):
        assert _same_bits(codes[:, b], twins[b].adc.scan_counts(LAST))
        _assert_lane_is_twin(lc, twins, b)


def test_what_cannot_run_in_lanes_is_refused_in_one_line() -> None:
    racks = [Rack(s) for s in SEEDS[:2]]
    lc = Crate("lanes")
    lc.lanes = LaneSet(2)
    boards = [r.board for r in racks]
    boards[1].inject("stuck_channel", channel=0, code=7)
    with pytest.raises(NotImplementedError, match="fault"):
        Vmivme3113aBoard.from_lanes(boards, lc)  # type: ignore[arg-type]
    boards[1].clear_fault()
    with pytest.raises(ValueError, match="lanes"):
        Vmivme3113aBoard.from_lanes(boards, Crate("not lanes"))  # type: ignore[arg-type]
    other = Vmivme3113aBoard("adc0", wiring=boards[0].wiring, input_range="bipolar_5v")
    with pytest.raises(NotImplementedError, match="range"):
        Vmivme3113aBoard.from_lanes([boards[0], other], lc)  # type: ignore[arg-type]
    twos = Vmivme3113aDriver(racks[1].crate, boards[1].base, data_format="twos_complement")
    with pytest.raises(NotImplementedError, match="format"):
        Vmivme3113aDriver.from_lanes([racks[0].adc, twos], lc)
    drv = Vmivme3113aDriver.from_lanes([r.adc for r in racks], lc)
    with pytest.raises(NotImplementedError, match="lane"):
        drv.status()
