"""The reference ADC board and its driver in lanes (issue #34): B = 4 jpl-arm racks' ADCs stacked
(``Crate.from_lanes``, ``AdcBoard.from_lanes``, ``AdcDriver.from_lanes``), driven through the servo
tick's scans next to 4 scalar twins built the same way; every lane must equal its twin bit for bit
(codes, volts, registers, noise stream, clock, bus counters); a lane whose input is NaN or inf
(its scalar run raises there) is ejected and the others still equal their twins.

Each instance's crate holds the rig file's two ADC boards only (as ``build_emulated_rig`` builds
them: wiring, noise, references, the H-bridge switching noise), and its ADC drivers are built as
``servo.io.JointIO`` builds them: the other board types' lane forms are other branches' work.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from emulators.adc import AdcBoard
from emulators.crate import Crate
from emulators.crate_file import build_crate
from emulators.presets import resolve_rig
from hal.adc_dac.adc import AdcDriver
from hal.adc_dac.calibration import Calibration
from hal.config import ConfigTable
from hal.lanes import LaneSet, lane, stack
from servo.rig import load_rig
from vmehil.rig_setup.system import _couple_hbridge_noise, publish_references, wired_crate_table

B = 4
SEEDS = (3, 11, 5, 29)
ADCS = ("adc0", "adc1")
PWM = "hand.pwm"
TICK_NS = 8_000_000
SPEC = load_rig(resolve_rig("jpl-arm"))
#: the servo tick's scans (servo.io: the last channel a joint pin uses on each board)
LAST = {name: max(p.index for j in SPEC.joints for p in j.wiring.values() if p.board == name) for name in ADCS}


class Rack:
    """One instance: the rig's ADC boards in a crate, and their drivers."""

    def __init__(self, seed: int, b: int | None = None) -> None:
        table = wired_crate_table(SPEC)
        table.data["crate"]["board"] = [bd for bd in table.data["crate"]["board"] if bd["type"] == "adc"]
        self.crate = build_crate(ConfigTable(table.data, table.source), seed=seed)
        publish_references(self.crate, SPEC)
        _couple_hbridge_noise(self.crate, SPEC)
        self.boards: dict[str, AdcBoard] = {}
        for name in ADCS:
            board = self.crate.boards[name]
            assert isinstance(board, AdcBoard)
            self.boards[name] = board
        self.adc = {name: AdcDriver(self.crate, bd.base, space=bd.space) for name, bd in self.boards.items()}
        for net in self.nets():
            self.crate.signals.set_analog(net, 0.0)  # every wired net exists from the start
        if b is not None:
            self.vary(b)
            self.set_up(b)

    def nets(self) -> list[str]:
        return sorted({n for bd in self.boards.values() for n in bd.wiring.values()} | {PWM})

    def vary(self, b: int) -> None:
        """Lane ``b``'s own electronics: noise, offset and gain errors, a second switching-noise
        source of its own level, its own ADC calibration."""
        adc0, adc1 = (self.boards[n] for n in ADCS)
        adc0.noise_rms_v = (0.001, 0.0, 0.003, 0.001)[b]  # lane 1: noise only while the bridge switches
        adc1.noise_rms_v = (0.0, 0.0, 0.002, 0.0)[b]  # adc1 of lanes 0, 1, 3: no draw while it is off
        if b == 3:
            adc0.offset_v = tuple(0.002 * (ch - 8) for ch in range(16))
            adc0.gain_error = tuple(0.0005 * (ch % 5) for ch in range(16))
        adc0.add_switching_noise([PWM, "j1.amp_command"], (0.01, 0.02, 0.0, 0.005)[b])
        self.adc["adc0"].calibration = Calibration(tuple(0.001 * b * (ch % 3) for ch in range(16)),
                                                   tuple(1.0 + 0.0007 * b * (ch % 4) for ch in range(16)))

    def set_up(self, b: int) -> None:
        """Scans before the batch takes over, with the bridge switching in lane 1 only: the lanes
        are stacked part-way through their noise blocks, at different indices (or none drawn)."""
        self.crate.signals.set_analog(PWM, 0.35 if b == 1 else 0.0)
        for _ in range(2):
            for name in ADCS:
                self.adc[name].scan(LAST[name])


def _stacked(racks: list[Rack]) -> tuple[Crate, dict[str, AdcDriver]]:
    lc = Crate.from_lanes([r.crate for r in racks], LaneSet(len(racks)))
    return lc, {name: AdcDriver.from_lanes([r.adc[name] for r in racks], lc) for name in ADCS}


def _same_bits(a: Any, b: Any) -> bool:
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _assert_lane_is_twin(lc: Crate, twins: list[Rack], b: int) -> None:
    twin = twins[b]
    assert lc.clock.now_ns == twin.crate.clock.now_ns
    for name in ADCS:
        lb, tb = lc.boards[name], twin.boards[name]
        assert isinstance(lb, AdcBoard) and isinstance(tb, AdcBoard)
        assert {r: int(lane(v, b)) for r, v in lb.regs.items()} == tb.regs, name
        assert int(lane(lb.conversions, b)) == tb.conversions
        assert lb._busy == tb._busy
        assert lb.noise_state(b) == tb.noise_state(), f"{name}: lane {b}'s noise stream"
    for key, count in twin.crate.counters.items():
        assert lc.counters[key] == count, key


def _nets(rng: np.random.Generator, names: list[str], tick: int) -> list[dict[str, float]]:
    """Each lane's net values for one tick: some beyond the ±10 V rails, the bridge switching in
    some lanes and not others, a net alike in every lane."""
    out = []
    for _ in range(B):
        values = {n: float(rng.uniform(-11.0, 11.0)) for n in names}
        values[PWM] = float(rng.choice([0.0, 0.0, 0.35]))
        values["j1.amp_command"] = float(rng.choice([-0.2, 0.0, 0.4]))
        values["ref.adc1.12"] = 5.0
        out.append(values)
    if tick % 7 == 0:  # the bridge off everywhere: a net that is one Python float in lanes
        for values in out:
            values[PWM] = 0.0
    return out


@pytest.mark.filterwarnings("error")  # a dead lane's garbage must not even warn
def test_adc_lanes_equal_their_scalar_twins_through_the_servo_scans_and_bad_inputs_eject_their_lane() -> None:
    assert LAST == {"adc0": 13, "adc1": 6}  # pots 0..6, tachs 8..13; current monitors 0..6
    twins = [Rack(s, b) for b, s in enumerate(SEEDS)]
    lc, drivers = _stacked([Rack(s, b) for b, s in enumerate(SEEDS)])
    lanes = lc.lanes
    assert lanes is not None
    rng = np.random.default_rng(20261203)
    names = twins[0].nets()
    for b in range(B):
        _assert_lane_is_twin(lc, twins, b)
    nan_lane, nan_tick = 2, 31  # the scalar run's quantizer raises ValueError (NaN)
    inf_lane, inf_tick = 3, 47  # the scalar run's math.floor raises OverflowError (inf)
    t = lc.clock.now_ns
    for tick in range(60):
        t += TICK_NS
        values = _nets(rng, names, tick)
        if tick >= nan_tick:
            values[nan_lane]["j4.pot"] = float("nan")  # adc0 channel 3
        if tick >= inf_tick:
            values[inf_lane]["j2.tach"] = float("inf")  # adc0 channel 9
        for net in values[0]:
            lc.signals.analog[net] = stack([values[b][net] for b in range(B)])
        lc.advance_to(t)
        followed = [b for b in range(B) if lanes.alive[b]]
        for b in followed:
            twins[b].crate.signals.analog.update(values[b])
            twins[b].crate.advance_to(t)
        gain: Any = {3: 2, 9: 8, 12: 4} if tick % 5 == 2 else 1  # a gain per channel now and then
        volts = drivers["adc0"].scan(LAST["adc0"], gain)
        assert volts.shape == (LAST["adc0"] + 1, B)
        for b in followed:
            if tick >= nan_tick and b == nan_lane:
                with pytest.raises(ValueError, match="NaN"):
                    twins[b].adc["adc0"].scan(LAST["adc0"], gain)
                assert not lanes.alive[b] and "NaN" in lanes.reasons[b]
                continue
            if tick >= inf_tick and b == inf_lane:
                with pytest.raises(OverflowError):
                    twins[b].adc["adc0"].scan(LAST["adc0"], gain)
                assert not lanes.alive[b] and "float range" in lanes.reasons[b]
                continue
            assert _same_bits(volts[:, b], twins[b].adc["adc0"].scan(LAST["adc0"], gain)), (tick, b)
        followed = [b for b in range(B) if lanes.alive[b]]
        if tick % 4 == 1:  # every channel of adc1 (references, DAC loopback), raw codes
            codes = drivers["adc1"].scan_counts(15)
            assert codes.shape == (16, B) and codes.dtype == np.int64
            for b in followed:
                assert _same_bits(codes[:, b], twins[b].adc["adc1"].scan_counts(15)), (tick, b)
        volts = drivers["adc1"].scan(LAST["adc1"])
        for b in followed:
            assert _same_bits(volts[:, b], twins[b].adc["adc1"].scan(LAST["adc1"])), (tick, b)
        for b in followed:
            _assert_lane_is_twin(lc, twins, b)
    assert list(lanes.alive) == [True, True, False, False]
    assert set(lanes.reasons) == {nan_lane, inf_lane}
    adc0 = lc.boards["adc0"]
    assert isinstance(adc0, AdcBoard) and adc0._lanes is not None
    assert isinstance(adc0._lanes.next, np.ndarray), "lanes that drew at different samples keep their own index"


def test_a_lane_whose_csr_write_would_start_a_scan_alone_is_ejected_and_the_others_go_on() -> None:
    twins = [Rack(s) for s in SEEDS]
    lc, drivers = _stacked([Rack(s) for s in SEEDS])
    lanes = lc.lanes
    assert lanes is not None
    scan = 0x0002  # CSR.SCAN, as docs/boards/adc.md's bit table
    lc.write(twins[0].boards["adc1"].base + 0x02, np.array([0, 0, scan, 0], dtype=np.int64))  # lane 2 alone
    assert list(lanes.alive) == [True, True, False, True] and "started" in lanes.reasons[2]
    for b in (0, 1, 3):
        twins[b].crate.write(twins[b].boards["adc1"].base + 0x02, 0)
    volts = drivers["adc1"].scan(6)
    for b in (0, 1, 3):
        assert _same_bits(volts[:, b], twins[b].adc["adc1"].scan(6))
        _assert_lane_is_twin(lc, twins, b)


def test_what_cannot_run_in_lanes_is_refused_in_one_line() -> None:
    crates = [Crate(f"c{b}") for b in range(2)]
    boards = [c.install(AdcBoard("adc0", wiring={0: "in"}, seed=b), base=0x6000, space="A16")
              for b, c in enumerate(crates)]
    lc = Crate("lanes")
    lc.lanes = LaneSet(2)
    boards[1].inject("stuck_channel", channel=0, code=7)
    with pytest.raises(NotImplementedError, match="fault"):
        AdcBoard.from_lanes(boards, lc)  # type: ignore[arg-type]
    boards[1].clear_fault()
    boards[0].add_noise_source(lambda: 0.0)
    with pytest.raises(NotImplementedError, match="add_noise_source"):
        AdcBoard.from_lanes(boards, lc)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="lanes"):
        AdcBoard.from_lanes(boards, Crate("not lanes"))  # type: ignore[arg-type]
    drivers = [AdcDriver(c, 0x6000) for c in crates]
    drivers[1].enable_interrupts(3, 0x40)
    with pytest.raises(NotImplementedError, match="interrupt"):
        AdcDriver.from_lanes(drivers, lc)
