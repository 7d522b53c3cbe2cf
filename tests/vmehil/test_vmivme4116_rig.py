"""The VMIVME-4116 in the DAC role of the JPL arm: the jpl-arm preset with its reference DAC
(``dac0``) replaced by the crate entry the jpl-arm-vmic preset needs (docs/boards/vmivme4116.md),
built through both board-type tables. The servo runs on it, and its safe stop leaves every
amplifier command at 0 V: read from the emulated board and from the plant's side of the nets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from emulators.presets import resolve_rig
from emulators.vmivme4116 import VmiVme4116Board
from hal.adc_dac import VmiVme4116Driver
from servo.rig import load_rig
from servo.runner import LockstepRunner
from vmehil.rig_setup.real_bus import dry_pass
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import EmulatedRig, build_emulated_rig

REFERENCE_DAC = 'type = "dac"\nname = "dac0"'
VMIVME_4116 = 'type = "vmivme-4116"\nupdate = "synchronized"\ncoding = "offset_binary"\nname = "dac0"'
#: the preset's [assumed] per-channel offsets of dac0, kept on the 4116 (docs: output model)
OFFSETS_V = [0.004, -0.003, 0.002, 0.005, -0.004, 0.003]
SEED = 5


def rig_file(tmp_path: Path) -> Path:
    text = resolve_rig("jpl-arm").read_text()
    assert text.count(REFERENCE_DAC) == 1
    p = tmp_path / "jpl-arm-4116.toml"
    p.write_text(text.replace(REFERENCE_DAC, VMIVME_4116))
    return p


def run(system: EmulatedRig, seconds: float) -> np.ndarray:
    n_ticks = round(seconds * system.rig.servo_rate_hz)
    loop = build_loop(system, n_ticks=n_ticks)
    loop.start()
    LockstepRunner(system, loop).run(n_ticks)
    return loop.recorder.trimmed()["theta"]


@pytest.fixture(scope="module")
def ran(tmp_path_factory: pytest.TempPathFactory) -> tuple[EmulatedRig, np.ndarray, np.ndarray]:
    system = build_emulated_rig(rig_file(tmp_path_factory.mktemp("rig")), seed=SEED)
    reference = build_emulated_rig(None, seed=SEED)
    return system, run(system, 1.0), run(reference, 1.0)


def test_the_arm_builds_with_the_4116_as_its_dac_and_the_servo_drives_it(ran) -> None:
    system, theta, theta_ref = ran
    board = system.crate.boards["dac0"]
    assert isinstance(board, VmiVme4116Board) and isinstance(system.io.dac["dac0"], VmiVme4116Driver)
    assert board.connected and board.updates > 100  # one synchronized update per tick
    assert np.any(np.abs(theta[-1] - theta[0]) > 1e-3)  # the joints moved
    # the same motion as on the reference 12-bit DAC, within what the finer LSB changes
    np.testing.assert_allclose(theta, theta_ref, atol=2e-3)


def test_the_safe_stop_leaves_every_amplifier_command_at_zero_volts(ran) -> None:
    system, _, _ = ran
    board = system.crate.boards["dac0"]
    system.io.write_command_volts({0: 2.0, 1: -1.5, 4: 0.5})  # commands on the amplifiers, then the stop
    system.crate.delay(20e-6)
    before = system.harness.collect().amp_command_v
    assert before[0] == pytest.approx(2.0 * 1.001 + 0.004, abs=1e-3) and before[1] < -1.4
    assert system.io.safe_stop() == []  # the stop's own read-back finds nothing unsafe
    system.crate.delay(20e-6)  # two settling times
    assert board.converter == [0x8000] * 8 and board.connected
    # the plant's side: each joint's command net holds the 0 V code's output, the board's offset
    cmd = system.harness.collect().amp_command_v
    np.testing.assert_array_equal(cmd, np.array([*OFFSETS_V, 0.0]))  # the hand: an H-bridge, no DAC command


def test_the_dry_pass_finds_the_4116_by_its_csr_having_no_id_register(tmp_path: Path) -> None:
    spec = load_rig(rig_file(tmp_path))
    system = build_emulated_rig(spec, seed=SEED)
    check = next(c for c in dry_pass(system.crate, spec) if c.name == "dac0")
    assert check.ok and check.detail == "no ID register (VMIVME-4116); CSR 0x4100"  # opened: LED off, on P3
    system.crate.boards["dac0"].inject("removed")
    check = next(c for c in dry_pass(system.crate, spec) if c.name == "dac0")
    assert not check.ok and "BusError" in check.detail
