"""The calibration bench's rig file (no vmehil import: the servo's own tests read it too)."""

from __future__ import annotations

from pathlib import Path

from servo.rig import RigSpec, load_rig

RIG_TOML = """
[rig]
name = "bench"

[rig.references]
"adc1:12" = 5.0
"adc1:13" = 0.0

[rig.loopback]
"dac0:6" = "adc1:14"
"dac0:7" = "adc1:15"

[crate]
name = "bench-rack"

[[crate.board]]
type = "adc"
name = "adc0"
space = "A16"
base = 0x6000

[[crate.board]]
type = "adc"
name = "adc1"
space = "A16"
base = 0x6100

[[crate.board]]
type = "dac"
name = "dac0"
space = "A16"
base = 0x7000

[[crate.board]]
type = "quad"
name = "quad0"
space = "A16"
base = 0x5000

[[joint]]
name = "j1"
amplifier = "linear"
[joint.wiring]
amp_command = "dac0:0"
pot = "adc0:0"
imon = "adc1:0"
encoder = "quad0:0"
[joint.servo]
velocity = "encoder"
[joint.link]
lower_stop_rad = -2.88
upper_stop_rad = 2.88
[joint.encoder]
lines_per_rev = 500
[joint.gear]
ratio = 100.0
[joint.linear_amp]
gain_a_per_v = 3.0
monitor_v_per_a = 0.3333333333
current_limit_a = 30.0

[[joint]]
name = "j2"
amplifier = "linear"
[joint.wiring]
amp_command = "dac0:1"
pot = "adc0:1"
imon = "adc1:1"
encoder = "quad0:1"
[joint.servo]
velocity = "encoder"
[joint.link]
lower_stop_rad = -0.35
upper_stop_rad = 1.9
[joint.encoder]
lines_per_rev = 500
[joint.gear]
ratio = 100.0
[joint.linear_amp]
gain_a_per_v = 2.0
monitor_v_per_a = 0.5
current_limit_a = 20.0
"""

POT_SPAN = 5.934  # rad, ~340° element across ±10 V


def write_rig(folder: Path, text: str = RIG_TOML, name: str = "bench.toml") -> RigSpec:
    p = folder / name
    p.write_text(text)
    return load_rig(p)
