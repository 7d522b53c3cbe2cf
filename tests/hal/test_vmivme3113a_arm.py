"""The VMIVME-3113A in the arm's ADC role: the [[crate.board]] entry the preset ``jpl-arm-vmic``
needs (docs/boards/vmivme-3113a.md, "The arm's wiring on this board") builds a crate whose
board the driver reads as the servo does — one ``scan(31)`` per tick."""

from __future__ import annotations

import tomllib

import pytest

from emulators.board_factory import BuildContext
from emulators.crate import Crate
from emulators.vmivme3113a import vmivme3113a_factory
from hal.adc_dac.vmivme3113a import Vmivme3113aDriver
from hal.config import ConfigTable
from tests.support.vmivme3113a_preset import ARM_WIRING, PRESET_BOARD


def arm_crate() -> tuple[Crate, dict]:
    """A crate holding the preset's entry, its wiring table as the rig adds it from [joint.wiring],
    [rig.references] and [rig.loopback]."""
    entry = tomllib.loads(PRESET_BOARD)["crate"]["board"][0]
    entry = {**entry, "wiring": ARM_WIRING}
    name, slot, space, base = entry.pop("name"), entry.pop("slot"), entry.pop("space"), entry.pop("base")
    assert entry.pop("type") == "vmivme-3113a"
    c = Crate("jpl-arm-vmic")
    board = vmivme3113a_factory(name, ConfigTable(entry, "preset", "crate.board"), BuildContext(c.signals, seed=0))
    c.install(board, base=base, space=space, slot=slot)
    return c, {"base": base, "space": space}


def test_the_preset_entry_builds_the_arms_adc_and_the_driver_reads_every_signal() -> None:
    c, loc = arm_crate()
    nets = {net: round(-9.0 + 0.5 * i, 3) for i, net in enumerate(sorted(set(ARM_WIRING.values())))}
    for net, v in nets.items():
        c.signals.set_analog(net, v)
    adc = Vmivme3113aDriver(c, loc["base"], space=loc["space"], input_range="bipolar_10v")
    volts = adc.scan(31)
    lsb = 20.0 / 4096
    for ch, net in ARM_WIRING.items():
        reading = nets[net] * 1.002 + 0.006  # the board's gain and offset error (uncalibrated driver)
        assert volts[int(ch)] == pytest.approx(reading, abs=lsb / 2 + 4 * 0.001), (ch, net)
    assert c.board("adc0").describe()["model"] == "VMIVME-3113A"
    assert c.slots()[0].board.slot == 2


def test_a_tick_of_the_arm_is_32_reads_and_no_wait() -> None:
    c, loc = arm_crate()
    adc = Vmivme3113aDriver(c, loc["base"])
    before_ns, before_cycles = c.clock.now_ns, sum(c.counter_snapshot().values())
    adc.scan(31)
    assert sum(c.counter_snapshot().values()) - before_cycles == 32
    assert c.clock.now_ns - before_ns == 32 * 300  # 300 ns a D16 cycle at this board: 9.6 µs


def test_both_board_tables_name_the_3113a_with_its_role_driver_probe_and_document() -> None:
    from emulators.board_types import BOARD_TYPES as EMULATOR_TYPES
    from hal.board_types import BOARD_TYPES, types_answering
    from hal.vme import Width

    bt = BOARD_TYPES["vmivme-3113a"]
    assert bt.role == "adc"
    assert bt.metadata() == {"vendor": "VMIC", "model": "VMIVME-3113A", "document": "docs/boards/vmivme-3113a.md"}
    assert bt.load_driver() is Vmivme3113aDriver and bt.channels() == 64
    reg = bt.id_register()
    assert reg is not None and (reg.offset, reg.width, reg.reset) == (0x00, Width.D16, 0x1100)  # the doc's ID
    assert types_answering(0x00, Width.D16, 0x1100) == ["vmivme-3113a"]
    assert EMULATOR_TYPES["vmivme-3113a"] is vmivme3113a_factory
