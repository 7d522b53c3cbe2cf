"""Time the 2 s lockstep run in-process and through the FUSE stand-in for /dev/bus/vme, and one D16
read through it (docs/vme-user.md): ``.venv/bin/python -m tests.support.measure_vme_fuse [RIG]`` (default
jpl-arm; e.g. ``jpl-arm-vmic``)."""

from __future__ import annotations

import pathlib
import sys
import tempfile
import time

from emulators.presets import resolve_rig
from hal.vme.vme_user import VmeUserBus
from servo.io import JointIO
from servo.nominal import nominal_scaling, rig_nominal
from servo.runner import LockstepRunner
from tests.support.vme_fuse import MountedVmeUser
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

TICKS = 250


def _run(system, bus):
    system.io = JointIO(bus, system.rig, nominal_scaling(rig_nominal(system.rig)))
    loop = build_loop(system, n_ticks=TICKS)
    loop.start()
    t = time.perf_counter()
    LockstepRunner(system, loop).run(TICKS)
    return time.perf_counter() - t, loop


def main(rig: str = "jpl-arm") -> None:
    ref = build_emulated_rig(resolve_rig(rig), seed=11)
    t_ref, l_ref = _run(ref, ref.crate)
    s = build_emulated_rig(resolve_rig(rig), seed=11)
    adc0 = s.crate.boards["adc0"].base  # its ID register (jpl-arm: 0x6000; jpl-arm-vmic: 0x8500)
    with tempfile.TemporaryDirectory() as d, MountedVmeUser(s.crate, pathlib.Path(d)) as fs:
        with VmeUserBus(fs.dir, clock=s.crate.now, sleep=s.crate.delay) as bus:
            t_fuse, loop = _run(s, bus)
            calls = dict(fs.ops.calls)
            t = time.perf_counter()
            for _ in range(5000):
                bus.read(adc0, space="A16", width=16)
            per = (time.perf_counter() - t) / 5000
    rec, rr = loop.recorder.trimmed(), l_ref.recorder.trimmed()
    print(f"rig {rig}")
    print(f"servo run through FUSE: {calls['read'] / TICKS:.1f} reads, {calls['write'] / TICKS:.1f} writes per tick")
    print(f"in-process {TICKS} ticks {t_ref:.2f} s; through FUSE {t_fuse:.2f} s; one D16 read through FUSE "
          f"{per * 1e6:.1f} us")
    print("final error j1 (rad):", (rec["theta_d"] - rec["theta"])[-1][0], (rr["theta_d"] - rr["theta"])[-1][0])


if __name__ == "__main__":
    main(*sys.argv[1:2])
