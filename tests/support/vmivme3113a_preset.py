"""The VMIVME-3113A's entry for the preset ``jpl-arm-vmic`` (docs/boards/vmivme-3113a.md, "The
arm's wiring on this board"), and how the arm's pins move onto it from ``jpl-arm``'s two reference
ADCs. Shared by the crate-level test (tests/hal/test_vmivme3113a_arm.py) and the whole-rig test
(tests/vmehil/test_vmivme3113a_rig.py). No tests here."""

from __future__ import annotations

import re

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


def jpl_arm_on_the_3113a(jpl_arm_text: str) -> str:
    """``jpl-arm``'s rig file with its two reference ADCs replaced by the one VMIVME-3113A:
    current monitors adc1:N → adc0:16+N, references adc1:12/13 → adc0:28/29, DAC loopback
    adc1:14/15 → adc0:30/31 (pots adc0:0..6 and tachs adc0:8..13 keep their channels)."""
    head, sep, rest = jpl_arm_text.partition('[[crate.board]]\ntype = "adc"\nname = "adc0"')
    _, sep2, tail = rest.partition('[[crate.board]]\ntype = "dac"')
    if not (sep and sep2):
        raise ValueError("jpl-arm.toml's ADC entries moved")
    text = head + PRESET_BOARD.lstrip() + "\n" + sep2 + tail
    text = re.sub(r'imon = "adc1:(\d+)"', lambda m: f'imon = "adc0:{16 + int(m[1])}"', text)
    moves = {"adc1:12": "adc0:28", "adc1:13": "adc0:29", "adc1:14": "adc0:30", "adc1:15": "adc0:31"}
    for old, new in moves.items():
        text = text.replace(f'"{old}"', f'"{new}"')
    if '"adc1:' in text:
        raise ValueError("a pin on adc1 is left")
    return text
