"""The emulated VMIVME-2536 against its spec, docs/boards/vmivme2536.md: reset state, activation by
CSR, the worked values, bad accesses, faults, and the board in the arm's role (the crate-file
snippet the preset jpl-arm-vmic takes), driven by its driver."""

from __future__ import annotations

import tomllib

import pytest

from emulators.board_factory import BuildContext
from emulators.crate import Crate
from emulators.pio import pio_from_config
from emulators.vmivme2536 import Vmi2536Board, vmivme2536_from_config
from hal.config import ConfigTable
from hal.pio import LineStuckError, PioDriver, Vmi2536BoardIdError, Vmi2536Driver
from hal.vme import BusError, BusErrorCause, Width

BASE = 0xFF00
CSR, INPUT, OUTPUT = BASE + 0x02, BASE + 0x04, BASE + 0x08


def _board(lines: dict[str, str] | None = None, **kw) -> tuple[Crate, Vmi2536Board]:
    c = Crate("vmi2536")
    b = Vmi2536Board("dio0", lines=lines, **kw)
    c.install(b, base=BASE, space="A16", slot=5)
    return c, b


def _r(c: Crate, addr: int, width: Width) -> int:
    return c.read(addr, space="A16", width=width)


def _w(c: Crate, addr: int, value: int, width: Width) -> None:
    c.write(addr, value, space="A16", width=width)


OUT_NETS = {f"OUT{n}": f"o{n}" for n in range(32)}


def test_after_power_up_every_output_is_off_and_the_registers_hold_the_docs_reset_values() -> None:
    c, _ = _board({**OUT_NETS, "IN0": "in0"})
    c.signals.set_digital("in0", True)
    assert [_r(c, CSR, Width.D16), _r(c, INPUT, Width.D32), _r(c, OUTPUT, Width.D32)] == [0x0000, 0, 0]
    assert not any(c.signals.get_digital(f"o{n}") for n in range(32))
    assert _r(c, BASE, Width.D16) == 0x2536  # the stand-in BID (doc: "Identification")


def test_a_sysreset_turns_every_output_off_whatever_the_latch_held() -> None:
    c, b = _board(OUT_NETS)
    _w(c, CSR, 0xE000, Width.D16)
    _w(c, OUTPUT, 0xFFFF_FFFF, Width.D32)
    assert all(c.signals.get_digital(f"o{n}") for n in range(32))
    b.reset()
    assert not any(c.signals.get_digital(f"o{n}") for n in range(32))
    assert (_r(c, CSR, Width.D16), _r(c, OUTPUT, Width.D32)) == (0x0000, 0)


def test_worked_values_outputs_follow_the_latch_only_while_activated() -> None:
    c, _ = _board(OUT_NETS)
    _w(c, CSR, 0xE000, Width.D16)
    _w(c, OUTPUT, 0x0000_0005, Width.D32)
    assert [n for n in range(32) if c.signals.get_digital(f"o{n}")] == [0, 2]
    assert _r(c, OUTPUT, Width.D32) == 0x0000_0005
    _w(c, CSR, 0x0000, Width.D16)  # deactivated: nothing driven, the latch kept
    assert not any(c.signals.get_digital(f"o{n}") for n in range(32))
    assert _r(c, OUTPUT, Width.D32) == 0x0000_0005
    _w(c, CSR, 0x4000, Width.D16)  # outputs on: OUT0 and OUT2 at once
    assert [n for n in range(32) if c.signals.get_digital(f"o{n}")] == [0, 2]


def test_worked_values_inputs_read_only_while_activated() -> None:
    c, _ = _board({"IN3": "a", "IN31": "b", "IN7": "c"})
    c.signals.set_digital("a", True)
    c.signals.set_digital("b", True)
    _w(c, CSR, 0xE000, Width.D16)
    assert _r(c, INPUT, Width.D32) == 0x8000_0008
    _w(c, CSR, 0x8000, Width.D16)
    assert _r(c, INPUT, Width.D32) == 0x0000_0000


def test_csr_bits_12_to_0_are_ignored_and_read_0() -> None:
    c, _ = _board()
    _w(c, CSR, 0xFFFF, Width.D16)
    assert _r(c, CSR, Width.D16) == 0xE000
    _w(c, CSR, 0x1FFF, Width.D16)
    assert _r(c, CSR, Width.D16) == 0x0000


@pytest.mark.parametrize(("offset", "width"), [(0x0C, Width.D32), (0x0C, Width.D16), (0x0E, Width.D16),
                                               (0x0F, Width.D8)])
def test_the_reserved_word_is_no_register(offset: int, width: Width) -> None:
    c, _ = _board()
    with pytest.raises(BusError) as ei:
        _r(c, BASE + offset, width)
    assert ei.value.cause is BusErrorCause.NO_RESPONDER


@pytest.mark.parametrize(("offset", "width"), [(0x02, Width.D8), (0x03, Width.D8), (0x04, Width.D16),
                                               (0x06, Width.D16), (0x00, Width.D32), (0x08, Width.D16),
                                               (0x0A, Width.D16), (0x00, Width.D8)])
def test_widths_the_sources_never_use_end_in_berr(offset: int, width: Width) -> None:
    c, _ = _board()
    with pytest.raises(BusError) as ei:
        _r(c, BASE + offset, width)
    assert ei.value.cause is BusErrorCause.UNSUPPORTED_WIDTH


def test_a_d16_write_to_output_ends_in_berr_and_changes_nothing() -> None:
    c, _ = _board(OUT_NETS)
    _w(c, CSR, 0xE000, Width.D16)
    with pytest.raises(BusError) as ei:
        _w(c, BASE + 0x0A, 0xFFFF, Width.D16)
    assert ei.value.cause is BusErrorCause.UNSUPPORTED_WIDTH
    assert _r(c, OUTPUT, Width.D32) == 0 and not c.signals.get_digital("o0")


@pytest.mark.parametrize(("offset", "width"), [(0x00, Width.D16), (0x04, Width.D32)])
def test_writes_to_bid_and_input_end_in_berr(offset: int, width: Width) -> None:
    c, _ = _board()
    with pytest.raises(BusError) as ei:
        _w(c, BASE + offset, 0x1234, width)
    assert ei.value.cause is BusErrorCause.ACCESS


def test_a_stuck_output_drives_its_net_while_output_reads_the_latch() -> None:
    c, b = _board({"OUT5": "en"})
    _w(c, CSR, 0xE000, Width.D16)
    b.inject("line_stuck", line="OUT5", level=True)
    assert c.signals.get_digital("en") is True
    assert _r(c, OUTPUT, Width.D32) == 0  # the latch: the board cannot see its wire
    b.clear_fault("line_stuck")
    assert c.signals.get_digital("en") is False


def test_a_stuck_input_reads_its_stuck_level() -> None:
    c, b = _board({"IN9": "f"})
    _w(c, CSR, 0xE000, Width.D16)
    b.inject("line_stuck", line="IN9", level=True)
    assert _r(c, INPUT, Width.D32) == 1 << 9


def test_line_stuck_refuses_a_line_the_board_does_not_have() -> None:
    _, b = _board()
    with pytest.raises(ValueError, match="IN32"):
        b.inject("line_stuck", line="IN32", level=True)
    assert not b.active_faults


def test_a_removed_board_ends_every_cycle_in_berr() -> None:
    c, b = _board()
    b.inject("removed")
    with pytest.raises(BusError):
        _r(c, BASE, Width.D16)


def test_the_driver_sees_a_stuck_enable_through_its_loopback_input() -> None:
    c, b = _board({"OUT0": "j1.en", "IN16": "j1.en"})
    d = Vmi2536Driver(c, BASE, lines={"j1.en": "OUT0"}, loopback={"OUT0": "IN16"})
    d.configure(outputs=["j1.en"])
    d.set_line("j1.en", True)
    b.inject("line_stuck", line="OUT0", level=True)
    d.set_line("j1.en", False, verify=False)
    assert d.read_pins("OUT") & 1 == 1  # what servo.io's stop verification reads
    with pytest.raises(LineStuckError, match="j1.en"):
        d.verify_outputs()


# --- the board in the arm's role: the preset's crate-file snippet --------------------------
ARM_SNIPPET = """
[[crate.board]]
type = "vmivme-2536"
name = "dio0"                    # OUT0-5 enables j1-j6, OUT6-11 fault resets, OUT12-15 holding brakes,
slot = 10                        # OUT16 watchdog; IN0-5 amplifier faults; IN16-21 enables looped back
space = "A16"
base = 0xFF00

[[crate.board]]
type = "pio"
name = "pio0"                    # reference PIO, kept for the hand's H-bridge (PWM timer)
slot = 5
space = "A16"
base = 0x4000
"""
ARM_LINES = {
    **{f"OUT{i}": f"j{i + 1}.amp_enable" for i in range(6)},
    **{f"OUT{6 + i}": f"j{i + 1}.amp_reset" for i in range(6)},
    **{f"OUT{12 + k}": f"j{j}.holding_brake" for k, j in enumerate((2, 3, 4, 6))},
    "OUT16": "watchdog",
    **{f"IN{i}": f"j{i + 1}.amp_fault" for i in range(6)},
    **{f"IN{16 + i}": f"j{i + 1}.amp_enable" for i in range(6)},
}


def _arm_crate() -> Crate:
    data = tomllib.loads(ARM_SNIPPET)
    c = Crate("jpl-rack")
    ctx = BuildContext(c.signals)
    for i, bdata in enumerate(data["crate"]["board"]):
        if bdata["type"] == "vmivme-2536":
            bdata = {**bdata, "lines": ARM_LINES}
        cfg = ConfigTable(bdata, "jpl-arm-vmic snippet", f"crate.board[{i}]")
        factory = vmivme2536_from_config if bdata["type"] == "vmivme-2536" else pio_from_config
        c.install(factory(bdata["name"], cfg, ctx), base=bdata["base"], space=bdata["space"], slot=bdata["slot"])
    return c


def test_the_arm_snippet_builds_a_crate_whose_outputs_are_low_until_a_driver_enables_them() -> None:
    c = _arm_crate()
    assert c.boards["dio0"].describe()["model"] == "VMIVME-2536"
    enables = [f"j{i}.amp_enable" for i in range(1, 7)]
    assert not any(c.signals.get_digital(n) for n in (*enables, "watchdog"))
    wiring = {v: k for k, v in ARM_LINES.items() if k.startswith("OUT") or v.endswith("fault")}
    d = Vmi2536Driver(c, BASE, lines=wiring, loopback={f"OUT{i}": f"IN{16 + i}" for i in range(6)})
    assert d.probe() == 0x2536
    outs = [n for n in wiring if not n.endswith("fault")]
    d.configure(outputs=outs, initial=dict.fromkeys(outs, False))
    for n in enables:
        d.set_line(n, True)  # verified through the loopback inputs
    assert all(c.signals.get_digital(n) for n in enables)
    c.signals.set_digital("j3.amp_fault", True)  # the amplifier raises its fault line
    # INPUT: the six looped-back enables (IN16..IN21) and j3's fault (IN2)
    assert d.read_port(d.resolve("j3.amp_fault")[0]) == 0x003F_0004
    d.reset()
    assert not any(c.signals.get_digital(n) for n in (*enables, "watchdog"))
    hand = PioDriver(c, 0x4000)  # the hand's board answers beside it
    assert hand.probe() == 0x5001


def test_a_stated_board_id_refuses_another_value_naming_both() -> None:
    c, _ = _board(board_id=0x1234)
    with pytest.raises(Vmi2536BoardIdError, match=r"BID 0x2536 at 0xFF00: BID reads 0x1234"):
        Vmi2536Driver(c, BASE, board_id=0x2536).probe()
    assert Vmi2536Driver(c, BASE, board_id=0x1234).probe() == 0x1234


def test_the_crate_file_factory_refuses_a_line_the_board_does_not_have() -> None:
    cfg = ConfigTable({"lines": {"OUT32": "x"}}, "t.toml", "crate.board[0]")
    with pytest.raises(Exception, match="OUT32"):
        vmivme2536_from_config("dio0", cfg, BuildContext(Crate("t").signals))
