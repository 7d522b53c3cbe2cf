"""A 2 s lockstep servo run whose drivers talk to the emulated boards through the vme_user
backend: real open/ioctl/pread/pwrite system calls on a FUSE stand-in for /dev/bus/vme. On
``jpl-arm`` (the reference boards) and on ``jpl-arm-vmic`` (the VMIC boards; its SBS 617 vision
link is a PCI card the joint I/O never touches, so the run is the whole preset's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from emulators.presets import resolve_rig
from hal.vme.vme_user import VmeUserBus
from servo.io import JointIO
from servo.nominal import nominal_scaling, rig_nominal
from servo.runner import LockstepRunner
from tests.support.vme_fuse import MountedVmeUser, fuse_unavailable
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import EmulatedRig, build_emulated_rig

SECONDS = 2.0
SEED = 11


def _run(system: EmulatedRig, bus) -> tuple[np.ndarray, np.ndarray]:
    # the same construction either way: drivers built a second time, on the bus under test
    system.io = JointIO(bus, system.rig, nominal_scaling(rig_nominal(system.rig)))
    n_ticks = round(SECONDS * system.rig.servo_rate_hz)
    loop = build_loop(system, n_ticks=n_ticks)
    loop.start()
    LockstepRunner(system, loop).run(n_ticks)
    rec = loop.recorder.trimmed()
    return rec["theta"], rec["theta_d"] - rec["theta"]


@pytest.mark.slow
@pytest.mark.parametrize("rig", ["jpl-arm", "jpl-arm-vmic"])
def test_servo_run_through_vme_user_matches_the_in_process_run(tmp_path: Path, rig: str) -> None:
    why = fuse_unavailable()
    if why:
        pytest.skip(f"FUSE stand-in cannot be mounted: {why}")
    ref = build_emulated_rig(resolve_rig(rig), seed=SEED)
    theta_ref, err_ref = _run(ref, ref.crate)

    system = build_emulated_rig(resolve_rig(rig), seed=SEED)
    with MountedVmeUser(system.crate, tmp_path) as fs:
        with VmeUserBus(fs.dir, clock=system.crate.now, sleep=system.crate.delay) as bus:
            theta, err = _run(system, bus)
    assert fs.ops.calls["read"] > 1000 and fs.ops.calls["write"] > 100  # it did go through the kernel
    assert fs.ops.calls["ioctl"] <= 4 + 2 * 4  # probe/read-back, then each window set once and reused
    assert len(theta) == round(SECONDS * ref.rig.servo_rate_hz)
    np.testing.assert_array_equal(err[-1], err_ref[-1])  # the same final error, joint by joint
    np.testing.assert_array_equal(theta, theta_ref)
    assert np.any(np.abs(theta[-1] - theta[0]) > 1e-3)  # the joints moved
