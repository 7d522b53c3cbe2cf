"""The tools-layer pieces that let procedures run on an emulated rig.

* :class:`EmulatedFixture` — the rig's reference fixture: in the emulator the joint's true
  angle (``system.truth()["theta_joint"]``), as a precise fixture would give. Only ``--auto``
  uses it.
* :class:`EmulatedPositioner` — moves joints with the rig's own servo loop (the paper's gains,
  integrator switch-off, watchdog), ticking the plant in lockstep; lets time pass; borrows an
  amplifier command for one period (:meth:`override_command`).

Procedures see only the :class:`vmehil.calibration.base.Positioner` / ``Fixture`` protocols, so
a real-hardware positioner (the same loop under the real-time runner) slots in unchanged.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from servo.motion import QuinticMove, WaitMove
from servo.trajectory.sequencer import Sequencer
from vmehil.calibration.base import CalibrationAbort, TickHook
from vmehil.calibration.store import CalibrationStore
from vmehil.rig_setup.session import build_loop, plan_context_of
from vmehil.rig_setup.system import EmulatedRig


class EmulatedFixture:
    """Precise joint angles from the emulated plant (ground truth)."""

    def __init__(self, system: EmulatedRig) -> None:
        self.system = system

    def joint_angle(self, joint: int) -> float:
        truth = self.system.truth()
        if truth is None or "theta_joint" not in truth:
            raise RuntimeError("the emulated plant has not reported its state yet")
        return float(truth["theta_joint"][joint])


class EmulatedPositioner:
    """Servo-loop positioner on an emulated rig (lockstep ticks)."""

    def __init__(self, system: EmulatedRig, store: CalibrationStore | None = None) -> None:
        self.system = system
        self.io = system.io
        if store is not None:
            self.io.apply_calibration(store)
        self.period_s = system.rig.period_s
        self.loop = build_loop(system, motion=None, watchdog=True)
        # Start holding where the joints are.
        start = self.io.read().theta
        self.loop.set_motion(Sequencer([WaitMove(0.0)], start, plan_context_of(self.loop)))
        self._theta_d = np.asarray(start, float)
        self._override: dict[int, float] = {}
        period_ns = system.period_ns
        self._t0_ns = -(-int(system.crate.clock.now_ns) // period_ns) * period_ns + period_ns
        self.loop.start()

    # --- ticking --------------------------------------------------------------------------------
    def _tick(self, on_tick: TickHook | None) -> None:
        sys_ = self.system
        k = self.loop.tick_count
        t_tick = self._t0_ns + k * sys_.period_ns
        sys_.crate.advance_to(max(t_tick, sys_.crate.clock.now_ns))
        sys_.harness.publish()
        if on_tick is not None:
            on_tick()
        self.loop.tick(truth=sys_.truth())
        if self._override and self.loop.enabled:
            self.io.write_command_volts(self._override)  # recorded for the watchdog's current check
        self._override = {}
        # The command reaches the amplifier at the computation delay: let the crate run to that
        # instant so the DAC outputs have settled onto their nets before the exchange reads them.
        delay_ns = round(sys_.rig.computation_delay_s * 1e9)
        sys_.crate.advance_to(max(t_tick + delay_ns, sys_.crate.clock.now_ns))
        sys_.harness.step(self.period_s, sys_.rig.computation_delay_s)

    def hold(self, seconds: float, *, on_tick: TickHook | None = None) -> None:
        for _ in range(max(1, round(seconds / self.period_s))):
            self._tick(on_tick)
            if self.loop.fault is not None:
                return

    def move_to(self, targets: dict[int, float], *, settle_s: float = 1.0, on_tick: TickHook | None = None,
                speed_rad_s: float | Mapping[int, float] | None = None) -> None:
        last = self.loop.last.get("theta_d")
        start = np.asarray(last if last is not None else self._theta_d, float).copy()
        goal = start.copy()
        for j, a in targets.items():
            goal[j] = a
        ctx = plan_context_of(self.loop)
        speed = 1.0
        if speed_rad_s is not None:
            vmax = np.asarray(ctx.limits.v_max, float)
            moving = [j for j in targets if abs(goal[j] - start[j]) > 0]
            if moving:  # one coordinated move: no joint faster than its own limit
                limit = speed_rad_s if isinstance(speed_rad_s, Mapping) else dict.fromkeys(moving, speed_rad_s)
                speed = min(1.0, min(limit[j] / vmax[j] for j in moving))
        seq = Sequencer([QuinticMove(goal, None, speed)], start, ctx)
        if seq.plan_error is not None:  # refused (a soft limit, the scene): never started
            raise CalibrationAbort(f"cannot move the joints there: {seq.plan_error}")
        self.loop.set_motion(seq)
        ticks = 0
        # (a loop that replaced the move — it refused it when it was to start — holds instead)
        while not seq.finished and self.loop.sequencer is seq and self.loop.fault is None and ticks < 10**6:
            self._tick(on_tick)
            ticks += 1
        self._theta_d = goal
        self.hold(settle_s, on_tick=on_tick)

    def override_command(self, joint: int, volts: float | None) -> None:
        if volts is None:
            self._override.pop(joint, None)
        else:
            self._override[joint] = float(volts)

    def position(self, joint: int) -> float:
        theta = self.loop.last.get("theta")
        return float(theta[joint]) if theta is not None else float(self._theta_d[joint])

    def faulted(self) -> str | None:
        f = self.loop.fault
        return None if f is None else f"{f.cause} ({f.joint}): {f.detail}"
