"""A small in-process servo loop for exercising the endpoint without the emulated crate: a real
:class:`servo.loop.ServoLoop` with the real controller, over ideal unit-inertia joints (θ'' = τ,
exact zero-order-hold integration). For tests and demos of the MAVLink endpoint.
"""

from __future__ import annotations

import numpy as np

from servo.control.normalize import unit_chain
from servo.control.objects import build_controller
from servo.io import Measurement
from servo.loop import Recorder, ServoLoop, WatchdogConfig
from servo.motion import QuinticMove, WaitMove
from servo.trajectory.base import JointLimits
from servo.trajectory.sequencer import PlanContext, Sequencer


class DoubleIntegratorIO:
    """Joint I/O of ``n`` ideal joints (unit inertia, rad, rad/s, N·m) advanced by :meth:`step`."""

    def __init__(self, n: int, period_s: float = 0.008, friction_nm: float = 0.0) -> None:
        self.n = n
        self.period_s = period_s
        self.theta = np.zeros(n)
        self.omega = np.zeros(n)
        self.torque = np.zeros(n)
        self.friction_nm = friction_nm
        self.enabled = False
        self.fault = np.zeros(n, bool)

    def read(self) -> Measurement:
        nan = np.full(self.n, np.nan)
        return Measurement(theta_pot=self.theta.copy(), theta_enc=self.theta.copy(), omega_tach=self.omega.copy(),
                           omega_enc=self.omega.copy(), current=self.torque.copy(), pot_v=nan, fault=self.fault.copy(),
                           theta=self.theta.copy(), omega=self.omega.copy())

    def write_torque(self, torque: np.ndarray, omega: np.ndarray | None = None) -> np.ndarray:
        self.torque = np.asarray(torque, float).copy() if self.enabled else np.zeros(self.n)
        return self.torque.copy()

    def enable(self, on: bool = True) -> None:
        self.enabled = on

    def clear_faults(self) -> None:
        self.fault[:] = False

    def safe_stop(self) -> list[str]:
        self.enabled = False
        self.torque = np.zeros(self.n)
        return []

    def step(self) -> None:
        """Advance one period with the held torque (minus Coulomb friction while moving)."""
        T = self.period_s
        a = self.torque - self.friction_nm * np.sign(self.omega)
        self.theta = self.theta + self.omega * T + 0.5 * a * T * T
        self.omega = self.omega + a * T


class FakeRunner:
    """Lockstep runner over :class:`DoubleIntegratorIO` with ``after_tick`` callbacks."""

    def __init__(self, loop: ServoLoop, io: DoubleIntegratorIO) -> None:
        self.loop = loop
        self.io = io
        self.after_tick: list = []
        self.delay_s = 0.0

    def tick(self) -> None:
        self.loop.tick()
        self.io.step()
        for cb in self.after_tick:
            cb(self.loop)

    def run(self, n_ticks: int) -> None:
        for _ in range(n_ticks):
            self.tick()


def fake_loop(n: int = 2, period_s: float = 0.008, move_rad: float = 0.2, hold_s: float = 60.0,
              n_ticks: int = 0) -> tuple[ServoLoop, DoubleIntegratorIO, FakeRunner]:
    """A started loop moving every joint by ``move_rad`` then holding; with torque limit 50 N·m and
    the default JPL gains (Kp 100, Kpi 5000, Kv 50, KvI 1000)."""
    io = DoubleIntegratorIO(n, period_s)
    controller = build_controller({"objects": ["pid", "torque_limit"], "torque_limit": {"tau_max_nm": 50.0}},
                                  unit_chain(n), period_s)
    ctx = PlanContext(JointLimits.make(n, 0.5))
    seq = Sequencer([QuinticMove(None, np.full(n, move_rad)), WaitMove(hold_s)], np.zeros(n), ctx)
    loop = ServoLoop(io, controller, seq, WatchdogConfig(following_error_rad=np.full(n, 0.5)),
                     recorder=Recorder(n_ticks, n) if n_ticks else None, names=[f"j{i + 1}" for i in range(n)])
    loop.plan_context = ctx  # type: ignore[attr-defined]
    loop.start()
    return loop, io, FakeRunner(loop, io)
