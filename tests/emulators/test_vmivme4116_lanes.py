"""The VMIVME-4116 board and driver in lanes (batched lockstep, issue #34): every lane equals its
scalar twin, bit for bit.

Four rigs with a VMIVME-4116 as jpl-arm's dac0 (per-lane offset/gain errors and rails on the board,
a calibration per lane in the driver) are stacked with ``from_lanes``; four more, built the same
way, run scalar as the twins. Both go through the tick's DAC program (servo.io: JointIO.write_torque's
six amplifier commands with one update strobe, a second write while the outputs still settle, the
stop's 0 V to all eight channels and its read-back) with different volts per lane, and every live
lane's registers, latches, codes, output volts, nets, counters and time are compared with its
twin's after every step. The expected values are the twins': an independent (scalar) execution.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from emulators.crate import Crate
from emulators.vmivme4116 import VmiVme4116Board, ideal_volts, ideal_volts_lanes
from hal.adc_dac.calibration import Calibration
from hal.adc_dac.vmivme4116 import (
    Vmi4116RangeError,
    VmiVme4116Driver,
    vmi4116_volts_to_code,
    vmi4116_volts_to_codes,
)
from hal.lanes import LaneSet, lane, stack

B = 4
PERIOD_NS = 8_000_000  # 125 Hz
DELAY_NS = 1_000_000  # the command's computation delay
SETTLE_PART_NS = 3_000  # inside the 10 µs settling time
LSB_V = 20.0 / 65536  # docs/boards/vmivme4116.md: 305.17578125 µV
DAC_NETS = {ch: f"j{ch + 1}.amp_command" for ch in range(6)} | {6: "loop.dac0.6", 7: "loop.dac0.7"}


# --- the rigs -----------------------------------------------------------------------------------
class Rig:
    """One instance's 4116 and its driver, opened as servo.io.JointIO opens jpl-arm's dac0."""

    def __init__(self, b: int, *, update: str = "synchronized", coding: str = "offset_binary",
                 clamp: bool = True, crate: Crate | None = None, parts: Sequence[Rig] = ()) -> None:
        if crate is not None:  # the lane rig: the driver stacked on the lane crate
            self.crate = crate
            self.dac = VmiVme4116Driver.from_lanes([p.dac for p in parts], crate)
            return
        g = np.random.default_rng(200 + b)
        self.crate = c = Crate("jpl-rack")
        c.install(VmiVme4116Board("dac0", wiring=DAC_NETS, update=update, coding=coding,
                                  offset_v=g.uniform(-0.01, 0.01, 8).tolist(),
                                  gain_error=g.uniform(-0.003, 0.003, 8).tolist(), rail_v=10.0 - 0.05 * b),
                  base=0x7000, space="A16", slot=4)
        cal = Calibration(tuple(g.uniform(-0.005, 0.005, 8).tolist()), tuple(g.uniform(0.998, 1.002, 8).tolist()))
        self.dac = VmiVme4116Driver(c, 0x7000, clamp=clamp, calibration=cal, coding=coding,  # type: ignore[arg-type]
                                    synchronized=update == "synchronized")


#: what each instance's set-up wrote before the batch took over (a set-up of its own, as
#: ``vmehil calibrate dac`` makes): every lane's latches, outputs and counts differ when stacked
SETUP_V = [[-3.25 + b, 10.3 - 0.2 * b, 0.0, 2.5 * b - 4.0, 7.0, -9.9, 1e-3 * b, -10.4 + 0.1 * b] for b in range(B)]


def _build(**kw: Any) -> tuple[Rig, list[Rig], LaneSet]:
    """The lane rig (four rigs stacked) and the four scalar twins, each after its own set-up."""
    parts = [Rig(b, **kw) for b in range(B)]
    twins = [Rig(b, **kw) for b in range(B)]
    for b, r in [*enumerate(parts), *enumerate(twins)]:
        if r.dac.clamp:
            r.dac.write_many(dict(enumerate(SETUP_V[b])), update=True)
        r.crate.advance_to(PERIOD_NS // 2)  # settled: no event queued when stacked
    lanes = LaneSet(B)
    return Rig(-1, crate=Crate.from_lanes([p.crate for p in parts], lanes), parts=parts), twins, lanes


def _bits(x: Any) -> bytes:
    return struct.pack("<d", float(x))


def assert_lane_equals_twin(lanes: Rig, twin: Rig, b: int) -> None:
    """Lane ``b`` of the lane rig holds exactly what the scalar twin holds."""
    lc, tc = lanes.crate, twin.crate
    assert lc.clock.now_ns == tc.clock.now_ns
    assert lc.counters == tc.counters
    ld, td = lc.boards["dac0"], tc.boards["dac0"]
    assert isinstance(ld, VmiVme4116Board) and isinstance(td, VmiVme4116Board)
    for reg, value in ld.regs.items():
        assert isinstance(value, int) or value.dtype == np.int64, reg
        assert int(lane(value, b)) == td.regs[reg], reg
    assert [int(lane(v, b)) for v in ld.holding] == td.holding
    assert [int(lane(v, b)) for v in ld.converter] == td.converter
    assert ld._gen == td._gen
    for ch in range(8):
        (t0, vs, vf), (tt0, tvs, tvf) = ld._step[ch], td._step[ch]
        assert (t0, _bits(lane(vs, b)), _bits(lane(vf, b))) == (tt0, _bits(tvs), _bits(tvf)), ch
        assert _bits(lane(ld.output_volts(ch), b)) == _bits(td.output_volts(ch)), ch
        assert _bits(lane(ld.converter_volts(ch), b)) == _bits(td.converter_volts(ch)), ch
    assert lane(ld.updates, b) == td.updates
    assert ld.connected is td.connected
    for net, v in tc.signals.analog.items():
        assert _bits(lane(lc.signals.analog[net], b)) == _bits(v), net
    dl, dt = lanes.dac, twin.dac
    assert lane(dl.clamp_events, b) == dt.clamp_events
    assert [int(lane(v, b)) for v in dl._holding] == dt._holding
    assert [int(lane(v, b)) for v in dl._output] == dt._output


class Program:
    """The tick's driver calls on the 4116 (servo.io), with volts drawn per lane (seeded)."""

    def __init__(self, seed: int, span_v: float = 10.6) -> None:
        self.g = np.random.default_rng(seed)
        self.span_v = span_v

    def volts(self, k: int, twins: Sequence[Rig]) -> np.ndarray:
        """Tick ``k``'s six amplifier commands per lane, shape (6, B)."""
        g = self.g
        if k % 6 == 5:  # commands on a code transition, through each lane's calibration: the last bit counts
            edges = -10.0 + LSB_V * (g.integers(1, 65536, (6, B)) - 0.5)
            return np.array([[twins[b].dac.calibration.apply(ch, edges[ch, b]) for b in range(B)] for ch in range(6)])
        if k % 8 == 7:  # every lane alike: a plain float reaches the drivers
            return np.repeat(g.uniform(-9.0, 9.0, (6, 1)), B, axis=1)
        return g.uniform(-self.span_v, self.span_v, (6, B))  # beyond the range too: clamped (clamp=True)

    @staticmethod
    def write(rig: Rig, volts: np.ndarray, b: int | None) -> dict[int, Any]:
        """JointIO.write_torque's DAC write: the six commands, one strobe. ``b`` None: the lane rig
        (every lane's volts, as lane values); else twin ``b`` (its own, as floats)."""
        cmds = {ch: (stack(volts[ch].tolist()) if b is None else float(volts[ch, b])) for ch in range(6)}
        return rig.dac.write_many(cmds, update=True).codes

    @staticmethod
    def stop(rig: Rig) -> dict[str, Any]:
        """JointIO._stop_outputs' dac_zero and verify_stopped's read-back of the amplifier commands."""
        rig.dac.write_many({ch: 0.0 for ch in range(rig.dac.CHANNELS)}, update=True)
        return {ch: (rig.dac.code_for(ch, 0.0)[0], rig.dac.read_back_counts(ch)) for ch in range(6)}


def _compare(lane_rig: Rig, twins: Sequence[Rig], lanes: LaneSet, got: Any, want: Sequence[Any]) -> None:
    for b, t in enumerate(twins):
        if not lanes.alive[b]:
            continue
        assert {ch: tuple(int(lane(x, b)) for x in v) if isinstance(v, tuple) else int(lane(v, b))
                for ch, v in got.items()} == want[b]
        assert_lane_equals_twin(lane_rig, t, b)


def _run(lane_rig: Rig, twins: Sequence[Rig], lanes: LaneSet, prog: Program, ticks: int) -> None:
    rigs: list[tuple[Rig, int | None]] = [(lane_rig, None), *((t, b) for b, t in enumerate(twins))]
    # as stacked: each lane holds its set-up's latches, outputs and counts (and reads them back)
    _compare(lane_rig, twins, lanes, {ch: (lane_rig.dac.read_back_counts(ch),) for ch in range(8)},
             [{ch: (t.dac.read_back_counts(ch),) for ch in range(8)} for t in twins])
    for k in range(ticks):
        volts = prog.volts(k, twins) if k else np.zeros((6, B))
        codes = []
        for rig, b in rigs:
            rig.crate.advance_to(PERIOD_NS + k * PERIOD_NS)
            codes.append(Program.write(rig, volts, b))
        _compare(lane_rig, twins, lanes, codes[0], codes[1:])
        if k % 4 == 2:  # a second write while the outputs settle (a stop right after a tick's write)
            volts2 = prog.volts(k + 1, twins)
            codes = []
            for rig, b in rigs:
                rig.crate.advance_to(PERIOD_NS + k * PERIOD_NS + SETTLE_PART_NS)
                codes.append(Program.write(rig, volts2, b))
            _compare(lane_rig, twins, lanes, codes[0], codes[1:])
        for rig, _b in rigs:  # inside the settling time: the outputs on their way, the nets not yet
            rig.crate.advance_to(PERIOD_NS + k * PERIOD_NS + 2 * SETTLE_PART_NS)
        _compare(lane_rig, twins, lanes, {}, [{}] * B)
        for rig, _b in rigs:
            rig.crate.advance_to(PERIOD_NS + k * PERIOD_NS + DELAY_NS)
        _compare(lane_rig, twins, lanes, {}, [{}] * B)
    got = [Program.stop(rig) for rig, _b in rigs]
    want = [{ch: (int(z), int(c)) for ch, (z, c) in g.items()} for g in got[1:]]
    _compare(lane_rig, twins, lanes, got[0], want)
    for rig, _b in rigs:
        rig.crate.advance_to(PERIOD_NS + ticks * PERIOD_NS)
    _compare(lane_rig, twins, lanes, {}, [{}] * B)


# --- the tick's program -------------------------------------------------------------------------
@pytest.mark.parametrize(("update", "coding"), [("synchronized", "offset_binary"), ("synchronized", "twos_complement"),
                                                ("immediate", "offset_binary")])
def test_every_lane_of_the_4116_tick_program_equals_its_scalar_twin(update: str, coding: str) -> None:
    lane_rig, twins, lanes = _build(update=update, coding=coding)
    _run(lane_rig, twins, lanes, Program(seed=7), ticks=60)
    assert lanes.n_alive == B, lanes.reasons
    board = lane_rig.crate.boards["dac0"]
    assert isinstance(board, VmiVme4116Board)
    # the stop's 0 V goes through each lane's calibration: codes per lane, (B,) int64
    assert all(isinstance(c, np.ndarray) and c.dtype == np.int64 for c in board.converter)
    assert isinstance(lane_rig.dac.clamp_events, np.ndarray) and lane_rig.dac.clamp_events.min() > 0
    # the nets the amplifiers read differ per lane (the lanes' offset errors): (B,) lane values
    assert isinstance(lane_rig.crate.signals.analog["j1.amp_command"], np.ndarray)


def test_a_lane_whose_command_is_nan_is_ejected_where_the_scalar_driver_raises() -> None:
    lane_rig, twins, lanes = _build()
    prog = Program(seed=3)
    rigs: list[tuple[Rig, int]] = list((t, b) for b, t in enumerate(twins))
    for k in range(50):
        volts = prog.volts(k, twins) if k else np.zeros((6, B))
        if k >= 20:  # lane 1's command is NaN from tick 20: its twin's driver raises then, and stops
            volts[2, 1] = np.nan
        lane_rig.crate.advance_to(PERIOD_NS + k * PERIOD_NS)
        got = Program.write(lane_rig, volts, None)
        want: list[Any] = []
        for t, b in rigs:
            t.crate.advance_to(PERIOD_NS + k * PERIOD_NS)
            if b == 1 and k >= 20:
                if k == 20:
                    with pytest.raises(ValueError, match="NaN"):
                        Program.write(t, volts, b)
                want.append(None)
                continue
            want.append(Program.write(t, volts, b))
        assert lanes.alive.tolist() == [True, k < 20, True, True]
        _compare(lane_rig, twins, lanes, got, want)
    assert "not a number" in lanes.reasons[1]


def test_a_lane_whose_command_is_out_of_range_without_clamp_is_ejected_where_the_scalar_driver_raises() -> None:
    lane_rig, twins, lanes = _build(clamp=False)
    volts = np.array([[9.0, -9.5, 10.2, 1.0]])  # lane 2: past +9.999695 V
    with pytest.raises(Vmi4116RangeError):
        Program.write(twins[2], np.repeat(volts, 6, axis=0), 2)
    want = [Program.write(twins[b], np.repeat(volts, 6, axis=0), b) if b != 2 else None for b in range(B)]
    got = Program.write(lane_rig, np.repeat(volts, 6, axis=0), None)
    assert lanes.alive.tolist() == [True, True, False, True]
    assert "outside the output range" in lanes.reasons[2]
    _compare(lane_rig, twins, lanes, got, want)


def test_raw_codes_per_lane_reach_each_lane_and_a_code_past_16_bits_is_ejected() -> None:
    lane_rig, twins, lanes = _build()
    codes = [0x1234, 0xFFFF, 0x10000, 0x0000]  # lane 2: past 0xFFFF, its twin's driver raises
    with pytest.raises(ValueError, match="outside 0..0xFFFF"):
        twins[2].dac.write_counts(5, codes[2])
    for b in (0, 1, 3):
        twins[b].dac.write_counts(5, codes[b])
    lane_rig.dac.write_counts(5, np.array(codes, dtype=np.int64))
    assert lanes.alive.tolist() == [True, True, False, True]
    assert "outside 0..0xFFFF" in lanes.reasons[2]
    _compare(lane_rig, twins, lanes, {}, [{}] * B)


def test_a_csr_write_that_differs_between_lanes_takes_the_majoritys_and_ejects_the_others() -> None:
    lane_rig, twins, lanes = _build()
    csr = [0x4300, 0x4300, 0x0000, 0x4300]  # lane 2: outputs off P3, no strobe; the others: the update
    for b, t in enumerate(twins):
        if b != 2:
            t.crate.write(0x7010, csr[b], space="A16")
    lane_rig.crate.write(0x7010, np.array(csr, dtype=np.int64), space="A16")
    assert lanes.alive.tolist() == [True, True, False, True]
    assert "CSR" in lanes.reasons[2]
    _compare(lane_rig, twins, lanes, {}, [{}] * B)


def test_boards_with_an_injected_fault_or_other_jumpers_do_not_stack() -> None:
    parts = [Rig(b) for b in range(2)]
    parts[1].crate.boards["dac0"].inject("dead_channel", channel=3)
    with pytest.raises(NotImplementedError, match="fault"):
        Crate.from_lanes([p.crate for p in parts], LaneSet(2))
    parts = [Rig(0), Rig(1, coding="twos_complement")]
    with pytest.raises(NotImplementedError, match="jumpers"):
        Crate.from_lanes([p.crate for p in parts], LaneSet(2))


# --- the conversions' array forms ---------------------------------------------------------------
@pytest.mark.parametrize("coding", ["offset_binary", "twos_complement"])
def test_the_array_4116_conversion_gives_the_scalar_codes_bit_for_bit(coding: str) -> None:
    g = np.random.default_rng(3)
    edges = -10.0 + LSB_V * (np.arange(-3, 65540) - 0.5)  # every transition, and beyond the ends
    near = [edges[::4]]  # and a few ulps either side of every fourth (where x·(1/LSB) and x/LSB part)
    for _ in range(5):
        near += [np.nextafter(near[-1], 20)]
    below = [edges[::4]]
    for _ in range(5):
        below += [np.nextafter(below[-1], -20)]
    volts = np.concatenate([g.uniform(-10.5, 10.5, 3000), edges, np.nextafter(edges, 20), np.nextafter(edges, -20),
                            *near[2:], *below[2:], [np.nan, np.inf, -np.inf, 1e306, -1e306]])
    codes, clipped, invalid = vmi4116_volts_to_codes(volts, coding)  # type: ignore[arg-type]
    zero = 0x0000 if coding == "twos_complement" else 0x8000
    for v, c, k, bad in zip(volts.tolist(), codes.tolist(), clipped.tolist(), invalid.tolist(), strict=True):
        try:
            want = vmi4116_volts_to_code(v, coding)  # type: ignore[arg-type]
        except (ValueError, OverflowError):
            assert bad and (c, k) == (zero, False), v
            continue
        assert not bad and (c, k) == want, v


@pytest.mark.parametrize("coding", ["offset_binary", "twos_complement"])
def test_the_lane_ideal_volts_give_the_scalar_volts_bit_for_bit(coding: str) -> None:
    codes = np.arange(65536, dtype=np.int64)
    got = ideal_volts_lanes(codes, coding)
    assert [_bits(v) for v in got.tolist()] == [_bits(ideal_volts(c, coding)) for c in range(65536)]
    assert _bits(ideal_volts_lanes(0x8001, coding)) == _bits(ideal_volts(0x8001, coding))


# --- end to end: the fingerprint's VMIVME-4116 case as lanes --------------------------------------
@pytest.mark.slow  # ≈ 2.5 s of call time (eight lane runs, eight scalar runs)
def test_the_arm_on_a_4116_runs_as_eight_lanes_with_each_scalar_runs_figures() -> None:
    from tests.emulators.lockstep_fingerprint import _REFERENCE_DAC, _VMIVME_4116, BATCH_CASES
    from vmehil.analysis.batch import simulate_batch
    from vmehil.analysis.lane_batch import LaneReport
    from vmehil.analysis.rigparams import load_joint
    from vmehil.analysis.simulate import SimRun, SimSettings, simulate
    from vmehil.analysis.sweep import rig_text, task_rig

    _label, rig, gains, plant, seed, faults = next(c for c in BATCH_CASES if c[0] == "VMIVME-4116 DAC")
    assert rig == "jpl-arm/vmivme-4116" and not plant and not faults
    text = rig_text("jpl-arm").replace(_REFERENCE_DAC, _VMIVME_4116)
    assert text.count(_VMIVME_4116) == 1
    sim = SimSettings(seed=seed, move_deg=5, hold_s=0.1, allow_short=True)  # the case's rig, seed, gains; shorter
    # the fingerprint's case (kp 90) and seven gain points around it: every lane's values differ
    points = [gains, *({"kp": kp} for kp in (70.0, 80.0, 100.0, 110.0)), {"kp": 90.0, "kvi": 700.0},
              {"kv": 40.0}, {"kp": 120.0, "kvi": 650.0}]
    jps = [load_joint(task_rig(text, "jpl-arm", 1), 1, gains=p) for p in points]
    report = LaneReport(len(jps))
    got = simulate_batch([SimRun(jp, False, sim) for jp in jps], traces=True, report=report)
    assert report.scalar_reason is None and report.vector_ticks > 0, report.scalar_reason
    assert report.ejected == {}, report.ejected  # no lane of this case diverges: all followed to the end
    for g, jp in zip(got, jps, strict=True):
        want = simulate(jp, False, sim, traces=True)
        assert json.dumps(g, sort_keys=True) == json.dumps(want, sort_keys=True)
