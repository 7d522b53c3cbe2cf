"""Every fake the tests use, in one place.

* :class:`DoubleIntegrator`: ``n`` ideal rigid joints, θ'' = τ/J + d, integrated exactly over each
  period with the input held (zero-order hold). It is the plant of the law-level tests
  (:meth:`DoubleIntegrator.step`) and, through the :class:`servo.io.JointIO` methods, the joint
  I/O of a real :class:`servo.loop.ServoLoop` with no crate behind it (measured = true values).
* :func:`make_loop` and :func:`tick`: a started loop over it holding still, ticked by the test
  (the console and resume tests).
* :func:`fake_loop` and :class:`DoubleIntegratorLockstepRunner`: a started loop that moves and then holds, with a
  runner's ``after_tick`` callbacks (the MAVLink tests).
* :class:`LossyEndpoint` and :func:`sync_frames_of`: a CAN endpoint that loses chosen outgoing
  frames (fault injection on the plant link).

The loops are the real ones (controller, sequencer, watchdog); only the joints are fake. As on the
rig, the plant advances once per tick, after the loop's work (:func:`tick`,
:meth:`DoubleIntegratorLockstepRunner.tick`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import can
import numpy as np

from emulators.can.bus import Endpoint
from emulators.can.dbc import ID_SYNC
from servo.control.normalize import normalizing_chain, unit_chain
from servo.control.objects import Controller, build_controller
from servo.io import Measurement
from servo.loop import Recorder, ServoLoop, WatchdogConfig
from servo.motion import QuinticMove, WaitMove
from servo.trajectory import JointLimits, PlanContext, Sequencer


class DoubleIntegrator:
    """``n`` joints of inertia ``inertia`` (kg·m², one value or one per joint) in rad, rad/s, N·m.

    :meth:`step` advances one period. As joint I/O: :meth:`write_torque` holds the torque (zero
    while disabled) for the coming period, reported back as the measured current; set
    ``read_error`` to make :meth:`read` raise it, ``fault`` to assert amplifier fault lines.
    """

    def __init__(self, n: int = 1, period_s: float = 0.008, inertia: float | Sequence[float] = 1.0) -> None:
        self.n = n
        self.period_s = period_s
        self.inertia = np.broadcast_to(np.asarray(inertia, float), (n,)).copy()
        self.theta = np.zeros(n)
        self.omega = np.zeros(n)
        self.torque = np.zeros(n)
        self.enabled = False
        self.fault = np.zeros(n, bool)
        self.read_error: Exception | None = None

    def step(self, torque: np.ndarray | float | None = None, disturbance: np.ndarray | float = 0.0,
             period_s: float | None = None) -> None:
        """Advance one period (``period_s``, default the joints' period) with ``torque`` held (default:
        the torque last written) plus the acceleration ``disturbance`` (rad/s²)."""
        T = self.period_s if period_s is None else period_s
        tau = self.torque if torque is None else np.asarray(torque, float)
        a = tau / self.inertia + disturbance
        self.theta = self.theta + T * self.omega + 0.5 * T * T * a
        self.omega = self.omega + T * a

    # --- servo.io.JointIO ------------------------------------------------------------------------
    def read(self) -> Measurement:
        if self.read_error is not None:
            raise self.read_error
        nan = np.full(self.n, np.nan)
        return Measurement(theta_pot=self.theta.copy(), theta_enc=self.theta.copy(), omega_tach=self.omega.copy(),
                           omega_enc=self.omega.copy(), current=self.torque.copy(), pot_v=nan,
                           fault=self.fault.copy(), theta=self.theta.copy(), omega=self.omega.copy())

    def write_torque(self, torque: np.ndarray, omega: np.ndarray | None = None) -> np.ndarray:
        self.torque = np.asarray(torque, float).copy() if self.enabled else np.zeros(self.n)
        return self.torque.copy()

    def enable(self, on: bool = True) -> None:
        self.enabled = on

    def clear_faults(self) -> None:
        self.fault[:] = False

    def safe_stop(self, interruptions: list[BaseException] | None = None) -> list[str]:
        self.enabled = False
        self.torque = np.zeros(self.n)
        return []


def _started_loop(io: DoubleIntegrator, controller: Controller, moves: list, limits: JointLimits,
                  following_error_rad: float, names: list[str] | None = None,
                  recorder: Recorder | None = None) -> ServoLoop:
    ctx = PlanContext(limits)
    seq = Sequencer(moves, np.zeros(io.n), ctx)
    loop = ServoLoop(io, controller, seq, WatchdogConfig(following_error_rad=np.full(io.n, following_error_rad)),
                     recorder=recorder, names=names or [f"j{i + 1}" for i in range(io.n)], plan_context=ctx)
    loop.start()
    return loop


def make_loop(n: int = 2, names: list[str] | None = None, inertia: float = 1.0) -> ServoLoop:
    """A started loop (paper gains, pid only) over a :class:`DoubleIntegrator` (``loop.io``), holding
    at zero; speed limit 30°/s, following-error limit 10°. Drive it with :func:`tick`."""
    io = DoubleIntegrator(n, inertia=inertia)
    chain = normalizing_chain([inertia] * n, [1.0] * n, [1.0] * n, [1.0] * n)
    controller = build_controller({"objects": ["pid"]}, chain, io.period_s)
    return _started_loop(io, controller, [], JointLimits.make(n, math.radians(30.0)), math.radians(10.0), names)


def tick(loop: ServoLoop, console=None, n: int = 1) -> None:
    """Run ``n`` ticks as a runner does: the loop's work, the joints through the period, then the
    console's per-tick hook."""
    for _ in range(n):
        loop.tick()
        loop.io.step()
        if console is not None:
            console.on_tick(loop)


class DoubleIntegratorLockstepRunner:
    """Lockstep runner over a :class:`DoubleIntegrator` with ``after_tick`` callbacks (as the real runners)."""

    def __init__(self, loop: ServoLoop, io: DoubleIntegrator) -> None:
        self.loop = loop
        self.io = io
        self.after_tick: list[Callable[[ServoLoop], None]] = []
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
              n_ticks: int = 0) -> tuple[ServoLoop, DoubleIntegrator, DoubleIntegratorLockstepRunner]:
    """A started loop over unit-inertia joints moving every joint by ``move_rad`` then holding, with
    torque limit 50 N·m and the default JPL gains (Kp 100, Kpi 5000, Kv 50, KvI 1000); speed limit
    0.5 rad/s, following-error limit 0.5 rad; a recorder of ``n_ticks`` rows when given."""
    io = DoubleIntegrator(n, period_s)
    controller = build_controller({"objects": ["pid", "torque_limit"], "torque_limit": {"tau_max_nm": 50.0}},
                                  unit_chain(n), period_s)
    moves = [QuinticMove(None, np.full(n, move_rad)), WaitMove(hold_s)]
    loop = _started_loop(io, controller, moves, JointLimits.make(n, 0.5), 0.5,
                         recorder=Recorder(n_ticks, n) if n_ticks else None)
    return loop, io, DoubleIntegratorLockstepRunner(loop, io)


class LossyEndpoint(Endpoint):
    """Drops outgoing frames for which ``drop(msg)`` is true (fault injection)."""

    def __init__(self, *a, drop: Callable[[can.Message], bool] | None = None, **kw) -> None:
        super().__init__(*a, **kw)
        self.drop = drop or (lambda m: False)

    def send(self, msg: can.Message) -> None:
        if not self.drop(msg):
            super().send(msg)


def sync_frames_of(ticks) -> Callable[[can.Message], bool]:
    """A ``drop`` for :class:`LossyEndpoint`: the controller's SYNC frames of these link ticks."""
    ticks = set(ticks)
    return lambda m: m.arbitration_id == ID_SYNC and int.from_bytes(m.data[:4], "little") in ticks
