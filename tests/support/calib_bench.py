"""A calibration test bench: a small rig built from board emulators with injected errors, and a
test-side stand-in for the arm (joint angle → pot volts with a wire-wound non-linearity, motor
encoder edges, amplifier current monitor). No plant: the procedures see only drivers, the
Positioner protocol and the fixture, exactly as on the emulated rig.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from emulators.adc import AdcBoard
from emulators.crate import Crate
from emulators.dac import DacBoard
from emulators.encoder_edges import EncoderSampler
from emulators.quadrature import QuadratureBoard
from emulators.rng import rng_for
from hal.adc_dac.calibration import Calibration
from servo.io import JointIO, SensorScaling
from servo.rig import RigSpec, loopback_net, reference_net
from tests.support.bench_rig import POT_SPAN, RIG_TOML, write_rig
from vmehil.calibration.base import CalibrationContext
from vmehil.calibration.store import BoardCal, CalibrationStore, JointCal, rig_boards, utc_now


def pot_volts(theta: float, bow: float, periodic: float, centre: float = 0.0, cycles: float = 3.0) -> float:
    """Wire-wound pot: a bow (fraction of span) and a winding-pitch ripple, across ±10 V."""
    x = min(max((theta - centre) / POT_SPAN + 0.5, 0.0), 1.0)
    f = x + bow * 4 * x * (1 - x) + periodic * math.sin(2 * math.pi * cycles * x)
    return -10.0 + 20.0 * f


@dataclass
class Errors:
    """Injected board and arm errors."""

    adc1_offset_v: float = 0.0
    adc1_gain_error: float = 0.0
    adc_noise_v: float = 0.001
    dac_offset_v: tuple[float, ...] = (0.0,) * 8
    dac_gain_error: tuple[float, ...] = (0.0,) * 8
    pot_bow: tuple[float, ...] = (0.003, 0.0025)
    pot_periodic: tuple[float, ...] = (0.0001, 0.0001)  # the plant's jpl-arm pots (3 cycles over the span)
    pot_cycles: float = 3.0
    pot_centre: tuple[float, ...] = (0.0, 0.8)
    pot_noise_v: float = 0.0015
    amp_gain: tuple[float, ...] = (3.0, 2.0)
    amp_offset_a: tuple[float, ...] = (0.0, 0.0)
    amp_limit_a: tuple[float, ...] = (30.0, 20.0)
    monitor_v_per_a: tuple[float, ...] = (1 / 3, 0.5)
    encoder_sign: tuple[int, ...] = (1, 1)
    encoder_lines: tuple[int, ...] = (500, 500)
    initial_rad: tuple[float, ...] = (0.1, 0.5)


@dataclass
class Bench:
    rig: RigSpec
    crate: Crate
    errors: Errors
    theta: np.ndarray
    samplers: list[EncoderSampler]
    io: JointIO
    period_s: float = 0.008
    ratio: float = 100.0
    speed_rad_s: float = 0.35
    seed: int = 0
    _override: dict[int, float] = field(default_factory=dict)
    ticks: int = 0

    # --- the arm -----------------------------------------------------------------------------
    def _publish(self, currents: np.ndarray, dt: float) -> None:
        e, s = self.errors, self.crate.signals
        rng = self._rng
        for j in self.rig.joints:
            i = j.index
            v = pot_volts(self.theta[i], e.pot_bow[i], e.pot_periodic[i], e.pot_centre[i], e.pot_cycles)
            s.set_analog(j.net("pot"), v + e.pot_noise_v * float(rng.standard_normal()))
            s.set_analog(j.net("imon"), currents[i] * e.monitor_v_per_a[i])
            ev = self.samplers[i].step(e.encoder_sign[i] * self.theta[i] * self.ratio, dt)
            s.publish_quadrature(j.net("encoder"), ev)

    def _tick(self, target: dict[int, float] | None, on_tick) -> None:
        e = self.errors
        self.ticks += 1
        self.crate.advance_to(max(self.crate.clock.now_ns, self.ticks * 8_000_000))
        if target:
            step = self.speed_rad_s * self.period_s
            for i, a in target.items():
                self.theta[i] += max(-step, min(step, a - self.theta[i]))
        # sensors at this tick's sampling instant (the current commanded during the last period)
        self._publish(self._pending, self.period_s)
        if on_tick is not None:
            on_tick()
        # the servo loop would command here; an override replaces it for the coming period
        currents = np.zeros(len(self.theta))
        for i, v in self._override.items():
            currents[i] = max(-e.amp_limit_a[i], min(e.amp_limit_a[i], e.amp_gain[i] * v + e.amp_offset_a[i]))
        self._override = {}
        self._pending = currents

    # --- Positioner protocol -----------------------------------------------------------------
    def move_to(self, targets, *, settle_s=1.0, on_tick=None, speed_rad_s=None):
        saved = self.speed_rad_s
        if speed_rad_s is not None:  # one speed, or one per joint (the slowest, for this stepper)
            self.speed_rad_s = min(speed_rad_s.values()) if isinstance(speed_rad_s, dict) else speed_rad_s
        while any(abs(self.theta[i] - a) > 1e-12 for i, a in targets.items()):
            self._tick(targets, on_tick)
        self.speed_rad_s = saved
        self.hold(settle_s, on_tick=on_tick)

    def hold(self, seconds, *, on_tick=None):
        for _ in range(max(1, round(seconds / self.period_s))):
            self._tick(None, on_tick)

    def override_command(self, joint, volts):
        self._override[joint] = volts

    def position(self, joint):
        return float(self.theta[joint])

    def faulted(self):
        return None

    # --- Fixture protocol ----------------------------------------------------------------------
    def joint_angle(self, joint):
        return float(self.theta[joint])

    def context(self, store: CalibrationStore | None = None, **kw) -> CalibrationContext:
        return CalibrationContext(rig=self.rig, bus=self.crate, store=store or CalibrationStore.empty(self.rig),
                                  auto=True, fixture=self, positioner_factory=lambda st: self._with(st),
                                  say=lambda s: None, **kw)

    def _with(self, store: CalibrationStore) -> Bench:
        self.io.apply_calibration(store)
        return self


def build_bench(folder: Path, errors: Errors | None = None, seed: int = 0, rig_text: str = RIG_TOML) -> Bench:
    e = errors or Errors()
    rig = write_rig(folder, rig_text)
    crate = Crate("bench-rack")
    adc0_wiring = {0: "j1.pot", 1: "j2.pot"}
    adc1_wiring = {0: "j1.imon", 1: "j2.imon"}
    for pin in rig.references:
        adc1_wiring[pin.index] = reference_net(pin)
    dac_wiring = {0: "j1.amp_command", 1: "j2.amp_command"}
    for d, a in rig.loopback.items():
        dac_wiring[d.index] = loopback_net(d)
        adc1_wiring[a.index] = loopback_net(d)
    crate.install(AdcBoard("adc0", wiring=adc0_wiring, noise_rms_v=e.adc_noise_v, seed=seed), base=0x6000, space="A16")
    crate.install(AdcBoard("adc1", wiring=adc1_wiring, noise_rms_v=e.adc_noise_v, seed=seed,
                           offset_v=[e.adc1_offset_v] * 16, gain_error=[e.adc1_gain_error] * 16),
                  base=0x6100, space="A16")
    crate.install(DacBoard("dac0", wiring=dac_wiring, offset_v=e.dac_offset_v, gain_error=e.dac_gain_error),
                  base=0x7000, space="A16")
    crate.install(QuadratureBoard("quad0", nets={0: "j1.encoder", 1: "j2.encoder"}), base=0x5000, space="A16")
    for pin, v in rig.references.items():
        crate.signals.set_analog(reference_net(pin), v)
    theta = np.array(e.initial_rad, float)
    samplers = [EncoderSampler(4 * e.encoder_lines[i], 1e6, index_phase_x4=37,
                               theta0_rad=e.encoder_sign[i] * theta[i] * 100.0) for i in range(2)]
    scaling = [SensorScaling(pot_v_per_rad=20.0 / POT_SPAN, pot_zero_v=20.0 / POT_SPAN * -c,
                             encoder_counts_per_rev=2000.0 * 100, ratio=100.0, amp_gain_a_per_v=g,
                             monitor_v_per_a=m, current_limit_a=lim)
               for c, g, m, lim in zip(e.pot_centre, (3.0, 2.0), (1 / 3, 0.5), (30.0, 20.0), strict=True)]
    io = JointIO(crate, rig, scaling)
    bench = Bench(rig, crate, e, theta, samplers, io, seed=seed)
    bench._rng = rng_for(seed, "bench", "pot")
    bench._pending = np.zeros(2)
    bench._publish(np.zeros(2), 1e-3)
    return bench


def sample_store(rig: RigSpec) -> CalibrationStore:
    """A small valid calibration file's content: adc1's coefficients and j1's pot, encoder and
    amplifier entries (the refusal tests and the calibration-file fuzz harness mutate it)."""
    s = CalibrationStore.empty(rig)
    s.set_board(BoardCal(rig_boards(rig)["adc1"], Calibration((0.01,) * 16, (1.004,) * 16), "adc", 1, utc_now(), ()))
    s.set_joint("j1", JointCal("pot", 1, utc_now(), {"volts": [-9.0, 0.0, 9.0], "angles_rad": [-2.7, 0.0, 2.7]}))
    s.set_joint("j1", JointCal("encoder", 1, utc_now(), {"counts_per_joint_rev": 409600.0}))
    s.set_joint("j1", JointCal("amplifier", 1, utc_now(), {"gain_a_per_v": 3.0, "offset_a": 0.01}))
    return s
