"""The reference ADC board and its driver in lanes (issue #34, docs in emulators/adc_lanes.py):
B = 4 jpl-arm crates stacked into one board of lanes per ADC and one driver of lanes, driven
through the servo tick's scans next to 4 scalar twins built the same way; every lane must equal
its twin bit for bit (codes, volts, registers, noise stream, clock), a lane with a NaN input is
ejected and the others still equal their twins.

The lane crate here is a stand-in for ``Crate.from_lanes`` (lane-core): a crate with a
:class:`hal.lanes.LaneSet`, the nets stacked, the ADC boards stacked and installed where the
scalar boards are.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from emulators.adc import AdcBoard
from emulators.clock import SimClock
from emulators.crate import Crate
from hal.adc_dac.adc import AdcDriver
from hal.adc_dac.calibration import Calibration
from hal.lanes import LaneSet, lane, stack
from hal.vme.types import Width
from vmehil.rig_setup.system import EmulatedRig, build_emulated_rig

B = 4
SEEDS = (3, 11, 5, 29)
ADCS = ("adc0", "adc1")
PWM = "hand.pwm"
TICK_NS = 8_000_000


def _vary(rig: EmulatedRig, b: int) -> None:
    """Lane ``b``'s own electronics: noise, offset and gain errors, a second switching-noise
    source of its own level, its own ADC calibration (the same on a lane's source and twin)."""
    adc0, adc1 = (rig.crate.boards[n] for n in ADCS)
    assert isinstance(adc0, AdcBoard) and isinstance(adc1, AdcBoard)
    adc0.noise_rms_v = (0.001, 0.0, 0.003, 0.001)[b]  # lane 1: noise only while the bridge switches
    adc1.noise_rms_v = (0.0, 0.0, 0.002, 0.0)[b]  # lanes 0, 1, 3 of adc1: no draws while it is off
    if b == 3:
        adc0.offset_v = tuple(0.002 * (ch - 8) for ch in range(16))
        adc0.gain_error = tuple(0.0005 * (ch % 5) for ch in range(16))
    adc0.add_switching_noise([PWM, "j1.amp_command"], (0.01, 0.02, 0.0, 0.005)[b])
    rig.io.adc["adc0"].calibration = Calibration(tuple(0.001 * b * (ch % 3) for ch in range(16)),
                                                 tuple(1.0 + 0.0007 * b * (ch % 4) for ch in range(16)))


@pytest.fixture(scope="module")
def rigs() -> tuple[list[EmulatedRig], list[EmulatedRig]]:
    """(sources to stack, their scalar twins): twin b is built exactly as source b."""
    built = [[build_emulated_rig("jpl-arm", seed=s) for s in SEEDS] for _ in range(2)]
    for group in built:
        for b, rig in enumerate(group):
            _vary(rig, b)
    return built[0], built[1]


def _lane_crate(crates: list[Crate]) -> Crate:
    """Stand-in for ``Crate.from_lanes``: the nets stacked, the ADCs stacked and installed."""
    lc = Crate("lanes", clock=SimClock(crates[0].clock.now_ns))
    lc.lanes = LaneSet(len(crates))
    lc.signals.analog.update({net: stack([c.signals.analog[net] for c in crates]) for net in crates[0].signals.analog})
    for name in ADCS:
        boards = [c.boards[name] for c in crates]
        assert all(isinstance(b, AdcBoard) for b in boards)
        lb = AdcBoard.from_lanes(boards, lc)  # type: ignore[arg-type]
        lc.install(lb, base=boards[0].base, space=boards[0].space, slot=boards[0].slot)
    return lc


def _same_bits(a: Any, b: Any) -> bool:
    a, b = np.ascontiguousarray(a), np.ascontiguousarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _assert_lane_is_twin(lc: Crate, twins: list[EmulatedRig], b: int) -> None:
    twin = twins[b].crate
    assert lc.clock.now_ns == twin.clock.now_ns
    for name in ADCS:
        lb, tb = lc.boards[name], twin.boards[name]
        assert isinstance(lb, AdcBoard) and isinstance(tb, AdcBoard)
        assert {r: int(lane(v, b)) for r, v in lb.regs.items()} == tb.regs, name
        assert int(lane(lb.conversions, b)) == tb.conversions
        assert lb._busy == tb._busy
        assert lb.noise_state(b) == tb.noise_state(), f"{name}: lane {b}'s noise stream"


def _nets(rng: np.random.Generator, net_names: list[str], tick: int) -> list[dict[str, float]]:
    """Each lane's net values for one tick: some beyond the ±10 V rails, the bridge switching in
    some lanes and not others, a net alike in every lane."""
    out = []
    for _ in range(B):
        values = {n: float(rng.uniform(-11.0, 11.0)) for n in net_names}
        values[PWM] = float(rng.choice([0.0, 0.0, 0.35]))
        values["j1.amp_command"] = float(rng.choice([-0.2, 0.0, 0.4]))
        values["ref.adc1.12"] = 5.0
        out.append(values)
    if tick % 7 == 0:  # the bridge off everywhere: a net that is one Python float in lanes
        for values in out:
            values[PWM] = 0.0
    return out


def test_adc_lanes_equal_their_scalar_twins_through_the_servo_scans_and_a_nan_lane_is_ejected(rigs) -> None:
    sources, twins = rigs
    lc = _lane_crate([r.crate for r in sources])
    drivers = {name: AdcDriver.from_lanes([r.io.adc[name] for r in sources], lc) for name in ADCS}
    last = sources[0].io._adc_last  # the servo tick's scans: adc0 0..13, adc1 0..6
    assert last == {"adc0": 13, "adc1": 6}
    lanes = lc.lanes
    assert lanes is not None
    rng = np.random.default_rng(20261203)
    net_names = sorted(n for n in lc.signals.analog if n not in (PWM, "ref.adc1.12"))
    for b in range(B):
        _assert_lane_is_twin(lc, twins, b)
    nan_lane, nan_tick = 2, 31
    t = lc.clock.now_ns
    for tick in range(60):
        t += TICK_NS
        values = _nets(rng, net_names, tick)
        if tick >= nan_tick:
            values[nan_lane]["j4.pot"] = float("nan")  # adc0 channel 3
        for net in values[0]:
            lc.signals.analog[net] = stack([values[b][net] for b in range(B)])
        lc.advance_to(t)
        followed = [b for b in range(B) if lanes.alive[b]]
        for b in followed:
            twins[b].crate.signals.analog.update(values[b])
            twins[b].crate.advance_to(t)
        gain: Any = {3: 2, 9: 8, 12: 4} if tick % 5 == 2 else 1  # a gain per channel now and then
        volts = drivers["adc0"].scan(last["adc0"], gain)
        assert volts.shape == (last["adc0"] + 1, B)
        for b in followed:
            if tick >= nan_tick and b == nan_lane:
                with pytest.raises(ValueError, match="NaN"):
                    twins[b].io.adc["adc0"].scan(last["adc0"], gain)
                assert not lanes.alive[b] and "NaN" in lanes.reasons[b]
                continue
            assert _same_bits(volts[:, b], twins[b].io.adc["adc0"].scan(last["adc0"], gain)), (tick, b)
        followed = [b for b in range(B) if lanes.alive[b]]
        if tick % 4 == 1:  # every channel of adc1 (references, DAC loopback), raw codes
            codes = drivers["adc1"].scan_counts(15)
            assert codes.shape == (16, B) and codes.dtype == np.int64
            for b in followed:
                assert _same_bits(codes[:, b], twins[b].io.adc["adc1"].scan_counts(15)), (tick, b)
        volts = drivers["adc1"].scan(last["adc1"])
        for b in followed:
            assert _same_bits(volts[:, b], twins[b].io.adc["adc1"].scan(last["adc1"])), (tick, b)
        for b in followed:
            _assert_lane_is_twin(lc, twins, b)
    assert list(lanes.alive) == [True, True, False, True]
    assert set(lanes.reasons) == {nan_lane}
    adc0 = lc.boards["adc0"]
    assert isinstance(adc0, AdcBoard) and adc0._lanes is not None
    assert isinstance(adc0._lanes.next, np.ndarray), "lanes that drew at different samples keep their own index"


def test_a_lane_whose_csr_write_would_start_a_scan_alone_is_ejected_and_the_others_go_on() -> None:
    sources = [build_emulated_rig("jpl-arm", seed=s) for s in SEEDS]
    twins = [build_emulated_rig("jpl-arm", seed=s) for s in SEEDS]
    lc = _lane_crate([r.crate for r in sources])
    lanes = lc.lanes
    assert lanes is not None
    board = lc.boards["adc1"]
    scan = 0x0002  # CSR.SCAN, as docs/boards/adc.md's bit table
    value = np.array([0, 0, scan, 0], dtype=np.int64)  # only lane 2's program would start a scan
    board.bus_write(0x02, Width.D16, value)
    assert list(lanes.alive) == [True, True, False, True] and "started" in lanes.reasons[2]
    for b in (0, 1, 3):
        twins[b].crate.boards["adc1"].bus_write(0x02, Width.D16, 0)
    drv = AdcDriver.from_lanes([r.io.adc["adc1"] for r in sources], lc)
    volts = drv.scan(6)
    for b in (0, 1, 3):
        assert _same_bits(volts[:, b], twins[b].io.adc["adc1"].scan(6))
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
