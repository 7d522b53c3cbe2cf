"""jpl-arm rig files with extra tables for one joint (named controllers, a velocity filter)."""

from __future__ import annotations

from pathlib import Path

PRESET = Path(__file__).resolve().parents[2] / "emulators" / "presets" / "jpl-arm.toml"

#: joint j2's named controllers in the tests: a stiffer gain set, the velocity filter, and a
#: high-Kp set the guard accepts with the auto switch-off boost (Kp_eff = Kp + KvI = 1500) but
#: not with a boost of 10 (Kp_eff = 15 000)
STIFF = """
[[joint.controller]]
name = "stiff"
[joint.controller.pid]
kp = 200.0
kpi = 10000.0
kv = 60.0
kvi = 2000.0
[[joint.controller]]
name = "filtered"
[joint.controller.pid]
velocity_filter = { cutoff_hz = 5.0 }
[[joint.controller]]
name = "tight"
[joint.controller.pid]
kp = 1500.0
kpi = 20000.0
kv = 60.0
kvi = 0.0
"""


def rig_with(tmp_path: Path, extra: str, joint: int = 2, servo_extra: str = "") -> Path:
    """jpl-arm with ``extra`` appended to joint ``joint``'s tables (1-based) and ``servo_extra``
    added to its [joint.servo] table; written to ``tmp_path/rig.toml``."""
    parts = PRESET.read_text().split("\n[[joint]]\n")
    body = parts[joint]
    if servo_extra:
        body = body.replace("[joint.servo]\n", "[joint.servo]\n" + servo_extra + "\n", 1)
    parts[joint] = body.rstrip("\n") + "\n" + extra + "\n"
    path = tmp_path / "rig.toml"
    path.write_text("\n[[joint]]\n".join(parts))
    return path
