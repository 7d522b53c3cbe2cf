"""The JPL link-1 limit cycle comes out of the plant's physics, and the paper's cure stops it.

A minimal 125 Hz controller is written here (not the project's servo): the normalized JPL law
``a = Kp·e + Kpi·∫e + Kv·ė + KvI·∫ė`` with backward-Euler integrators, ``τ = J·a`` → amplifier
current ``τ/(N·Kt)`` → amplifier volts, held for the period (ZOH). Position: the true joint
angle quantized to a 12-bit pot LSB (1.45 mrad); velocity: the plant's tachometer *voltage*
divided by its gradient. The cycle is produced by the tachometer's brush-contact dead band
(velocity feedback blind below 0.12 rad/s) with Harmonic Drive stiction and the integrators.
Measured on the true angle over 9 s after a 0.2 rad move ends.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from emulators.plant import Plant, PlantParams, load_plant_params
from emulators.plant.friction_metrics import deadband_limit_cycle

T = 0.008
LSB = 1.45e-3
MOVE = 0.2
T_MOVE = 1.0
GAINS = {"Kp": 100.0, "Kpi": 5000.0, "Kv": 50.0, "KvI": 1000.0}


def _joint1(brush_drop_v: float | None = None):
    j1 = load_plant_params("jpl-arm").joints[0]
    if brush_drop_v is not None:
        j1 = replace(j1, tach=replace(j1.tach, brush_drop_v=brush_drop_v))
    return j1


class MiniServo:
    """The JPL normalized law at 125 Hz on one joint of a plant (written for this test)."""

    def __init__(self, plant: Plant) -> None:
        jp = plant.params.joints[0]
        self.plant = plant
        self.J = jp.inertia_at_joint()
        self.N = jp.gear.ratio
        self.Kt = jp.motor.kt_nm_per_a
        self.gain = jp.linear_amp.gain_a_per_v
        self.grad = jp.tach.gradient_v_per_rad_s
        self.Kp, self.Kpi, self.Kv, self.KvI = GAINS["Kp"], GAINS["Kpi"], GAINS["Kv"], GAINS["KvI"]
        self.Ie = 0.0
        self.Iv = 0.0
        self.integrating = True
        self.cmd = plant.idle_command()
        self.cmd.amp_enable[0] = True
        self.theta = float(plant.joint_angle()[0])
        self.tach_v = 0.0
        self.e = 0.0

    def integral_term(self) -> float:
        return self.Kpi * self.Ie + self.KvI * self.Iv

    def tick(self, thd: float, wd: float) -> float:
        pos = round(self.theta / LSB) * LSB
        vel = self.tach_v / self.grad
        self.e = thd - pos
        ed = wd - vel
        if self.integrating:
            self.Ie += T * self.e
            self.Iv += T * ed
        a = self.Kp * self.e + self.Kv * ed + self.integral_term()
        self.cmd.amp_command_v[0] = self.J * a / (self.N * self.Kt) / self.gain
        s = self.plant.step_period(self.cmd, T)
        self.theta = float(s.truth["theta_joint"][0])
        self.tach_v = float(s.tach_v[0])
        return self.theta


def _reference(t: float) -> tuple[float, float]:
    if t >= T_MOVE:
        return MOVE, 0.0
    s = t / T_MOVE
    return MOVE * (10 * s**3 - 15 * s**4 + 6 * s**5), MOVE * (30 * s**2 - 60 * s**3 + 30 * s**4) / T_MOVE


def _run(servo: MiniServo, t_end: float, on_tick=None) -> tuple[np.ndarray, np.ndarray]:
    n = round(t_end / T)
    ts = np.empty(n)
    th = np.empty(n)
    for k in range(n):
        t = k * T
        if on_tick is not None:
            on_tick(t, servo)
        th[k] = servo.tick(*_reference(t))
        ts[k] = t + T
    return ts, th


def _cycle(ts: np.ndarray, th: np.ndarray, t0: float) -> tuple[float, float]:
    """(half peak-to-peak amplitude in degrees, dominant frequency in Hz) after ``t0``."""
    x = th[ts >= t0]
    amp = math.degrees((x.max() - x.min()) / 2.0)
    x = (x - x.mean()) * np.hanning(len(x))
    nfft = 1 << 16
    spec = np.abs(np.fft.rfft(x, nfft))
    f = np.fft.rfftfreq(nfft, T)
    spec[f < 0.2] = 0.0
    return amp, float(f[int(np.argmax(spec))])


def _df_prediction(j):
    return deadband_limit_cycle(
        kp=GAINS["Kp"], kpi=GAINS["Kpi"], kv=GAINS["Kv"], kvi=GAINS["KvI"],
        inertia_kg_m2=j.inertia_at_joint(), ratio=j.gear.ratio,
        viscous_input=j.friction.viscous_nm_s_per_rad, coulomb_input=j.friction.coulomb_nm,
        deadband_rad_s=j.tach.brush_drop_v / j.tach.gradient_v_per_rad_s,
    )


def test_link1_limit_cycles_about_three_quarter_degree_at_1_to_3_hz():
    j = _joint1()
    plant = Plant(PlantParams(joints=[j]), seed=3)
    ts, th = _run(MiniServo(plant), T_MOVE + 10.0)
    amp, freq = _cycle(ts, th, T_MOVE + 1.0)
    df = _df_prediction(j)
    print(
        f"limit cycle: ±{amp:.3f} deg at {freq:.2f} Hz; describing function: "
        f"±{math.degrees(df.amplitude_rad):.3f} deg at {df.frequency_hz:.2f} Hz"
    )
    assert 0.5 <= amp <= 1.0
    assert 1.0 <= freq <= 3.0
    # the mechanism is the one analysed: harmonic balance of the dead band with friction
    assert amp == pytest.approx(math.degrees(df.amplitude_rad), rel=0.1)
    assert freq == pytest.approx(df.frequency_hz, rel=0.1)


def test_without_the_tach_dead_band_only_tiny_hunting_remains():
    """The same loop with an ideal tachometer: friction + integrators + quantization alone."""
    plant = Plant(PlantParams(joints=[_joint1(brush_drop_v=0.0)]), seed=3)
    ts, th = _run(MiniServo(plant), T_MOVE + 10.0)
    amp, _ = _cycle(ts, th, T_MOVE + 1.0)
    print(f"ideal tach: ±{amp:.4f} deg")
    assert amp < 0.1


def _freeze_run(policy):
    """Let the cycle build up, then switch the integrator inputs off (values kept) and
    double Kp when ``policy(servo)`` first allows it after t = 5 s."""
    plant = Plant(PlantParams(joints=[_joint1()]), seed=5)
    servo = MiniServo(plant)
    frozen: dict[str, float] = {}

    def on_tick(t: float, s: MiniServo) -> None:
        if s.integrating and t >= 5.0 and policy(s):
            s.integrating = False
            s.Kp = 2.0 * GAINS["Kp"]
            frozen["t"] = t
            frozen["C"] = s.integral_term()

    ts, th = _run(servo, 11.0, on_tick)
    jp = plant.params.joints[0]
    t_f_max = jp.breakout_at_output_nm() * (1.0 + jp.friction.ripple_fraction)
    return servo, ts, th, frozen, t_f_max, jp.inertia_at_joint()


@pytest.mark.parametrize("policy_name", ["at_once", "integrators_not_pushing"])
def test_integrator_switch_off_with_raised_kp_stops_the_cycle(policy_name):
    policies = {
        "at_once": lambda s: True,
        # freeze where the frozen integral contributes (almost) nothing: the paper's T_F/(J·Kp)
        "integrators_not_pushing": lambda s: abs(s.integral_term()) < 0.3,
    }
    servo, ts, th, frozen, t_f, J = _freeze_run(policies[policy_name])
    assert "t" in frozen
    amp, _ = _cycle(ts, th, frozen["t"] + 2.0)
    e_static = MOVE - th[-1]
    kp_b = servo.Kp
    print(
        f"{policy_name}: frozen at {frozen['t']:.3f} s, C = {frozen['C']:.3f} rad/s², residual "
        f"±{amp:.4f} deg, static error {math.degrees(e_static):.3f} deg, "
        f"T_F/(J·Kp) = {math.degrees(t_f / (J * kp_b)):.3f} deg"
    )
    assert amp < 0.1
    # the joint holds because stiction balances the frozen loop's torque: at rest the
    # commanded torque J·(Kp·e + C) is within the output breakout torque
    assert abs(J * (kp_b * servo.e + frozen["C"])) <= t_f * (1.0 + 1e-9)
    # hence the static error from the frozen integrators' balance point is within T_F/(J·Kp)
    assert abs(e_static + frozen["C"] / kp_b) <= t_f / (J * kp_b) + LSB / 2
    if policy_name == "integrators_not_pushing":
        assert abs(e_static) <= (t_f / J + abs(frozen["C"])) / kp_b + LSB / 2
