"""The compiled period kernel (emulators/plant/numba_kernel.py) against the numpy path and its own
Python source; the kernel choice; compile once, never again inside a loop."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from emulators.plant import Plant, PlantCommand, PlantParams, encoder_events, load_plant_params, numba_kernel
from emulators.plant import kernel as kernel_mod

T = 0.008
#: per-period agreement of the two paths: the same expressions, libm vs numpy SIMD exp/sin/cos and
#: one form of the linear amplifier's update differ by round-off only (measured ≤ 1e-13 over 300
#: periods of jpl-arm); over long runs stick/slip decisions at round-off distance may diverge
RTOL = 1e-9
ATOL = 1e-9


def _drive(p: Plant, k: int) -> PlantCommand:
    """A busy command: sine commands, enable toggles, H-bridge duty/direction/brake, fault resets."""
    t = k * T
    n = p.n_joints
    c = p.idle_command()
    c.amp_enable[:] = (k // 40) % 4 != 3
    c.amp_command_v[:] = 3.0 * np.sin(2 * math.pi * 0.7 * t + np.arange(n))
    c.pwm_duty[:] = 0.6 * abs(math.sin(2 * math.pi * 0.4 * t))
    c.pwm_direction[:] = math.sin(2 * math.pi * 0.4 * t) > 0
    c.brake[:] = (k // 25) % 5 == 4
    c.fault_reset[:] = k % 50 == 0
    c.watchdog_line = bool(k % 2)
    return c


def _compliant_params() -> PlantParams:
    js = load_plant_params("jpl-arm").joints
    flex = replace(js[1], name="flex", gear=replace(js[1].gear, compliant=True, kinematic_error_rad=3e-4),
                   link=replace(js[1].link, gravity_torque_nm=40.0, lower_stop_rad=-0.05, upper_stop_rad=0.05))
    stop = replace(js[0], name="stop", link=replace(js[0].link, lower_stop_rad=-0.02, upper_stop_rad=0.02))
    return PlantParams(joints=[flex, stop, js[6]])


def _assert_sensors_close(a, b, k: int) -> None:
    for name in ("pot_v", "tach_v", "imon_v", "switching_noise_v"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=RTOL, atol=ATOL, err_msg=f"{name} @{k}")
    np.testing.assert_array_equal(a.amp_fault, b.amp_fault, err_msg=f"amp_fault @{k}")
    np.testing.assert_array_equal(a.switching, b.switching, err_msg=f"switching @{k}")
    assert a.encoder == b.encoder, k
    assert a.truth.keys() == b.truth.keys()
    for name, va in a.truth.items():
        vb = b.truth[name]
        assert np.asarray(va).dtype == np.asarray(vb).dtype, name
        if np.asarray(va).dtype == np.float64:
            np.testing.assert_allclose(va, vb, rtol=RTOL, atol=ATOL, err_msg=f"{name} @{k}")
        else:
            np.testing.assert_array_equal(va, vb, err_msg=f"{name} @{k}")


@pytest.mark.parametrize("params", ["jpl-arm", "melmalec-16", "compliant"])
def test_compiled_and_numpy_paths_agree_to_round_off(params: str) -> None:
    pp = _compliant_params() if params == "compliant" else load_plant_params(params)
    a = Plant(pp, seed=5, kernel="numpy")
    b = Plant(pp, seed=5, kernel="numba")
    assert (a.kernel, b.kernel) == ("numpy", "numba")
    for k in range(160):
        if k == 30:
            for p in (a, b):
                p.set_external_torque(np.full(p.n_joints, 2.0))
        c = _drive(a, k)
        _assert_sensors_close(a.step_period(c, T, 0.002), b.step_period(c, T, 0.002), k)


def test_faults_and_the_watchdog_behave_the_same_on_both_paths() -> None:
    pp = replace(load_plant_params("jpl-arm"), watchdog_timeout_s=0.02)
    a = Plant(pp, seed=1, kernel="numpy")
    b = Plant(pp, seed=1, kernel="numba")
    c = a.idle_command()
    c.amp_enable[:] = True
    c.amp_command_v[:] = 1.0
    c.pwm_duty[:] = 0.5
    tripped = False
    for k in range(60):
        c.watchdog_line = bool(k % 2) if k < 30 else True  # the pump stops at k = 30
        if k == 5:
            for p in (a, b):
                p.inject("pot_open", joint=p.names[0])
                p.inject("tach_stuck", joint=p.names[1], volts=3.0)
                p.inject("amp_fault", joint=p.names[2])
        if k == 15:
            for p in (a, b):
                p.clear_fault("amp_fault")
        c.fault_reset[:] = k == 16
        sa, sb = a.step_period(c, T, 0.003), b.step_period(c, T, 0.003)
        _assert_sensors_close(sa, sb, k)
        tripped |= bool(sb.truth["amp_watchdog_tripped"].any())
    assert tripped  # the watchdog ran out in the period it was due, on both paths
    assert b.watchdog.trips == a.watchdog.trips > 0


def test_the_compiled_kernel_is_bit_identical_to_its_python_source() -> None:
    """No fast-math: the machine code computes exactly what the Python source says."""
    pp = _compliant_params()
    a = Plant(pp, seed=3, kernel="numba")
    b = Plant(pp, seed=3, kernel="numba")
    b._kernel_fn = numba_kernel.period_kernel.py_func
    for k in range(40):
        c = _drive(a, k)
        sa, sb = a.step_period(c, T, 0.002), b.step_period(c, T, 0.002)
        for name in sa.truth:
            np.testing.assert_array_equal(sa.truth[name], sb.truth[name], err_msg=f"{name} @{k}")
        np.testing.assert_array_equal(sa.pot_v, sb.pot_v)
        assert sa.encoder == sb.encoder


@pytest.mark.parametrize("speed_x4_per_period", [3.0, 900.0, 4.0e4, -5.0e4])
def test_the_kernels_encoder_events_equal_encoder_events(speed_x4_per_period: float) -> None:
    rng = np.random.default_rng(7)
    steps, n = 32, 5
    x = 1234.3 + np.cumsum(np.vstack([np.zeros(n), rng.uniform(0.2, 1.8, (steps, n))]), axis=0)
    x = (x - x[0]) * speed_x4_per_period / steps + x[0]
    fs = np.array([1e6, 2e5, 5e4, 1e6, 3e6])
    per = np.array([4000, 2048, 4000, 64, 40000], dtype=np.int64)
    ph = np.array([0, 17, 3999, 5, 123], dtype=np.int64)
    want = encoder_events(x, T / steps, fs, per, ph)
    E = np.zeros((4, n), dtype=np.int64)
    idx = np.zeros((n, 2 * steps + round(T * fs.max()) + 4), dtype=np.int64)
    for j in range(n):
        numba_kernel._encoder(np.ascontiguousarray(x[:, j]), steps, T / steps, fs[j], per[j], ph[j], j, E, idx)
        got = (int(E[0, j]), int(E[1, j]), tuple(idx[j, : E[3, j]].tolist()), int(E[2, j]))
        assert got == (want[j].counts, want[j].illegal, want[j].index_offsets, want[j].phase), j


def test_the_kernel_choice_follows_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    pp = load_plant_params("jpl-arm")
    monkeypatch.setenv(kernel_mod.ENV, "numpy")
    assert Plant(pp).kernel == "numpy"
    assert Plant(pp, kernel="numba").kernel == "numba"  # an explicit choice wins
    monkeypatch.setenv(kernel_mod.ENV, "numba")
    assert Plant(pp).kernel == "numba"
    monkeypatch.setenv(kernel_mod.ENV, "fortran")
    with pytest.raises(ValueError, match="VMEHIL_PLANT_KERNEL"):
        Plant(pp)


def test_the_kernel_is_compiled_once_and_can_never_compile_again() -> None:
    p = Plant(load_plant_params("jpl-arm"), kernel="numba")
    disp = numba_kernel.period_kernel
    assert kernel_mod.report() is not None and "plant kernel" in kernel_mod.report()
    # odd inputs (lists, ints, other periods and delays) still reach the one compiled signature
    c = p.idle_command()
    c.amp_enable = [True] * p.n_joints  # type: ignore[assignment]
    c.amp_command_v = [1] * p.n_joints  # type: ignore[assignment]
    for period, delay in ((T, 0.0), (0.004, 0.001), (1 / p.rate_hz, 0.0), (T, T)):
        p.step_period(c, period, delay)
    p.omega_m = np.arange(p.n_joints)  # an int array set from outside is copied into the state
    p.step_period(c, T)
    assert len(disp.signatures) == 1
    with pytest.raises(TypeError):  # other types are refused, not compiled
        disp(*([np.zeros(1, dtype=np.float32)] * 23))


def test_stale_cached_machine_code_is_refused() -> None:
    """Numba's cache is keyed on the kernel's source file only: a layout change in kernel_layout.py
    must not run old machine code with new row numbers."""
    from emulators.plant import kernel_layout

    p = Plant(load_plant_params("jpl-arm"), kernel="numba")
    p.step_period(p.idle_command(), T)
    consts = p._step_consts(T / round(T * p.rate_hz))
    consts.F[kernel_layout.F_LAYOUT] = kernel_layout.LAYOUT_ID + 1  # as if the layout had changed
    with pytest.raises(RuntimeError, match="stale"):
        p.step_period(p.idle_command(), T)


@pytest.mark.slow
def test_a_compile_is_reported_once_and_the_next_process_loads_it_from_the_disk_cache(tmp_path) -> None:
    import os
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    code = "from emulators.plant import kernel; print(kernel.warm_up())"
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr
    compiled = [line for line in first.stderr.splitlines() if line.startswith("plant kernel:")]
    assert len(compiled) == 1 and "compiled by numba" in compiled[0] and " s, cached on disk in " in compiled[0]
    assert any((tmp_path / "cache").rglob("*.nbi"))
    second = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert second.returncode == 0, second.stderr
    assert "plant kernel" not in second.stderr  # nothing compiled, nothing said
    assert "loaded from its on-disk cache" in second.stdout


def test_a_joint_at_rest_calls_sin_cos_exp_a_few_times_a_period_not_per_substep(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The kernel's memos (equal argument: the value computed for it before): jpl-arm idle, every
    joint stuck, runs the Python source with counting sin/cos/exp, and its numbers are the
    compiled kernel's (which the numpy path checks to round-off above) bit for bit."""
    calls = {"sin": 0, "cos": 0, "exp": 0}

    class CountingMath:
        def __getattr__(self, name: str):
            f = getattr(math, name)
            if name not in calls:
                return f

            def counted(x: float) -> float:
                calls[name] += 1
                return f(x)  # type: ignore[no-any-return]
            return counted

    pp = load_plant_params("jpl-arm")
    a = Plant(pp, seed=5, kernel="numba")
    b = Plant(pp, seed=5, kernel="numba")
    b._kernel_fn = numba_kernel.period_kernel.py_func
    monkeypatch.setattr(numba_kernel, "math", CountingMath())
    n_periods = 5
    for _ in range(n_periods):
        c = a.idle_command()
        sa, sb = a.step_period(c, T, 0.002), b.step_period(c, T, 0.002)
        for name in sa.truth:
            np.testing.assert_array_equal(sa.truth[name], sb.truth[name], err_msg=name)
        np.testing.assert_array_equal(sa.pot_v, sb.pot_v)
        np.testing.assert_array_equal(sa.tach_v, sb.tach_v)
    assert bool(np.all(sb.truth["stuck"]))
    n_sub = round(T * b.rate_hz)  # 32 substeps a period at 4 kHz
    per_joint_period = sum(calls.values()) / (n_periods * b.n_joints)
    # without the memos: ≥ 3 calls (friction ripple, Stribeck exp, exp(-x)) per substep
    assert n_sub >= 8 and per_joint_period < 3 * n_sub / 4
