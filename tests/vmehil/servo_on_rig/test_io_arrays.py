"""JointIO converts all joints as arrays (wiring resolved once, scalings kept as arrays): the
readings, the commands and so the whole run are the same, bit for bit, as converting joint by
joint through the hal helpers — also after a pot table, a tach gradient or an amplifier gain
changes in the middle of a run."""

from __future__ import annotations

import numpy as np
import pytest

from hal.adc_dac.conversions import DAC_V_MAX, DAC_V_MIN
from hal.amplifiers import clamp_current, command_volts, duty_for_current
from servo.io import JointIO, Measurement, PotCalibration, SensorScaling
from servo.runner import LockstepRunner
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig


def _reference_read(io: JointIO) -> Measurement:
    """Joint by joint, as JointIO.read did before it worked on arrays."""
    n = io.n
    nan = np.full(n, np.nan)
    m = Measurement(nan.copy(), nan.copy(), nan.copy(), nan.copy(), nan.copy(), nan.copy(), np.zeros(n, bool))
    volts = {name: drv.scan(io._adc_last[name]) for name, drv in io.adc.items()}
    readings = {name: drv.update(io.period_s) for name, drv in io.quad.items()}
    for j in io.rig.joints:
        i, s, w = j.index, io.scaling[j.index], j.wiring
        if "pot" in w:
            v = float(volts[w["pot"].board][w["pot"].index])
            m.pot_v[i] = v
            m.theta_pot[i] = io.pot_angle(i, v)
        if "tach" in w and s.tach_v_per_rad_s:
            m.omega_tach[i] = float(volts[w["tach"].board][w["tach"].index]) / s.tach_v_per_rad_s
        if "imon" in w:
            m.current[i] = float(volts[w["imon"].board][w["imon"].index]) / s.monitor_v_per_a
        if "encoder" in w:
            r = readings[w["encoder"].board][w["encoder"].index]
            m.theta_enc[i] = r.position_rad
            m.omega_enc[i] = r.velocity_rad_s
    ports: dict[tuple[str, int], int] = {}
    for i, board, port, bit in io._fault_lines:
        value = ports.get((board, port))
        if value is None:
            value = ports[(board, port)] = io.pio[board].read_port(port)
        m.fault[i] = bool(value >> bit & 1)
    m.theta = np.where(io._position_from_pot, m.theta_pot, m.theta_enc)
    m.omega = np.where(io._velocity_from_tach, m.omega_tach, m.omega_enc)
    return m


def _reference_write_torque(io: JointIO, torque_nm: np.ndarray, omega: np.ndarray | None = None) -> np.ndarray:
    """Joint by joint, as JointIO.write_torque did before it worked on arrays."""
    current = np.zeros(io.n)
    per_dac: dict[str, dict[int, float]] = {}
    for j in io.rig.joints:
        i, s = j.index, io.scaling[j.index]
        amps = clamp_current(float(torque_nm[i]) / (s.ratio * s.kt_nm_per_a), s.current_limit_a)  # i = τ/(N·Kt)
        if j.amplifier == "linear":
            volts = min(DAC_V_MAX, max(DAC_V_MIN, command_volts(amps, s.amp_gain_a_per_v, s.amp_offset_a)))
            pin = j.wiring["amp_command"]
            per_dac.setdefault(pin.board, {})[pin.index] = volts
            io.last_dac_volts[i] = volts
            current[i] = volts * s.amp_gain_a_per_v + s.amp_offset_a
        else:
            w_m = 0.0 if omega is None or not np.isfinite(omega[i]) else float(omega[i]) * s.ratio
            io._set_hbridge(j, duty_for_current(amps, s.resistance_ohm, s.ke_v_s_per_rad, w_m, s.supply_v))
            current[i] = amps
    for board, cmds in per_dac.items():
        io.dac[board].write_many(cmds, update=True)
    io.last_current_a[:] = current
    if io._release_pending:
        io.release_brakes()
    if io.watchdog_running:
        io._toggle_watchdog()
    return current


def _run(rig: str, reference: bool, ticks: int = 160):
    system = build_emulated_rig(rig, seed=3)
    loop = build_loop(system, n_ticks=ticks)
    io = system.io
    if reference:
        io.read = lambda: _reference_read(io)  # type: ignore[method-assign]
        io.write_torque = lambda t, w=None: _reference_write_torque(io, t, w)  # type: ignore[method-assign]
    loop.start()
    runner = LockstepRunner(system, loop)
    for k in range(ticks):
        if k == 40:  # a calibrated pot table on joint 1: a slight bow around the nominal line
            s = io.scaling[0]
            v = np.linspace(-9.0, 9.0, 9)
            io.set_pot_calibration(0, PotCalibration(list(v), list((v - s.pot_zero_v) / s.pot_v_per_rad
                                                                   * (1.0 + 1e-4 * np.cos(v)))))
        if k == 70:  # scalings changed in place, as a calibration procedure does
            io.scaling[1].tach_v_per_rad_s *= 1.0005
            io.scaling[2].amp_gain_a_per_v *= 1.0002
        if k == 100:  # a tach with a zero gradient is not read (NaN), the joint keeps its encoder
            io.set_sources(1, "pot", "encoder")
            io.scaling[1].tach_v_per_rad_s = 0.0
        runner.tick()
    data = {k: v.copy() for k, v in loop.recorder.trimmed().items() if k != "compute_s"}
    out = (data, [repr(e) for e in loop.law.events], repr(loop.fault), io.last_dac_volts.copy())
    system.close()
    return out


@pytest.mark.parametrize("rig", ["jpl-arm", "melmalec-16"])
def test_array_conversions_give_the_joint_by_joint_run_bit_for_bit(rig: str) -> None:
    fast, ref = _run(rig, reference=False), _run(rig, reference=True)
    assert fast[2] == ref[2] == "None"  # no stop: the changes above are small
    assert fast[1] == ref[1]
    assert fast[3].tobytes() == ref[3].tobytes()
    for name, arr in ref[0].items():
        assert fast[0][name].tobytes() == arr.tobytes(), name
    assert np.isnan(fast[0]["omega_tach"][-1, 1])  # the zero-gradient tach really went unread


def test_a_scaling_changed_in_place_is_used_at_the_next_read() -> None:
    system = build_emulated_rig("jpl-arm", seed=0)
    io = system.io
    before = io.read()
    io.scaling[0].pot_v_per_rad *= 2.0
    after = io.read()
    # the pot volts are the same (nothing moves: amplifiers off), the angle halves
    assert after.pot_v[0] == before.pot_v[0]
    assert after.theta_pot[0] == pytest.approx(before.theta_pot[0] / 2.0, rel=1e-12, abs=1e-15)
    io.scaling[0] = SensorScaling(**{**io.scaling[0].__dict__, "pot_v_per_rad": 1.0})  # a new object
    assert io.read().theta_pot[0] == pytest.approx(after.pot_v[0] - io.scaling[0].pot_zero_v)
    system.close()


def test_write_torque_is_the_one_conversion_of_torque_to_amps_and_dac_volts() -> None:
    """jpl-arm joint 1, nominal scaling ([joint.servo.nominal]: N = 100, Kt = 0.028 N·m/A, 3 A/V):
    5.6 N·m → i = 5.6/(100 · 0.028) = 2 A → 2/3 V on the DAC; 100 N·m → 35.7 A, clamped to the
    30 A limit → 10 V, which the ±10 V 12-bit DAC tops at 10 − 20/4096 V = 9.9951171875 V, so
    29.9853515625 A commanded."""
    system = build_emulated_rig("jpl-arm")
    try:
        io = system.io
        tau = np.zeros(io.n)
        tau[0] = 5.6
        assert io.write_torque(tau)[0] == pytest.approx(2.0)
        assert io.last_dac_volts[0] == pytest.approx(2.0 / 3.0)
        tau[0] = 100.0
        assert io.write_torque(tau)[0] == pytest.approx(29.9853515625)
        assert io.last_dac_volts[0] == pytest.approx(9.9951171875)
        io.write_torque(np.zeros(io.n))
    finally:
        system.close()
