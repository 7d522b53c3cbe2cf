"""Rig files (servo.rig.load_rig, hal.config, then the emulated rig's build): the jpl-arm preset
with one value replaced by garbage, a key or table deleted, an unknown key added, or its text
corrupted. Property: the file loads, builds and makes a servo loop, or is refused with hal.config.ConfigError
naming the file and the key — nothing else escapes."""

from __future__ import annotations

import tomllib

from hypothesis import given

from emulators.presets import resolve_rig
from hal.config import ConfigError
from servo.rig import load_rig
from tests.fuzz.harness import refused
from tests.fuzz.mutate import mutated
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

PRESET = resolve_rig("jpl-arm").read_text()
DOC = tomllib.loads(PRESET)


@given(data=mutated(PRESET, DOC))
def test_a_mangled_rig_file_builds_or_is_refused_naming_file_and_key(tmp_path_factory, data: bytes) -> None:
    path = tmp_path_factory.getbasetemp() / "fuzz-rig.toml"
    path.write_bytes(data)
    system = None
    try:
        system = build_emulated_rig(load_rig(path), seed=0)
        build_loop(system)  # reads [servo] (gains, objects, limits) and the joints' servo tables
    except ConfigError as e:
        # a key where one is wrong; the file itself (not TOML, not UTF-8) names no key
        assert str(path) in str(e) and (f"key '{e.key}'" in str(e) if e.key else "expected" in str(e)), str(e)
        refused("ConfigError " + (e.key.split(".", 1)[0].split("[", 1)[0] or "<file>"))
    finally:
        if system is not None:
            system.close()
