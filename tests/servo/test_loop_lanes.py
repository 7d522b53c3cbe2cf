"""ServoLoop in lanes (batched lockstep, issue #34): B loops stacked with ``ServoLoop.from_lanes``
tick as one, and every live lane records, tick by tick, exactly the rows of its scalar twin.

The twins are independent executions: B ordinary scalar loops, each over its own noisy joints
(:class:`NoisyJoints`, its own seeded generator). The lane loop runs over B more of those joints
side by side (:class:`SideBySide`: each lane's joints draw from their own generator, as the twin's
do), so lane b sees the measurement stream twin b sees. The lanes differ in gains, torque limits
and motions (two lanes with the same move timing, one with another, one holding); one lane's joint
is kicked so that its twin's following-error check stops it: that lane is ejected with that cause,
and the others still equal their twins bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from hal.lanes import LaneSet
from servo.control.normalize import normalizing_chain
from servo.control.objects import build_controller
from servo.io import Measurement, SensorResolution
from servo.loop import Recorder, ServoLoop, WatchdogConfig
from servo.motion import QuinticMove, WaitMove
from servo.trajectory import JointLimits, PlanContext, Sequencer

N = 3
PERIOD_S = 0.008
TICKS = 160
INERTIA = np.array([3.0, 1.8, 0.7])
#: per lane: gains, torque limit (N·m), its move (joint, delta rad; None: a hold), its kick (tick, rad/s²)
LANES = [
    ({"kp": 100.0, "kpi": 5000.0, "kv": 50.0, "kvi": 1000.0}, 400.0, (0, 0.10), None),
    ({"kp": 80.0, "kpi": 3000.0, "kv": 40.0, "kvi": 700.0}, 8.0, (0, 0.10), None),  # saturates: anti-windup
    ({"kp": 120.0, "kpi": 6000.0, "kv": 60.0, "kvi": 1200.0}, 400.0, (1, -0.05), None),
    ({"kp": 100.0, "kpi": 5000.0, "kv": 50.0, "kvi": 1000.0}, 400.0, (2, 0.05), (70, 400.0)),  # trips
]
FOLLOWING_ERROR_RAD = 0.04


class NoisyJoints:
    """``N`` rigid joints (θ'' = τ/J + kick) whose sensors read with noise from the joints' own
    generator: the joint I/O of a loop in this test (pot and tach close the loop; encoder, tach and
    current monitor feed the cross-checks)."""

    def __init__(self, seed: int, kick: tuple[int, float] | None) -> None:
        self.n = N
        self.period_s = PERIOD_S
        self.rng = np.random.default_rng(seed)
        self.theta = np.array([0.1, 0.4, -0.2])
        self.omega = np.zeros(N)
        self.torque = np.zeros(N)
        self.enabled = False
        self.kick = kick
        self.ticks = 0
        self.last_current_a = np.zeros(N)
        self.calibration_generation = 0
        self.homed = np.zeros(N, bool)
        self.enc_rad = 2.0 * math.pi / 200000.0

    def resolution(self) -> SensorResolution:
        full = np.full
        return SensorResolution(full(N, 1e-3), full(N, self.enc_rad), full(N, 5e-3), full(N, 0.01), full(N, 5e-3),
                                full(N, 30.0), np.ones(N, bool))

    def read(self) -> Measurement:
        noise = self.rng.normal(size=(3, N))
        pot = self.theta + 3e-4 * noise[0]
        enc = np.round(self.theta / self.enc_rad) * self.enc_rad
        tach = self.omega + 2e-3 * noise[1]
        m = Measurement(theta_pot=pot, theta_enc=enc, omega_tach=tach, omega_enc=self.omega.copy(),
                        current=self.last_current_a + 2e-3 * noise[2], pot_v=pot * 3.37, fault=np.zeros(N, bool),
                        encoder_illegal=np.zeros(N, bool), encoder_counts=enc / self.enc_rad)
        m.theta, m.omega = pot.copy(), tach.copy()
        return m

    def write_torque(self, torque: np.ndarray, omega: np.ndarray | None = None) -> np.ndarray:
        self.torque = np.asarray(torque, float).copy() if self.enabled else np.zeros(N)
        self.last_current_a = self.torque / 2.0  # 2 N·m per A
        return self.last_current_a.copy()

    def enable(self, on: bool = True) -> None:
        self.enabled = on

    def clear_faults(self) -> None:
        pass

    def safe_stop(self, interruptions: list[BaseException] | None = None) -> list[str]:
        self.enabled = False
        self.torque = np.zeros(N)
        self.last_current_a = np.zeros(N)
        return []

    def step(self) -> None:
        a = self.torque / INERTIA
        if self.kick is not None and self.kick[0] <= self.ticks < self.kick[0] + 12:
            a = a + np.array([self.kick[1], 0.0, 0.0])
        self.theta = self.theta + PERIOD_S * self.omega + 0.5 * PERIOD_S * PERIOD_S * a
        self.omega = self.omega + PERIOD_S * a
        self.ticks += 1


class SideBySide:
    """B :class:`NoisyJoints` as the lane-major joint I/O of a lane loop (B·N joints): each lane's
    joints read and move on their own (a stand-in for JointIO over lane drivers)."""

    def __init__(self, lanes: list[NoisyJoints]) -> None:
        self.lanes = lanes
        self.n = N * len(lanes)
        self.period_s = PERIOD_S
        self.calibration_generation = 0
        self.homed = np.zeros(self.n, bool)

    @property
    def last_current_a(self) -> np.ndarray:
        return np.concatenate([j.last_current_a for j in self.lanes])

    def read(self) -> Measurement:
        ms = [j.read() for j in self.lanes]
        m = Measurement(**{f: np.concatenate([getattr(x, f) for x in ms]) for f in (
            "theta_pot", "theta_enc", "omega_tach", "omega_enc", "current", "pot_v", "fault", "encoder_illegal",
            "encoder_counts")})
        m.theta = np.concatenate([x.theta for x in ms])
        m.omega = np.concatenate([x.omega for x in ms])
        return m

    def write_torque(self, torque: np.ndarray, omega: np.ndarray | None = None) -> np.ndarray:
        return np.concatenate([j.write_torque(torque[b * N:(b + 1) * N]) for b, j in enumerate(self.lanes)])

    def enable(self, on: bool = True) -> None:
        for j in self.lanes:
            j.enable(on)

    def clear_faults(self) -> None:
        pass

    def safe_stop(self, interruptions: list[BaseException] | None = None) -> list[str]:
        for j in self.lanes:
            j.safe_stop()
        return []

    def step(self) -> None:
        for j in self.lanes:
            j.step()


def _loop(b: int) -> ServoLoop:
    """Lane ``b``'s scalar loop (not started), over its own joints (seed 100 + b)."""
    gains, tau_max, move, kick = LANES[b]
    io = NoisyJoints(100 + b, kick)
    chain = normalizing_chain(INERTIA, [1.0] * N, [2.0] * N, [1.0] * N)
    controller = build_controller({"objects": ["pid", "torque_limit"], "pid": dict(gains),
                                   "torque_limit": {"tau_max_nm": tau_max}}, chain, PERIOD_S)
    ctx = PlanContext(JointLimits.make(N, 0.5))
    moves: list = [WaitMove(0.3)]
    if move is not None:
        delta = np.zeros(N)
        delta[move[0]] = move[1]
        moves = [QuinticMove(None, delta), WaitMove(0.6)]
    seq = Sequencer(moves, io.theta.copy(), ctx)
    wd = WatchdogConfig(following_error_rad=np.full(N, FOLLOWING_ERROR_RAD))
    return ServoLoop(io, controller, seq, wd, recorder=Recorder(TICKS, N), names=["a", "b", "c"], plan_context=ctx)


def _bits(x: np.ndarray) -> bytes:
    return np.ascontiguousarray(x).tobytes()


def test_lanes_record_their_scalar_twins_rows_bit_for_bit_and_a_tripping_lane_is_ejected():
    B = len(LANES)
    twins = [_loop(b) for b in range(B)]
    scalars = [_loop(b) for b in range(B)]
    lanes = LaneSet(B)
    io = SideBySide([lp.io for lp in scalars])
    lane = ServoLoop.from_lanes(scalars, io, lanes)  # type: ignore[arg-type]
    assert lane.n == B * N and lane.tick != scalars[0].tick  # the lane tick, chosen once
    for live in (lambda: lane.submit(lambda lp: None), lambda: lane.resume()):  # no live changes in lanes
        try:
            live()
        except NotImplementedError:
            pass
        else:
            raise AssertionError("a live change was taken by a lane loop")
    seq = lane.sequencer
    paths = {"quintic": 0, "stay": 0}
    quintic, stay = seq._sample_quintic, seq._sample_stay  # type: ignore[attr-defined]

    def count(name, f):
        def counted(*a):
            paths[name] += 1
            return f(*a)
        return counted
    seq._sample_quintic, seq._sample_stay = count("quintic", quintic), count("stay", stay)  # type: ignore[attr-defined]
    with lane.armed():
        for lp in twins:
            lp.start()
        for k in range(TICKS):
            for lp in twins:
                lp.tick()
                lp.io.step()
            lane.tick()
            io.step()
            for b in np.flatnonzero(lanes.alive).tolist():
                mine, theirs = lane.recorder_for_lane(b), twins[b].recorder
                for f in (*Recorder.FIELDS, "t"):
                    assert _bits(mine.data[f][k]) == _bits(theirs.data[f][k]), (k, b, f)
    for lp in twins:
        if lp.enabled:
            lp.shutdown("end", "the run ended")

    assert paths["quintic"] > 10 and paths["stay"] > 10  # the stacked samples, not only the lanes' own

    # the kicked lane: its twin stopped on the following error; the lane was ejected then, with that cause
    tripped = twins[3].fault
    assert tripped is not None and tripped.cause == "following_error"
    assert not lanes.alive[3] and lanes.reasons[3].startswith("following_error")
    assert lanes.first_tick[3] == tripped.tick and lane.lane_faults[3].detail == tripped.detail
    assert lane.lane_faults[3].joint == tripped.joint
    # the others ran to the end as their twins, which did not stop
    assert lanes.alive[:3].all() and all(twins[b].fault is None for b in range(3))
    # what happened on the way (as the test means it to): lane 1 saturated, the integrators switched off
    assert np.any(np.abs(twins[1].recorder.data["torque"][:, 0]) >= 8.0 - 1e-12)
    assert any(not e.integrating for e in twins[0].law.events)

    # each live lane's end state handed back to its own scalar loop is its twin's
    for b in range(3):
        lane.write_lane(b, scalars[b])
        mine, theirs = scalars[b], twins[b]
        assert mine.tick_count == theirs.tick_count == TICKS
        for f in (*Recorder.FIELDS, "t"):
            assert _bits(mine.recorder.data[f]) == _bits(theirs.recorder.data[f]), (b, f)
        assert mine.law.events == theirs.law.events
        for f in ("ie", "iv", "integrating", "in_band_time", "e_prev"):
            assert _bits(getattr(mine.law.state, f)) == _bits(getattr(theirs.law.state, f)), (b, f)
        assert _bits(mine.law.kp_eff()) == _bits(theirs.law.kp_eff())
        for f in ("_stale_count", "_stale_travel", "_tach_int", "_cur_over", "_ring_ref", "_ring_int"):
            assert _bits(getattr(mine.cross_checks, f)) == _bits(getattr(theirs.cross_checks, f)), (b, f)
        for name in ("position", "velocity", "current"):
            assert _bits(mine.cross_checks.peak_ratio[name]) == _bits(theirs.cross_checks.peak_ratio[name])
        assert [r.t_start for r in mine.sequencer.records] == [r.t_start for r in theirs.sequencer.records]
        assert mine.final_stop is not None and theirs.final_stop is not None
        assert mine.final_stop == theirs.final_stop
        assert mine.stop_summary() == theirs.stop_summary()


def test_stacking_refuses_what_lanes_do_not_run():
    loops = [_loop(0), _loop(1)]
    loops[1].tick_count = 5
    try:
        ServoLoop.from_lanes(loops, SideBySide([lp.io for lp in loops]), LaneSet(2))  # type: ignore[arg-type]
    except NotImplementedError as e:
        assert "tick" in str(e)
    else:
        raise AssertionError("lanes at different ticks were stacked")
    loops = [_loop(0), _loop(1)]
    loops[0].sample_clock = lambda: 0.0
    try:
        ServoLoop.from_lanes(loops, SideBySide([lp.io for lp in loops]), LaneSet(2))  # type: ignore[arg-type]
    except NotImplementedError as e:
        assert "free-running" in str(e)
    else:
        raise AssertionError("a free-running plant's loop was stacked")
