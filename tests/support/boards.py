"""What the emulated boards say about the amplifiers: read off the crate's nets (enable lines, DAC
outputs, PWM) and the plant's currents, never off a flag of the loop's.

No tests here; safe-stop tests import it as ``tests.support.boards``.
"""

from __future__ import annotations

import numpy as np
import pytest


def assert_boards_safe(system) -> None:
    """Every enable line low, every amplifier command at 0 V, PWM off, no drive current in the plant."""
    signals = system.crate.signals
    for j in system.rig.joints:
        if "amp_enable" in j.wiring:
            assert signals.get_digital(j.net("amp_enable")) is False, f"{j.name} enable still high"
        if "amp_command" in j.wiring:
            # 0 V commanded; the uncalibrated DAC's offset error (≤ 10 mV in the preset) remains
            assert signals.get_analog(j.net("amp_command")) == pytest.approx(0.0, abs=0.0125), j.name
        if "pwm" in j.wiring:
            assert signals.get_analog(j.net("pwm")) == 0.0, f"{j.name} PWM still running"
    # the plant has seen the stop (the exchange that carried it over): no drive current any more
    answer = system.harness.pending or system.harness.last
    assert np.all(np.abs(answer.truth["current_a"]) < 0.5)


def driving(system) -> bool:
    """Whether any amplifier enable line is high on the emulated boards."""
    s = system.crate.signals
    return any(s.get_digital(j.net("amp_enable")) for j in system.rig.joints if "amp_enable" in j.wiring)


def watch_enables(monkeypatch) -> tuple[list, list[str]]:
    """Watch every rig the command builds (``vmehil.rig_setup.system.build_emulated_rig``) from its
    build on: returns ``(built, raised)``, the systems built and the joints whose amplifier enable
    net ever went high."""
    from vmehil.rig_setup import system as rig_system

    built: list = []
    raised: list[str] = []
    real_build = rig_system.build_emulated_rig

    def watched(*args, **kwargs):
        system = real_build(*args, **kwargs)
        for j in system.rig.joints:
            if "amp_enable" in j.wiring:
                system.crate.signals.subscribe(j.net("amp_enable"),
                                               lambda v, name=j.name: raised.append(name) if v else None)
        built.append(system)
        return system

    monkeypatch.setattr(rig_system, "build_emulated_rig", watched)
    return built, raised
