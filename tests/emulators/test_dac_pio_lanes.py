"""DAC and PIO boards and drivers in lanes (batched lockstep, issue #34): every lane equals its
scalar twin, bit for bit.

Four jpl-arm-like rigs (a DAC with per-lane offset/gain errors, a driver calibration per lane,
two PIO boards wired as the rig file wires them) are stacked with ``from_lanes``; four more,
built the same way, run scalar as the twins. Both go through the servo tick's program on these
boards (servo.io: the fault port read, the hand's PWM with its direction line, one DAC strobe
for the six amplifier commands, the brakes released on the first write, the watchdog line
toggled, enables and resets) with different inputs per lane, and every live lane's registers,
nets, returned values, counters and time are compared with its twin's after every step.
"""

from __future__ import annotations

import struct
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from emulators.crate import Crate
from emulators.dac import DacBoard
from emulators.pio import PioBoard
from hal.adc_dac.calibration import Calibration
from hal.adc_dac.conversions import dac_volts_to_code, dac_volts_to_codes
from hal.adc_dac.dac import DacDriver
from hal.amplifiers import duty_for_current, duty_for_current_array
from hal.lanes import LaneSet, lane, stack
from hal.pio.pio import LineStuckError, PioDriver

B = 4
PERIOD_NS = 8_000_000  # 125 Hz
DELAY_NS = 1_000_000  # the command's computation delay: the DAC settles before the exchange
DAC_NETS = {ch: f"j{ch + 1}.amp_command" for ch in range(6)} | {6: "loop.dac0.6", 7: "loop.dac0.7"}
FAULTS = [f"j{i}.amp_fault" for i in range(1, 7)] + ["hand.amp_fault"]
ENABLES = [f"j{i}.amp_enable" for i in range(1, 7)] + ["hand.amp_enable"]
RESETS = [f"j{i}.amp_reset" for i in range(1, 7)] + ["hand.amp_reset"]
BRAKES = ["j2.holding_brake", "j3.holding_brake", "j4.holding_brake", "j6.holding_brake"]
TACTILE = ["hand.tactile_left", "hand.tactile_right"]
# emulators/presets/jpl-arm.toml's wiring of pio0 and pio1
PIO0 = ({f"j{i + 1}.amp_enable": f"PA{i}" for i in range(6)} | {"hand.direction": "PA6", "hand.brake": "PA7"}
        | {f: f"PB{i}" for i, f in enumerate(FAULTS)} | {"rig.watchdog": "PB7"}
        | {f"j{i + 1}.amp_reset": f"PC{i}" for i in range(6)} | {"hand.amp_reset": "PC6", "hand.amp_enable": "PC7"})
PIO1 = {n: f"PA{i}" for i, n in enumerate(BRAKES)} | {n: f"PB{i}" for i, n in enumerate(TACTILE)}
PIO0_OUT = [*ENABLES, "hand.direction", "hand.brake", *RESETS, "rig.watchdog"]


# --- the rigs -----------------------------------------------------------------------------------
class Rig:
    """One instance's boards and drivers, set up as servo.io.JointIO sets up jpl-arm's."""

    def __init__(self, b: int, crate: Crate | None = None, parts: Sequence[Rig] = ()) -> None:
        if crate is not None:  # the lane rig: the drivers stacked on the lane crate
            self.crate = crate
            self.dac = DacDriver.from_lanes([p.dac for p in parts], crate)
            self.pio0 = PioDriver.from_lanes([p.pio0 for p in parts], crate)
            self.pio1 = PioDriver.from_lanes([p.pio1 for p in parts], crate)
            return
        g = np.random.default_rng(100 + b)
        self.crate = c = Crate("jpl-rack")
        c.install(DacBoard("dac0", wiring=DAC_NETS, offset_v=g.uniform(-0.01, 0.01, 8).tolist(),
                           gain_error=g.uniform(-0.003, 0.003, 8).tolist(), rail_v=10.0 - 0.05 * b),
                  base=0x7000, space="A16", slot=4)
        c.install(PioBoard("pio0", lines={p: n for n, p in PIO0.items()}, pwm_net="hand.pwm"),
                  base=0x4000, space="A16", slot=5)
        c.install(PioBoard("pio1", lines={p: n for n, p in PIO1.items()}), base=0x4100, space="A16", slot=10)
        for net in FAULTS + TACTILE:
            c.signals.set_digital(net, False)
        cal = Calibration(tuple(g.uniform(-0.005, 0.005, 8).tolist()), tuple(g.uniform(0.998, 1.002, 8).tolist()))
        self.dac = DacDriver(c, 0x7000, clamp=True, calibration=cal)
        self.pio0 = PioDriver(c, 0x4000, lines=PIO0)
        self.pio1 = PioDriver(c, 0x4100, lines=PIO1)
        self.pio0.configure(outputs=PIO0_OUT, initial={o: False for o in PIO0_OUT})
        self.pio1.configure(outputs=BRAKES, initial={o: False for o in BRAKES})
        self.pio0.set_pwm_period(5e-5)


def _bits(x: Any) -> bytes:
    return struct.pack("<d", float(x))


def assert_lane_equals_twin(lanes: Rig, twin: Rig, b: int) -> None:
    """Lane ``b`` of the lane rig holds exactly what the scalar twin holds."""
    lc, tc = lanes.crate, twin.crate
    assert lc.clock.now_ns == tc.clock.now_ns
    assert lc.counters == tc.counters
    for name, board in lc.boards.items():
        tb = tc.boards[name]
        for reg, value in board.regs.items():
            assert isinstance(value, int) or value.dtype == np.int64, (name, reg)
            assert int(lane(value, b)) == tb.regs[reg], (name, reg)
    ld, td = lc.boards["dac0"], tc.boards["dac0"]
    for ch in range(8):
        (t0, vs, vf), (tt0, tvs, tvf) = ld._step[ch], td._step[ch]
        assert (t0, _bits(lane(vs, b)), _bits(lane(vf, b))) == (tt0, _bits(tvs), _bits(tvf)), ch
        assert _bits(lane(ld.output_volts(ch), b)) == _bits(td.output_volts(ch)), ch
    assert lane(ld.updates, b) == td.updates
    for name in ("pio0", "pio1"):
        assert [lane(v, b) for v in lc.boards[name]._prev_inputs] == tc.boards[name]._prev_inputs
    for net, v in tc.signals.analog.items():
        assert _bits(lane(lc.signals.analog[net], b)) == _bits(v), net
    for net, v in tc.signals.digital.items():
        assert bool(lane(lc.signals.digital[net], b)) is v, net
    assert lane(lanes.dac.clamp_events, b) == twin.dac.clamp_events
    for attr in ("_ddr", "_latch", "_period_ticks"):
        for ld_, td_ in ((lanes.pio0, twin.pio0), (lanes.pio1, twin.pio1)):
            got, want = getattr(ld_, attr), getattr(td_, attr)
            assert ([lane(v, b) for v in got] if isinstance(want, list) else lane(got, b)) == want, attr


class Program:
    """The servo tick's driver calls on these boards, with inputs drawn per lane (seeded)."""

    def __init__(self, seed: int, flip_alone: tuple[int, int] | None = None) -> None:
        self.g = np.random.default_rng(seed)
        self.flip_alone = flip_alone  #: (tick, lane): that lane's hand reverses alone then
        self.sign = 1.0
        self.watchdog = False

    def inputs(self, k: int, twins: Sequence[Rig]) -> dict[str, Any]:
        """Tick ``k``'s inputs per lane: net levels the plant drives, amplifier commands, the
        hand's current and speed (or its duty itself)."""
        g = self.g
        if k % 7 == 3:
            self.sign = -self.sign  # every lane's hand reverses together
        sign = np.full(B, self.sign)
        if self.flip_alone is not None and k >= self.flip_alone[0]:
            sign[self.flip_alone[1]] = -self.sign
        nets = {n: g.random(B) < 0.15 for n in FAULTS + TACTILE}
        volts = g.uniform(-10.6, 10.6, (6, B))  # beyond ±10 V too: clamped (clamp=True)
        if k % 6 == 5:  # outputs on a code transition, through each lane's calibration: the last bit counts
            edges = -10.0 + 20.0 / 4096 * (g.integers(1, 4096, (6, B)) - 0.5)
            volts = np.array([[twins[b].dac.calibration.apply(ch, edges[ch, b]) for b in range(B)] for ch in range(6)])
        x = {"nets": nets if k % 5 == 2 else {}, "volts": volts,
             "amps": sign * g.uniform(0.0, 3.0, B), "omega": sign * g.uniform(0.0, 20.0, B)}
        if k % 9 == 4:  # the duty itself: half a timer tick (round half to even), or 0 (forward)
            x["duty"] = sign * (2 * g.integers(0, 250, B) + 1) / 1000 if k % 18 == 4 else np.zeros(B)
        return x

    def tick(self, k: int, lane_rig: Rig, twins: Sequence[Rig], x: dict[str, Any]) -> None:
        """One tick of both: the lane rig with every lane's inputs, each twin with its own."""
        self.watchdog = not self.watchdog
        self._tick(k, lane_rig, x, None)
        for b, t in enumerate(twins):
            self._tick(k, t, x, b)

    def _tick(self, k: int, rig: Rig, x: dict[str, Any], b: int | None) -> None:
        # b None: the lane rig (every lane's inputs, as lane values); else twin b (its own)
        def pick(values: np.ndarray) -> Any:
            return stack(values.tolist()) if b is None else values[..., b].tolist()

        rig.crate.advance_to(k * PERIOD_NS)
        for net, levels in x["nets"].items():  # the harness: the plant's fault and tactile lines
            rig.crate.signals.set_digital(net, pick(levels))
        rig.got = {"faults": rig.pio0.read_port("B"), "tactile": rig.pio1.read_port("B")}
        if k == 0:  # ServoLoop.start: clear faults, zero the outputs, enable
            for net in RESETS:
                rig.pio0.set_line(net, True)
                rig.pio0.set_line(net, False)
        # JointIO.write_torque: the hand's duty (H-bridge), the six commands with one strobe
        if "duty" in x:
            duty = pick(x["duty"])
        elif b is None:
            duty = duty_for_current_array(x["amps"], 2.0, 0.03, x["omega"] * 50.0, 24.0)
        else:
            duty = duty_for_current(pick(x["amps"]), 2.0, 0.03, pick(x["omega"]) * 50.0, 24.0)
        rig.pio0.set_pwm(duty, direction_line="hand.direction")
        volts = x["volts"] if k else np.zeros((6, B))
        cmds = {ch: (volts[ch] if b is None else pick(volts[ch])) for ch in range(6)}
        rig.got["codes"] = rig.dac.write_many(cmds, update=True).codes
        if k == 1:  # JointIO.release_brakes: after the first torque write's strobe
            for net in BRAKES:
                rig.pio1.set_line(net, True)
        if k > 0:  # JointIO._toggle_watchdog
            rig.pio0.set_line("rig.watchdog", self.watchdog, verify=False)
        rig.got["settling"] = rig.dac.settling
        if k == 0 or k % 20 == 10:  # JointIO.enable(on)
            on = k == 0 or k % 40 == 30
            for net in ENABLES:
                rig.pio0.set_line(net, on)
            rig.pio0.pwm_enable(on)
        rig.crate.advance_to(k * PERIOD_NS + DELAY_NS)


def _build() -> tuple[Rig, list[Rig], LaneSet]:
    """The lane rig (four rigs stacked) and the four scalar twins."""
    parts = [Rig(b) for b in range(B)]
    twins = [Rig(b) for b in range(B)]
    lanes = LaneSet(B)
    return Rig(-1, Crate.from_lanes([p.crate for p in parts], lanes), parts), twins, lanes


def _compare_got(lane_rig: Rig, twins: Sequence[Rig], lanes: LaneSet) -> None:
    for b, t in enumerate(twins):
        if not lanes.alive[b]:
            continue
        got, want = lane_rig.got, t.got
        assert lane(got["faults"], b) == want["faults"]
        assert lane(got["tactile"], b) == want["tactile"]
        assert {ch: lane(c, b) for ch, c in got["codes"].items()} == want["codes"]
        assert bool(lane(got["settling"], b)) is want["settling"]
        assert_lane_equals_twin(lane_rig, t, b)


def test_every_lane_of_the_dac_and_pio_tick_program_equals_its_scalar_twin() -> None:
    lane_rig, twins, lanes = _build()
    prog = Program(seed=7)
    seen_lane_words = False
    for k in range(60):
        x = prog.inputs(k, twins)
        prog.tick(k, lane_rig, twins, x)
        _compare_got(lane_rig, twins, lanes)
        seen_lane_words |= isinstance(lane_rig.got["faults"], np.ndarray)
    assert lanes.n_alive == B, lanes.reasons
    assert seen_lane_words  # the fault port read differed between lanes (a (B,) int64 word)
    assert isinstance(lane_rig.crate.signals.analog["j1.amp_command"], np.ndarray)
    assert isinstance(lane_rig.crate.signals.analog["hand.pwm"], np.ndarray)


def test_a_lane_whose_hand_reverses_alone_stays_and_every_lane_still_equals_its_twin() -> None:
    # set_pwm makes the same cycles whether the direction reverses or not (docs/boards/pio.md):
    # a reversal in one lane only is no divergence
    lane_rig, twins, lanes = _build()
    prog = Program(seed=11, flip_alone=(30, 2))  # from tick 30 lane 2's hand turns the other way
    differed = 0
    for k in range(50):
        prog.tick(k, lane_rig, twins, prog.inputs(k, twins))
        _compare_got(lane_rig, twins, lanes)
        directions = lane_rig.crate.signals.digital["hand.direction"]
        differed += isinstance(directions, np.ndarray) and len(set(directions.tolist())) == 2
    assert lanes.alive.tolist() == [True, True, True, True]
    assert differed  # the lanes' directions differed at some ticks


def test_a_lane_left_with_garbage_raises_and_warns_nothing_and_the_others_still_equal_their_twins() -> None:
    lane_rig, twins, lanes = _build()
    prog = Program(seed=5)
    junk = [np.nan, np.inf, -np.inf, 1e300, -1e300, 1e30]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a dead lane's values must not even warn
        for k in range(16):
            x = prog.inputs(k, twins)
            if k >= 4:  # lane 2: NaN at tick 4 (its twin's drivers raise: it is left), then any junk
                x["duty"] = duty_for_current_array(x["amps"], 2.0, 0.03, x["omega"] * 50.0, 24.0)
                x["duty"][2] = junk[k % len(junk)]
                x["volts"][:, 2] = np.roll(junk, k)
            prog.watchdog = not prog.watchdog
            prog._tick(k, lane_rig, x, None)
            for b, t in enumerate(twins):
                if b != 2 or k < 4:
                    prog._tick(k, t, x, b)
            assert lanes.alive.tolist() == [True, True, k < 4, True]
            _compare_got(lane_rig, twins, lanes)
    assert "PWM duty" in lanes.reasons[2]


def test_a_lane_whose_dac_command_is_nan_is_ejected_where_the_scalar_driver_raises() -> None:
    lane_rig, twins, lanes = _build()
    volts = np.array([1.0, -2.0, np.nan, 3.0])
    with pytest.raises(ValueError, match="NaN"):
        twins[2].dac.write_many({0: float(volts[2])})
    for b in (0, 1, 3):
        twins[b].dac.write_many({0: float(volts[b])})
    lane_rig.dac.write_many({0: volts})
    assert lanes.alive.tolist() == [True, True, False, True]
    assert "not a number" in lanes.reasons[2]
    for b in (0, 1, 3):
        assert_lane_equals_twin(lane_rig, twins[b], b)


def test_a_lane_whose_output_line_does_not_follow_its_latch_is_ejected_where_the_scalar_driver_raises() -> None:
    lane_rig, twins, lanes = _build()
    twins[1].crate.boards["pio1"].inject("line_stuck", line="PA1", level=False)
    with pytest.raises(LineStuckError):
        twins[1].pio1.set_line("j3.holding_brake", True)
    board = lane_rig.crate.boards["pio1"]
    pins = board.pins  # the same stuck line in lane 1: PIN_A's bit 1 reads low there

    def stuck_pins(port: int) -> Any:
        v = pins(port)
        return np.where(np.arange(B) == 1, v & ~2, v) if port == 0 else v

    board.pins = stuck_pins
    board._bind_ports()
    lane_rig.crate.invalidate()
    for b in (0, 2, 3):
        twins[b].pio1.set_line("j3.holding_brake", True)
    lane_rig.pio1.set_line("j3.holding_brake", True)
    assert lanes.alive.tolist() == [True, False, True, True]
    assert "does not follow its latch" in lanes.reasons[1]
    for b in (0, 2, 3):
        assert_lane_equals_twin(lane_rig, twins[b], b)


def test_boards_with_an_injected_fault_do_not_stack() -> None:
    parts = [Rig(b) for b in range(2)]
    parts[1].crate.boards["dac0"].inject("dead_channel", channel=3)
    with pytest.raises(NotImplementedError, match="fault"):
        Crate.from_lanes([p.crate for p in parts], LaneSet(2))


def test_the_array_dac_conversion_gives_the_scalar_codes_bit_for_bit() -> None:
    g = np.random.default_rng(3)
    lsb = 20.0 / 4096
    edges = -10.0 + lsb * (np.arange(-3, 4100) - 0.5)  # every transition, and beyond the ends
    volts = np.concatenate([g.uniform(-10.5, 10.5, 5000), edges, np.nextafter(edges, 20), np.nextafter(edges, -20),
                            [np.nan, np.inf, -np.inf, 1e306, -1e306]])
    codes, clipped, invalid = dac_volts_to_codes(volts)
    for v, c, k, bad in zip(volts.tolist(), codes.tolist(), clipped.tolist(), invalid.tolist(), strict=True):
        try:
            want = dac_volts_to_code(v)
        except (ValueError, OverflowError):
            assert bad and (c, k) == (0x800, False), v
            continue
        assert not bad and (c, k) == want, v


def test_the_array_duty_for_current_gives_the_scalar_duties_bit_for_bit() -> None:
    g = np.random.default_rng(5)
    amps = np.concatenate([g.uniform(-20, 20, 2000), [np.nan, np.inf, -np.inf, 0.0, -0.0]])
    omega = np.concatenate([g.uniform(-400, 400, 2000), [0.0, 1.0, 2.0, np.nan, 3.0]])
    got = duty_for_current_array(amps, 0.8, 0.028, omega, 24.0)
    want = [duty_for_current(a, 0.8, 0.028, w, 24.0) for a, w in zip(amps.tolist(), omega.tolist(), strict=True)]
    assert [_bits(d) for d in got.tolist()] == [_bits(d) for d in want]


def test_a_net_holding_lanes_set_to_one_level_tells_its_listeners_only_when_some_lane_changes() -> None:
    from emulators.signals import Signals

    s = Signals.from_lanes([Signals(), Signals(), Signals()])
    heard: list[Any] = []
    s.subscribe("fault", lambda net, v: heard.append(v))
    s.set_digital("fault", np.array([True, False, True]))
    s.set_digital("fault", False)  # lanes 0 and 2 change
    s.set_digital("fault", np.array([False, False, False]))  # no lane changes
    s.set_digital("fault", False)  # no lane changes
    assert [np.asarray(v).tolist() for v in heard] == [[True, False, True], False]
    assert s.digital["fault"] is False
