"""The VMIVME-2536 board and driver in lanes (batched lockstep, issue #34): every lane equals its
scalar twin, bit for bit; and the SBS 617 card of the same crate, idle, taken over as it is.

Four rigs with jpl-arm-vmic's dio0 and vision-link (emulators/presets/jpl-arm-vmic.toml: the
joints' enables, fault resets, holding brakes and fault inputs, the watchdog line, [rig.readback]'s
loopbacks) are stacked with ``from_lanes``; four more, built the same way, run scalar as the twins.
Both go through the servo tick's program on this board (servo.io.JointIO: the fault port read, the
resets at start, enables with their read-back through the looped-back inputs, brakes released with
the first torque write and dropped before a disable, the watchdog line toggled without read-back,
the stop's read-back), with inputs differing per lane (fault lines, a spare looped-back output
driven per lane, a CSR and a whole-port write per lane), and every live lane's registers, nets,
returned values, driver latch, counters and time are compared with its twin's after every step.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pytest

from emulators.crate import Crate
from emulators.sbs617 import Sbs617Card
from emulators.vmivme2536 import Vmi2536Board
from hal.lanes import LaneSet, lane, stack
from hal.pio.pio import LineStuckError
from hal.pio.vmivme2536 import Vmi2536Driver
from hal.vme.types import Width

B = 4
PERIOD_NS = 8_000_000  # 125 Hz
BASE = 0xFF00
J = range(1, 7)
ENABLES = [f"j{j}.amp_enable" for j in J]
RESETS = [f"j{j}.amp_reset" for j in J]
FAULTS = [f"j{j}.amp_fault" for j in J]
BRAKES = ["j2.holding_brake", "j3.holding_brake", "j4.holding_brake", "j6.holding_brake"]
WATCHDOG = "rig.watchdog"  # servo.rig.WATCHDOG_NET
SPARE = "spare.out"  # not in the preset: a spare output looped back, driven with a level per lane
# jpl-arm-vmic's [joint.wiring] on dio0, its [rig.watchdog] line and [rig.readback]
LINES = ({n: f"OUT{k}" for k, n in enumerate(ENABLES)} | {n: f"OUT{6 + k}" for k, n in enumerate(RESETS)}
         | {n: f"OUT{12 + k}" for k, n in enumerate(BRAKES)} | {WATCHDOG: "OUT16", SPARE: "OUT20"}
         | {n: f"IN{k}" for k, n in enumerate(FAULTS)})
READBACK = {f"OUT{k}": f"IN{16 + k}" for k in range(6)} | {"OUT16": "IN22", "OUT20": "IN30"}
OUTS = [*ENABLES, *RESETS, *BRAKES, WATCHDOG, SPARE]
# the board's wiring as vmehil.rig_setup.system.wired_crate_table makes it: a looped-back input
# sits on its output's net
BOARD_LINES = {pin: net for net, pin in LINES.items()}
BOARD_LINES |= {inp: BOARD_LINES[out] for out, inp in READBACK.items()}


# --- the rigs -----------------------------------------------------------------------------------
class Rig:
    """One instance's crate (dio0 and the idle vision-link card) and its 2536 driver, set up as
    servo.io.JointIO sets up jpl-arm-vmic's."""

    def __init__(self, b: int = 0, crate: Crate | None = None, parts: Sequence[Rig] = ()) -> None:
        self.got: dict[str, Any] = {}
        if crate is not None:  # the lane rig: the driver stacked on the lane crate
            self.crate = crate
            self.dio = Vmi2536Driver.from_lanes([p.dio for p in parts], crate)
            return
        self.crate = c = Crate("jpl-rack-vmic")
        c.install(Sbs617Card("vision-link", map_base=0x80010000, window_base=0x82000000),
                  base=0x80000000, space="A32", slot=1)
        c.install(Vmi2536Board("dio0", lines=BOARD_LINES), base=BASE, space="A16", slot=10)
        for net in FAULTS:
            c.signals.set_digital(net, False)
        self.dio = Vmi2536Driver(c, BASE, lines=LINES, loopback=READBACK)
        self.dio.configure(outputs=OUTS, initial={o: False for o in OUTS})
        self.dio.set_line(SPARE, b % 2 == 1)  # the instances differ from their set-up on: the latch


def assert_lane_equals_twin(lanes: Rig, twin: Rig, b: int) -> None:
    """Lane ``b`` of the lane rig holds exactly what the scalar twin holds."""
    lc, tc = lanes.crate, twin.crate
    assert lc.clock.now_ns == tc.clock.now_ns
    assert lc.counters == tc.counters
    for name, board in tc.boards.items():
        for reg, value in getattr(board, "regs", {}).items():
            got = lc.boards[name].regs[reg]
            assert isinstance(got, int) or got.dtype == np.int64, (name, reg)
            assert int(lane(got, b)) == value, (name, reg)
    assert lc.signals.digital.keys() == tc.signals.digital.keys()
    for net, v in tc.signals.digital.items():
        assert bool(lane(lc.signals.digital[net], b)) is v, net
    assert int(lane(lanes.dio._latch, b)) == twin.dio._latch
    assert lanes.got.keys() == twin.got.keys()
    for key, v in twin.got.items():
        assert type(v) in (int, bool), key
        assert lane(lanes.got[key], b) == v, key


class Program:
    """servo.io's calls on this board tick by tick, with inputs drawn per lane (seeded)."""

    def __init__(self, seed: int) -> None:
        self.g = np.random.default_rng(seed)
        self.watchdog = False
        self.watchdog_running = False
        self.release_pending = False

    def inputs(self, k: int) -> dict[str, Any]:
        g = self.g
        return {"nets": {n: g.random(B) < 0.2 for n in FAULTS} if k % 5 == 2 else {},
                "spare": g.random(B) < 0.5, "csr": g.permutation([0xE000, 0xA000, 0xC000, 0x0000]),
                "flip": g.integers(0, 2, B)}

    def tick(self, k: int, lane_rig: Rig, twins: Sequence[Rig], x: dict[str, Any],
             skip: Callable[[int], bool] = lambda b: False) -> None:
        """One tick of both: the lane rig with every lane's inputs, each twin with its own."""
        state = (self.watchdog, self.watchdog_running, self.release_pending)
        self._tick(k, lane_rig, x, None)
        end = (self.watchdog, self.watchdog_running, self.release_pending)
        for b, t in enumerate(twins):
            if not skip(b):
                self.watchdog, self.watchdog_running, self.release_pending = state
                self._tick(k, t, x, b)
        self.watchdog, self.watchdog_running, self.release_pending = end

    def _tick(self, k: int, rig: Rig, x: dict[str, Any], b: int | None) -> None:
        # b None: the lane rig (every lane's inputs as lane values); else twin b (its own)
        def pick(values: np.ndarray) -> Any:
            return stack(values.tolist()) if b is None else values[b].item()

        dio, got = rig.dio, rig.got
        got.clear()
        rig.crate.advance_to(k * PERIOD_NS)
        for net, levels in x["nets"].items():  # the harness: the amplifiers' fault lines
            rig.crate.signals.set_digital(net, pick(levels))
        got["faults"] = dio.read_port(0)  # JointIO.read: the fault port (INPUT), once a tick
        if k == 0:  # JointIO.clear_faults
            for net in RESETS:
                dio.set_line(net, True)
                dio.set_line(net, False)
        if k == 0 or k % 20 == 10:  # JointIO.enable(on)
            on = k == 0 or k % 40 == 30
            if on:
                self.watchdog_running = self.release_pending = True
            else:
                self.release_pending = False
                for net in BRAKES:  # engage_brakes
                    dio.set_line(net, False)
                self.watchdog_running, self.watchdog = False, False  # _stop_watchdog
                dio.set_line(WATCHDOG, False, verify=False)
            for net in ENABLES:
                dio.set_line(net, on)
        # the end of JointIO.write_torque: brakes released with the first write, the watchdog toggled
        if self.release_pending:
            self.release_pending = False
            for net in BRAKES:
                dio.set_line(net, True)
        if self.watchdog_running:
            self.watchdog = not self.watchdog
            dio.set_line(WATCHDOG, self.watchdog, verify=False)
        dio.set_line(SPARE, pick(x["spare"]))  # a level per lane, read back through its input
        if k % 7 == 3:  # the stop's read-back (verify_stopped): latches and wires
            got["enable"] = dio.get_line(ENABLES[k % 6])
            got["brake"] = dio.get_line(BRAKES[k % 4])
            got["fault"] = dio.get_line(FAULTS[k % 6])
            got["pins_out"] = dio.read_pins("OUT")
            got["pins_in"] = dio.read_pins("IN")
            got["port_out"] = dio.read_port("OUT")
        if k % 11 == 5:
            dio.verify_outputs()
        if k == 24:  # CSR per lane: outputs and inputs switched off in some lanes, then on again
            dio.win.write("CSR", pick(x["csr"]))
            got["csr_in"] = dio.read_port("IN")
            got["csr_pins"] = dio.read_pins("OUT")
            dio.win.write("CSR", 0xE000)
        if k == 44:  # a whole latch per lane: the spare output flipped in some lanes
            dio.write_port("OUT", dio._latch ^ (pick(x["flip"]) << 20))
            dio.verify_outputs()


def _build(n: int = B) -> tuple[Rig, list[Rig], list[Rig], LaneSet]:
    """The lane rig (``n`` rigs stacked), the ``n`` rigs it was stacked from and ``n`` scalar twins."""
    parts = [Rig(b) for b in range(n)]
    twins = [Rig(b) for b in range(n)]
    lanes = LaneSet(n)
    return Rig(-1, Crate.from_lanes([p.crate for p in parts], lanes), parts), parts, twins, lanes


def _alike() -> tuple[Rig, LaneSet]:
    """B instances alike stacked: every register and net one value for every lane."""
    parts = [Rig() for _ in range(B)]
    lanes = LaneSet(B)
    return Rig(-1, Crate.from_lanes([p.crate for p in parts], lanes), parts), lanes


def _compare(lane_rig: Rig, twins: Sequence[Rig], lanes: LaneSet) -> None:
    for b, t in enumerate(twins):
        if lanes.alive[b]:
            assert_lane_equals_twin(lane_rig, t, b)


# --- the 2536 -----------------------------------------------------------------------------------
def test_every_lane_of_the_2536_tick_program_equals_its_scalar_twin() -> None:
    lane_rig, _, twins, lanes = _build()
    prog = Program(seed=7)
    lane_words = set()
    for k in range(60):
        prog.tick(k, lane_rig, twins, prog.inputs(k))
        _compare(lane_rig, twins, lanes)
        lane_words |= {key for key, v in lane_rig.got.items() if isinstance(v, np.ndarray)}
    assert lanes.n_alive == B, lanes.reasons
    # the inputs did differ between lanes: words and nets per lane, not one value for all
    assert {"faults", "pins_out", "csr_in", "csr_pins"} <= lane_words
    assert isinstance(lane_rig.crate.signals.digital[SPARE], np.ndarray)
    assert isinstance(lane_rig.crate.boards["dio0"].regs["OUTPUT"], np.ndarray)


def _hold_low(lane_rig: Rig, net: str, where: np.ndarray) -> None:
    """The lane board's wire of ``net`` held low in the lanes ``where`` (lane boards take no
    injected fault: this is what a twin's ``line_stuck(level=False)`` does to its net)."""
    board = lane_rig.crate.boards["dio0"]
    drive = board._drive_outputs
    signals = lane_rig.crate.signals

    def drive_stuck() -> None:
        drive()
        signals.set_digital(net, False if where.all() else np.where(where, False, signals.get_digital(net)))

    board._drive_outputs = drive_stuck
    drive_stuck()


def test_a_lane_whose_enable_does_not_follow_its_latch_is_ejected_and_the_others_still_equal_their_twins() -> None:
    lane_rig, _, twins, lanes = _build()
    prog = Program(seed=11)
    for k in range(60):
        if k == 20:  # the enables are off (ticks 10..29): the stuck wire changes nothing until tick 30
            twins[1].crate.boards["dio0"].inject("line_stuck", line="OUT0", level=False)
            _hold_low(lane_rig, "j1.amp_enable", np.arange(B) == 1)
        x = prog.inputs(k)
        if k == 30:  # the enables go high: twin 1's driver reads IN16 low and raises
            state = (prog.watchdog, prog.watchdog_running, prog.release_pending)
            with pytest.raises(LineStuckError, match="j1.amp_enable"):
                prog._tick(k, twins[1], x, 1)
            prog.watchdog, prog.watchdog_running, prog.release_pending = state
        prog.tick(k, lane_rig, twins, x, skip=({1} if k >= 30 else set()).__contains__)
        assert lanes.alive.tolist() == [True, k < 30, True, True]
        _compare(lane_rig, twins, lanes)
    assert "j1.amp_enable" in lanes.reasons[1] and "LineStuckError" in lanes.reasons[1]


def test_verify_outputs_ejects_a_lane_whose_looped_back_wire_differs_and_raises_where_every_lane_does() -> None:
    lane_rig, _, twins, lanes = _build()
    twins[3].crate.boards["dio0"].inject("line_stuck", line="OUT16", level=False)
    _hold_low(lane_rig, WATCHDOG, np.arange(B) == 3)
    for rig in (lane_rig, *twins):
        rig.dio.set_line(WATCHDOG, True, verify=False)
    with pytest.raises(LineStuckError, match="rig.watchdog"):
        twins[3].dio.verify_outputs()
    for t in twins[:3]:
        t.dio.verify_outputs()
    lane_rig.dio.verify_outputs()
    assert lanes.alive.tolist() == [True, True, True, False]
    assert "do not follow" in lanes.reasons[3]
    for b in range(3):
        assert_lane_equals_twin(lane_rig, twins[b], b)

    # instances alike (one latch for every lane) with the same wire stuck: one driver's error
    alike, _ = _alike()
    twin = Rig()
    twin.crate.boards["dio0"].inject("line_stuck", line="OUT16", level=False)
    _hold_low(alike, WATCHDOG, np.ones(B, bool))
    for rig in (alike, twin):
        rig.dio.set_line(WATCHDOG, True, verify=False)
    with pytest.raises(LineStuckError) as want:
        twin.dio.verify_outputs()
    with pytest.raises(LineStuckError) as got:
        alike.dio.verify_outputs()
    assert str(got.value) == str(want.value) and got.value.lines == {WATCHDOG: False}


def test_a_lane_whose_port_value_is_not_32_bits_is_ejected_where_the_scalar_driver_raises() -> None:
    lane_rig, _, twins, lanes = _build()
    values = [0x1, 0x2, 1 << 32, 0x3]
    with pytest.raises(ValueError, match="32 bits"):
        twins[2].dio.write_port("OUT", values[2])
    for b in (0, 1, 3):
        twins[b].dio.write_port("OUT", values[b])
    lane_rig.dio.write_port("OUT", stack(values))
    assert lanes.alive.tolist() == [True, True, False, True]
    assert "not 32 bits" in lanes.reasons[2]
    for b in (0, 1, 3):
        assert_lane_equals_twin(lane_rig, twins[b], b)


def test_a_stuck_latch_alike_in_every_lane_raises_as_the_scalar_driver_does() -> None:
    lane_rig, lanes = _alike()
    board = lane_rig.crate.boards["dio0"]
    board.write_OUTPUT = lambda value: None  # the latch ignores writes in every lane (OUTPUT reads 0)
    lane_rig.crate.invalidate()
    with pytest.raises(LineStuckError, match="j3.amp_enable"):
        lane_rig.dio.set_line("j3.amp_enable", True)
    assert lanes.n_alive == B


def test_2536_boards_with_an_injected_fault_or_another_wiring_do_not_stack() -> None:
    parts = [Rig() for _ in range(2)]
    parts[1].crate.boards["dio0"].inject("line_stuck", line="IN3", level=True)
    with pytest.raises(NotImplementedError, match="fault"):
        Crate.from_lanes([p.crate for p in parts], LaneSet(2))
    a = Crate("a")
    a.install(Vmi2536Board("dio0", lines={"OUT0": "x"}), base=BASE, space="A16")
    c = Crate("a")
    c.install(Vmi2536Board("dio0", lines={"OUT1": "x"}), base=BASE, space="A16")
    with pytest.raises(NotImplementedError, match="wired differently"):
        Crate.from_lanes([a, c], LaneSet(2))


def test_a_lane_board_refuses_a_fault_and_the_scalar_boards_keep_their_own_methods() -> None:
    lane_rig, parts, _, _ = _build(2)
    board = lane_rig.crate.boards["dio0"]
    with pytest.raises(NotImplementedError, match="faults"):
        board.inject("line_stuck", line="OUT0", level=True)
    scalar = parts[0].crate.boards["dio0"]
    # the scalar board keeps its own methods: no lane method bound on it (the scalar path untouched)
    assert not {"read_INPUT", "output_level", "input_level", "_drive_outputs", "inject"} & scalar.__dict__.keys()


# --- the 617 ------------------------------------------------------------------------------------
def test_an_idle_617_is_lane_0s_card_with_its_bars_and_answers_as_a_scalar_card() -> None:
    lane_rig, parts, twins, _ = _build()
    card = lane_rig.crate.boards["vision-link"]
    assert card is parts[0].crate.boards["vision-link"]
    assert isinstance(card, Sbs617Card) and card.crate is lane_rig.crate
    assert lane_rig.crate.boards["vision-link.map"] is card.map_ram
    assert lane_rig.crate.boards["vision-link.window"] is card.window
    assert card.map_ram.crate is lane_rig.crate and card.window.crate is lane_rig.crate
    # the same cycles on the lane crate and on a scalar twin's give the same answers
    for c in (lane_rig.crate, twins[0].crate):
        c.boards["vision-link"].link.mem[0x10:0x14] = b"\x12\x34\x56\x78"  # the vision computer's data
        # PCI->VME entry 0: remote page 0x400 (remote_base 0x400000), AM 0x39 (A24), function 1
        c.write(0x80010000, 0x0040_0000 | 0x39 << 6 | 1 << 4, space="A32", width=Width.D32)
    want = [twins[0].crate.read(0x82000010, space="A32", width=Width.D32),
            twins[0].crate.read(0x80000002, space="A32", width=Width.D8)]
    got = [lane_rig.crate.read(0x82000010, space="A32", width=Width.D32),
           lane_rig.crate.read(0x80000002, space="A32", width=Width.D8)]
    assert got == want and want[0] == 0x12345678


def _write_loc_int_ctrl(crates: Sequence[Crate]) -> None:  # the same cycle everywhere; lane 2's value differs
    for b, c in enumerate(crates):
        c.write(0x80000001, 0x40 if b == 2 else 0x00, space="A32", width=Width.D8)


def _write_map_entry(crates: Sequence[Crate]) -> None:
    for b, c in enumerate(crates):
        c.write(0x80010004, 0x0040_0000 | 0x39 << 6 | 1 << 4 | (b == 2), space="A32", width=Width.D32)


def _vision_computer_writes(crates: Sequence[Crate]) -> None:  # no cycle on the robot's crate
    crates[2].boards["vision-link"].link.mem[0] = 0x55  # type: ignore[attr-defined]


@pytest.mark.parametrize("differ", [_write_loc_int_ctrl, _write_map_entry, _vision_computer_writes])
def test_a_617_whose_state_differs_between_lanes_has_no_lane_form(differ: Callable[[Sequence[Crate]], None]) -> None:
    crates = [Rig(1).crate for _ in range(B)]
    differ(crates)
    with pytest.raises(NotImplementedError, match="'vision-link'.*differs"):
        Crate.from_lanes(crates, LaneSet(B))


def test_a_617_with_a_fault_in_a_bar_or_polling_its_link_has_no_lane_form() -> None:
    crates = [Rig().crate for _ in range(2)]
    crates[1].boards["vision-link.window"].inject("removed")
    with pytest.raises(NotImplementedError, match="BARs"):
        Crate.from_lanes(crates, LaneSet(2))
    polling = [Sbs617Card("vision-link", poll_period_s=50e-6) for _ in range(2)]
    with pytest.raises(NotImplementedError, match="polls its link"):
        Sbs617Card.from_lanes(polling, None)
