"""A controller switch under load on jpl-arm's j2 (issue #36): the torque step and the boom's true
movement, bumpless (console ``controller use``, MAVLink ``J2_CTRL``) and as a plain gain change.

``python -m benchmarks.controller_switch``

The measurement of tests/vmehil/test_controller_switch_rig.py (its helper ``_around_switch``,
seed 0, the rig file of tests/support/rig_variants.py), printed: the step at the switch (the
torque commanded in the switch tick against a copy of the old controller on the same
measurements), the step of the mean torque over 12 ticks each side, the true angle's peak to
peak over the 24 ticks. Figures in docs/control.md.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from servo.motion import hold_motion
from servo.runner import LockstepRunner
from tests.support.rig_variants import STIFF, rig_with
from tests.vmehil.test_controller_switch_rig import J2, SWITCH_AT, TAU_MAX_J2_NM, WINDOW, _around_switch
from vmehil.console.commands import ATOMS, Session
from vmehil.mavlink.params import ParamTable
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig


def _console(loop: Any) -> Callable[[], object]:
    return lambda: ATOMS["controller"].run(Session(loop=loop, delay=0.125),
                                           {"action": "use", "name": "stiff", "joint": J2})


def _mavlink(loop: Any) -> Callable[[], object]:
    table = ParamTable(loop, delay_periods=0.125)
    return lambda: table.apply_command(table.find("J2_CTRL")[1], 2.0)(loop)


def _plain(loop: Any) -> Callable[[], object]:
    return lambda: loop.law.set_gains(kp=200.0, kpi=10000.0, kv=60.0, kvi=2000.0, joint=J2)


def main(quick: bool = False) -> list[str]:
    lines = []
    with tempfile.TemporaryDirectory() as d:
        rig = rig_with(Path(d), STIFF)
        for name, make in (("controller use stiff j2", _console), ("J2_CTRL = 2 (filter 5 Hz)", _mavlink),
                           ("gains j2 kp=200 kpi=10000 kv=60 kvi=2000", _plain)):
            system = build_emulated_rig(rig, seed=0)
            loop = build_loop(system, motion=hold_motion(), n_ticks=SWITCH_AT + 2 * WINDOW + 10)
            runner = LockstepRunner(system, loop)
            with loop.armed():
                step, mean_step, excursion, load = _around_switch(system, loop, runner, make(loop))
            system.close()
            lines.append(f"{name}: load {load:.2f} N·m; step at the switch {step:.3f} N·m "
                         f"({100 * step / TAU_MAX_J2_NM:.2f} %); mean step {mean_step:.3f} N·m "
                         f"({100 * mean_step / TAU_MAX_J2_NM:.2f} %); true angle {excursion:.4f}° peak to peak")
    for line in lines:
        print(line)
    return lines


if __name__ == "__main__":
    main()
