"""The servo side of jpl-arm in lanes (batched lockstep, issue #34): ``JointIO.from_lanes``,
``ServoLoop.from_lanes`` and ``LockstepRunner.from_lanes`` tick B sweep points (different gains;
one whose tach brush drop trips its watchdog) as one, and every live lane's run equals its scalar
twin's — recorded rows, switch-off events, the boards' counters, the figures of its report.

The boards' lane drivers are branches of their own (lane-adc, lane-dacpio, lane-quad); here a
stand-in (:class:`PerLane`) drives lane b's values into a scalar driver of lane b's own rig, one
call per lane, and stacks what they return: an independent implementation of the lane drivers'
interface (a (k, B) scan, readings whose fields are (B,) values, ports as (B,) words).
"""

from __future__ import annotations

import hashlib
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from hal.lanes import LaneSet
from servo.io import JointIO, PotCalibration
from servo.loop import ServoLoop
from servo.runner import LockstepRunner
from vmehil.analysis.rigparams import load_joint
from vmehil.analysis.simulate import SimRun, SimSettings
from vmehil.analysis.sweep import rig_text, task_rig

SIM = SimSettings(move_deg=10, hold_s=0.5, allow_short=True, seed=3)
TRIP_DROP_V = 0.2  #: tach brush drop of the tripping lane (nominal 0.12 V: docs/sweeps.md)


def _points():
    text = rig_text("jpl-arm")
    nominal = task_rig(text, "jpl-arm", 1)
    tripping = task_rig(text, "jpl-arm", 1, {"tach_brush_drop": TRIP_DROP_V})
    return [load_joint(nominal, 1, gains={"kp": 80.0}), load_joint(nominal, 1, gains={"kp": 120.0, "kvi": 700.0}),
            load_joint(tripping, 1), load_joint(nominal, 1, gains={"kv": 40.0})]


def _lane_value(v: Any, b: int) -> Any:
    if isinstance(v, np.ndarray) and v.ndim >= 1:
        return v[..., b].item() if v.ndim == 1 else v[..., b]
    if isinstance(v, dict):
        return {k: _lane_value(x, b) for k, x in v.items()}
    return v


def _stacked(values: list[Any]) -> Any:
    first = values[0]
    if first is None:
        return None
    if isinstance(first, dict):
        return {k: _stacked([v[k] for v in values]) for k in first}
    if isinstance(first, tuple):
        return tuple(_stacked(list(x)) for x in zip(*values, strict=True))
    if isinstance(first, bool | int | float | np.ndarray | np.generic):
        return np.stack([np.asarray(v) for v in values], axis=-1)
    fields = getattr(first, "__dataclass_fields__", None)
    if fields is not None:  # a reading (and its status): each field a lane value
        return SimpleNamespace(**{f: _stacked([getattr(v, f) for v in values]) for f in fields})
    return first


class PerLane:
    """A lane driver stand-in: lane b's values to scalar driver ``drivers[b]``, results stacked."""

    def __init__(self, drivers: list[Any]) -> None:
        self._drivers = drivers

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._drivers[0], name)
        if not callable(attr):
            return attr

        def call(*args: Any, **kwargs: Any) -> Any:
            out = [getattr(d, name)(*(_lane_value(a, b) for a in args),
                                    **{k: _lane_value(v, b) for k, v in kwargs.items()})
                   for b, d in enumerate(self._drivers)]
            return _stacked(out)
        return call


class SideBySidePlants:
    """The B rigs' plant boundaries as one (a stand-in for the lane harness and plant): each rig
    steps on its own; the truth is lane-major."""

    def __init__(self, systems: list[Any]) -> None:
        self.systems = systems
        first = systems[0]
        self.joints, self.period_s, self.computation_delay_s = first.joints, first.period_s, first.computation_delay_s

    def advance_to(self, t_ns: int) -> None:
        for s in self.systems:
            s.advance_to(t_ns)

    def sense(self, tick: int) -> None:
        for s in self.systems:
            s.sense(tick)

    def exchange(self, tick: int) -> None:
        for s in self.systems:
            s.exchange(tick)

    def truth(self) -> dict[str, np.ndarray]:
        truths = [s.truth() for s in self.systems]
        return {k: np.concatenate([t[k] for t in truths]) for k in truths[0]}


def _digest(run: SimRun) -> dict[str, Any]:
    rec = run.loop.recorder.trimmed()
    out: dict[str, Any] = {k: hashlib.sha256(np.ascontiguousarray(v).tobytes()).hexdigest()
                           for k, v in rec.items() if k != "compute_s"}
    out["ticks"] = run.loop.tick_count
    out["events"] = run.loop.law.events
    out["counters"] = run.system.crate.counter_snapshot()
    out["clock_ns"] = run.system.crate.clock.now_ns
    out["final_stop"] = run.loop.final_stop
    return out


@pytest.mark.slow  # ≈ 3 s at rest (8 runs of jpl-arm)
def test_jpl_arm_sweep_points_in_lanes_equal_their_scalar_runs_and_a_trip_ejects_only_its_lane() -> None:
    points = _points()
    twins = [SimRun(jp, False, SIM) for jp in points]
    runs = [SimRun(jp, False, SIM) for jp in points]
    try:
        for r in twins:
            with r.loop.armed():
                r.runner.run(r.n_ticks, stop=r.halt_when(None))
        B = len(runs)
        lanes = LaneSet(B)
        ios = [r.system.io for r in runs]

        def per_lane(role: str) -> dict[str, PerLane]:
            return {name: PerLane([getattr(io, role)[name] for io in ios]) for name in getattr(ios[0], role)}

        io = JointIO.from_lanes(ios, lanes, adc=per_lane("adc"), dac=per_lane("dac"), pio=per_lane("pio"),
                                quad=per_lane("quad"))
        loop = ServoLoop.from_lanes([r.loop for r in runs], io, lanes)
        runner = LockstepRunner.from_lanes([r.runner for r in runs], SideBySidePlants([r.system for r in runs]), loop)
        with loop.armed():
            runner.run(runs[0].n_ticks, stop=lambda: not lanes.alive.any())
        for b in np.flatnonzero(lanes.alive).tolist():
            loop.write_lane(b, runs[b].loop)
        ejected = twins[2].loop.fault
        assert ejected is not None and ejected.cause == "velocity_mismatch"
        assert lanes.alive.tolist() == [True, True, False, True]
        assert lanes.reasons[2].startswith("velocity_mismatch") and lanes.first_tick[2] == ejected.tick
        assert loop.lane_faults[2].detail == ejected.detail
        for b in (0, 1, 3):
            assert twins[b].loop.fault is None
            assert _digest(runs[b]) == _digest(twins[b]), f"lane {b} differs from its scalar run"
            assert runs[b].figures(runs[b].summarize()) == twins[b].figures(twins[b].summarize())
    finally:
        for r in twins + runs:
            r.close()


def test_lanes_refuse_a_run_with_injected_faults() -> None:
    jp = _points()[0]
    runs = [SimRun(jp, False, SIM), SimRun(jp, False, SIM, faults=("adc_noise@0.1:joint=j1,rms_v=0.02",))]
    try:
        with pytest.raises(NotImplementedError, match="after-tick"):
            LockstepRunner.from_lanes([r.runner for r in runs], SideBySidePlants([r.system for r in runs]),
                                      runs[0].loop)
    finally:
        for r in runs:
            r.close()


def _bits(x: Any) -> bytes:
    return np.ascontiguousarray(np.asarray(x)).tobytes()


def test_joint_io_in_lanes_reads_and_commands_each_lane_as_its_own_io_does() -> None:
    """A seeded program of torque writes (saturating ones, a NaN, a non-finite speed, the hand's
    H-bridge changing direction) and reads, then a safe stop: every lane's measurement, commanded
    current and board state equal its twin rig's, bit for bit. Pots calibrated: j1 with one table
    in every lane (read for all lanes at once; readings inside and beyond its ends), j2 with a
    table of its own per lane."""
    from vmehil.rig_setup.system import build_emulated_rig

    seeds = (1, 2, 5)
    twins = [build_emulated_rig("jpl-arm", seed=s) for s in seeds]
    systems = [build_emulated_rig("jpl-arm", seed=s) for s in seeds]
    try:
        B, n = len(seeds), twins[0].io.n
        for b, s in enumerate((*twins, *systems)):
            s.io.set_pot_calibration(0, PotCalibration([0.05, 0.058, 0.062, 0.07], [0.0149, 0.0172, 0.0183, 0.0209]))
            lane_b = b % B
            s.io.set_pot_calibration(1, PotCalibration([-6.0, -2.0, 3.0, 6.0],
                                                       [-1.0, -0.1 - 0.01 * lane_b, 1.7, 2.5 + 0.1 * lane_b]))
        lanes = LaneSet(B)
        ios = [s.io for s in systems]

        def per_lane(role: str) -> dict[str, PerLane]:
            return {name: PerLane([getattr(io, role)[name] for io in ios]) for name in getattr(ios[0], role)}

        io = JointIO.from_lanes(ios, lanes, adc=per_lane("adc"), dac=per_lane("dac"), pio=per_lane("pio"),
                                quad=per_lane("quad"))
        plants = SideBySidePlants(systems)
        rng = np.random.default_rng(7)
        limit = np.array([0.8, 0.4, 0.25, 0.1, 0.1, 0.05, 1.0])  # N·m (the hand's: 2 A at 0.5 N·m/A)
        for t in twins:
            t.io.clear_faults()
            t.io.enable(True)
        io.clear_faults()
        io.enable(True)
        pot_j1: list[float] = []
        period_ns, delay_ns = round(twins[0].period_s * 1e9), round(twins[0].computation_delay_s * 1e9)
        for k in range(60):
            torque = rng.normal(size=(B, n)) * limit * (3.0 if k % 7 == 0 else 0.5)
            if k == 20:
                torque[1, 2] = np.nan
            for s in (*twins, plants):
                s.advance_to(k * period_ns)
                s.sense(k)
            got = io.read()
            pot_j1.extend(got.pot_v[::n].tolist())
            speed = got.omega.copy()
            if k == 30:
                speed[n + 6] = np.inf  # lane 1's hand: no back-EMF feed-forward
            cur = io.write_torque(torque.reshape(-1), speed)
            duty = io.pio["pio0"].pwm_duty()  # (a read-back: the twins each make it too)
            for b, t in enumerate(twins):
                m = t.io.read()
                for f in ("theta_pot", "theta_enc", "omega_tach", "omega_enc", "current", "pot_v", "fault", "theta",
                          "omega", "encoder_illegal", "encoder_counts"):
                    assert _bits(getattr(got, f)[b * n:(b + 1) * n]) == _bits(np.asarray(getattr(m, f), getattr(
                        got, f).dtype)), (k, b, f)
                mine = t.io.write_torque(torque[b], speed[b * n:(b + 1) * n])
                assert _bits(cur[b * n:(b + 1) * n]) == _bits(mine), (k, b)
                assert _bits(io.last_dac_volts[b * n:(b + 1) * n]) == _bits(t.io.last_dac_volts)
                assert _bits(io.brake_released[b * n:(b + 1) * n]) == _bits(t.io.brake_released)
                assert duty[b] == t.io.pio["pio0"].pwm_duty()  # the hand's H-bridge
            for s in (*twins, plants):
                s.advance_to(k * period_ns + delay_ns)
                s.exchange(k)
        assert lanes.alive.all()
        # j1's table was read inside and beyond its ends
        assert min(pot_j1) < 0.05 and max(pot_j1) > 0.07 and any(0.05 < v < 0.07 for v in pot_j1), (
            min(pot_j1), max(pot_j1))
        assert io.safe_stop() == [] and io.lane_stop_failures == [[], [], []]
        for b, t in enumerate(twins):
            assert t.io.safe_stop() == []
            assert systems[b].crate.counter_snapshot() == t.crate.counter_snapshot()
            assert {k: _bits(v) for k, v in systems[b].truth().items()} == {k: _bits(v) for k, v in t.truth().items()}
            assert _bits(io.brake_released[b * n:(b + 1) * n]) == _bits(t.io.brake_released)
    finally:
        for s in twins + systems:
            s.close()


def _lane_drivers_landed() -> bool:
    from hal.adc_dac.adc import AdcDriver
    from hal.adc_dac.dac import DacDriver
    from hal.pio.pio import PioDriver
    from hal.quadrature.quad import QuadratureDriver

    return all(hasattr(d, "from_lanes") for d in (AdcDriver, DacDriver, PioDriver, QuadratureDriver))


@pytest.mark.skipif(not _lane_drivers_landed(),
                    reason="the lane drivers (lane-adc, lane-dacpio, lane-quad) have not landed")
def test_joint_io_over_the_lane_drivers_on_a_crate_of_lanes_equals_each_lanes_own_io() -> None:
    """JointIO.from_lanes over the drivers' own lane mode on ``Crate.from_lanes``: every lane's
    readings, commands and bus cycles are its twin rig's; the lane whose hand reverses (its PIO
    driver would flip the direction line: a cycle the others do not make) is ejected. No lane
    plant here: the nets hold the power-up readings (the boards' noise still differs per tick)."""
    from emulators.crate import Crate
    from vmehil.rig_setup.system import build_emulated_rig

    seeds = (1, 2, 5)
    twins = [build_emulated_rig("jpl-arm", seed=s) for s in seeds]
    systems = [build_emulated_rig("jpl-arm", seed=s) for s in seeds]
    try:
        B, n = len(seeds), twins[0].io.n
        lanes = LaneSet(B)
        crate = Crate.from_lanes([s.crate for s in systems], lanes)
        ios = [s.io for s in systems]

        def drivers(role: str) -> dict[str, Any]:
            return {name: type(d).from_lanes([getattr(io, role)[name] for io in ios], crate)
                    for name, d in getattr(ios[0], role).items()}

        io = JointIO.from_lanes(ios, lanes, adc=drivers("adc"), dac=drivers("dac"), pio=drivers("pio"),
                                quad=drivers("quad"))
        rng = np.random.default_rng(7)
        limit = np.array([0.8, 0.4, 0.25, 0.1, 0.1, 0.05, 1.0])
        for t in twins:
            t.io.clear_faults()
            t.io.write_torque(np.zeros(n))
            t.io.enable(True)
        io.clear_faults()
        io.write_torque(np.zeros(B * n))
        io.enable(True)
        period_ns = round(twins[0].period_s * 1e9)
        for k in range(1, 60):
            torque = rng.normal(size=(B, n)) * limit * (3.0 if k % 7 == 0 else 0.5)
            torque[:, 6] = np.abs(torque[:, 6]) * (-1.0 if k >= 40 else 1.0) ** np.arange(B)  # lane 1's hand reverses
            crate.advance_to(k * period_ns)
            for t in twins:
                t.crate.advance_to(k * period_ns)
            got = io.read()
            cur = io.write_torque(torque.reshape(-1), got.omega)
            for b, t in enumerate(twins):
                m = t.io.read()
                mine = t.io.write_torque(torque[b], m.omega)
                if not lanes.alive[b]:
                    continue
                for f in ("theta_pot", "theta_enc", "omega_tach", "omega_enc", "current", "pot_v", "fault", "theta",
                          "omega", "encoder_counts"):
                    assert _bits(getattr(got, f)[b * n:(b + 1) * n]) == _bits(np.asarray(getattr(m, f), getattr(
                        got, f).dtype)), (k, b, f)
                assert _bits(cur[b * n:(b + 1) * n]) == _bits(mine), (k, b)
        # lane 1's hand reversing alone is no divergence: set_pwm makes the same cycles either way
        assert lanes.alive.tolist() == [True, True, True]
        codes = {ch: np.broadcast_to(np.asarray(io.dac["dac0"].read_back_counts(ch)), (B,)) for ch in range(8)}
        assert io.safe_stop() == [] and io.lane_stop_failures[0] == io.lane_stop_failures[1] == \
            io.lane_stop_failures[2] == []
        for b in (0, 1, 2):
            t = twins[b]
            assert [int(codes[ch][b]) for ch in range(8)] == [t.io.dac["dac0"].read_back_counts(ch) for ch in range(8)]
            assert t.io.safe_stop() == []
        assert crate.counter_snapshot() == twins[0].crate.counter_snapshot() == twins[1].crate.counter_snapshot() \
            == twins[2].crate.counter_snapshot()
    finally:
        for s in twins + systems:
            s.close()
