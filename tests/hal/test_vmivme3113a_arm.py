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

#: the preset's entry, as the report hands it to the lead (the rig adds the wiring table from
#: [joint.wiring], [rig.references] and [rig.loopback])
_OFFSETS = ", ".join(["0.006"] * 64)
_GAINS = ", ".join(["0.002"] * 64)
PRESET_BOARD = f"""
[[crate.board]]
type = "vmivme-3113a"
name = "adc0"                    # pots 0..6, tachs 8..13, current monitors 16..22, refs 28/29, loopback 30/31
slot = 2
space = "A16"
base = 0x8500                    # DFELL_EPICS card 0 jumpers (J9 A08-A15), supervisory short I/O
input_range = "bipolar_10v"      # the range jumpers
conversion_time_us = 10          # [assumed] not in the public sources
noise_rms_v = 0.001
offset_v = [{_OFFSETS}]          # [assumed] one converter: the board's offset error on every channel
gain_error = [{_GAINS}]
"""

#: channel → net, as vmehil.rig_setup.system.wired_crate_table adds it from the rig's pins
ARM_WIRING = {
    **{str(i): f"j{i + 1}.pot" for i in range(6)}, "6": "hand.pot",
    **{str(8 + i): f"j{i + 1}.tach" for i in range(6)},
    **{str(16 + i): f"j{i + 1}.imon" for i in range(6)}, "22": "hand.imon",
    "28": "ref.adc0.28", "29": "ref.adc0.29", "30": "loop.dac0.6", "31": "loop.dac0.7",
}


def arm_crate() -> tuple[Crate, dict]:
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
