"""The layout of the arrays :func:`emulators.plant.numba_kernel.period_kernel` reads and writes:
rows of the parameter matrix ``P``, the flags ``F`` and the outputs ``O``, ``B``, ``E``."""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from emulators.plant.amplifier import FAULT_COMPLIANCE, FAULT_OVERCURRENT, FAULT_THERMAL

# ---- rows of the per-joint parameter matrix P (float64, [N_ROWS, n]) --------------------------
(IS_LIN, GAIN, LIN_LIMIT, HB_DEADTIME, HB_SUPPLY, HB_LIMIT, HB_TRIP, RL, RL_GAIN, EMF_GAIN, RAIL_GAIN,
 LOOP, THERMAL, THERMAL_GAIN, SAT_FAULT_S, KT, N_RATIO, INV_N, COMPLIANT, K_FLEX, C_FLEX, KE_AMP, KE_PHASE,
 J_LINK, G_TORQUE, G_PHASE, LOWER, UPPER, EXT_TORQUE, FR_RIPPLE, FR_PHASE, INV_WS, D_TS, COULOMB, BJH, INV_J,
 BREAKOUT, VISCOUS, T_PRESENT, T_GRADIENT, T_BRUSH, T_RIPPLE, T_CYCLES, T_DECAY, T_OFFSET, T_NOISE,
 ENC_SCALE, ENC_FS, POT_SPAN, POT_CENTER, POT_VLOW, POT_VHIGH, POT_BOW, POT_PERIODIC, POT_CYCLES, POT_NOISE,
 MON_GAIN, MON_OFFSET, MON_NOISE, SW_NOISE, BRAKE_HOLD, CONTACT_K, CONTACT_RAD, N_ROWS) = range(64)

# ---- flags F (int64) -------------------------------------------------------------------------
(F_EXTERNAL, F_COMPLIANT, F_GRAVITY, F_KE, F_TACH, F_TACH_RIPPLE, F_DIRECT, F_BRAKE, F_LAYOUT, F_CONTACT,
 N_FLAGS) = range(11)

# ---- rows of the float output O ([O_ROWS, n]) and of the bool output B ([B_ROWS, n]) ----------
(O_POT, O_TACH, O_IMON, O_SW_NOISE, O_THETA_J, O_OMEGA_J, O_THETA_M, O_OMEGA_M, O_CURRENT, O_TORQUE,
 O_FRICTION, O_THERMAL, O_X4, O_ROWS) = range(14)
B_SWITCHING, B_STUCK, B_AT_STOP, B_FAULT, B_ROWS = range(5)

# ---- encoder output E (int64, [E_ROWS, n]) ---------------------------------------------------
E_COUNTS, E_ILLEGAL, E_PHASE, E_NIDX, E_ROWS = range(5)


def _layout_id() -> int:
    """A fingerprint of this layout (and the fault bits the kernel sets). Numba's cache is keyed on
    the kernel's own source file only, so the kernel compares the fingerprint it was compiled with
    to the one passed in ``F[F_LAYOUT]`` and refuses to run stale machine code."""
    names = sorted(k for k, v in globals().items() if k.isupper() and isinstance(v, int))
    text = ",".join(f"{k}={globals()[k]}" for k in names)
    text += f";{FAULT_THERMAL},{FAULT_COMPLIANCE},{FAULT_OVERCURRENT}"
    return zlib.crc32(text.encode())


LAYOUT_ID = _layout_id()


def kernel_inputs(prev: Any, cmd: Any, noise: Mapping[str, Any], n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernel's command and noise inputs for ``n`` joints: ``cmd_f`` [2, 2, n] (the previous and
    this period's amplifier command volts and PWM duty), ``cmd_b`` [2, 2, n] (their PWM direction and
    brake) and this period's draws of the ``pot``, ``tach`` and ``imon`` noise streams [3, n]."""
    cmd_f = np.empty((2, 2, n))
    cmd_f[0, 0] = prev.amp_command_v
    cmd_f[0, 1] = prev.pwm_duty
    cmd_f[1, 0] = cmd.amp_command_v
    cmd_f[1, 1] = cmd.pwm_duty
    cmd_b = np.empty((2, 2, n), dtype=bool)
    cmd_b[0, 0] = prev.pwm_direction
    cmd_b[0, 1] = prev.brake
    cmd_b[1, 0] = cmd.pwm_direction
    cmd_b[1, 1] = cmd.brake
    draws = np.empty((3, n))
    draws[0] = noise["pot"].draw()
    draws[1] = noise["tach"].draw()
    draws[2] = noise["imon"].draw()
    return cmd_f, cmd_b, draws


def kernel_sensors(sensors_type: Any, O: np.ndarray, B: np.ndarray, events: Any, time_s: float, n: int,
                   enabled: np.ndarray, amp_cause: np.ndarray, watchdog: Any, brake_engaged: np.ndarray) -> Any:
    """The sensors (``sensors_type``: the plant's PlantSensors) of a period from the kernel's outputs
    ``O``/``B`` for ``n`` joints: the sensor volts, fault lines, encoder ``events`` and switching, and
    the truth the reports read (``enabled``: the enables the amplifiers obeyed, before their faults)."""
    fault = B[B_FAULT]
    truth = {
        "time_s": np.full(n, time_s),
        "theta_joint": O[O_THETA_J],
        "omega_joint": O[O_OMEGA_J],
        "theta_motor": O[O_THETA_M],
        "omega_motor": O[O_OMEGA_M],
        "current_a": O[O_CURRENT],
        "motor_torque_nm": O[O_TORQUE],
        "friction_torque_nm": O[O_FRICTION],
        "stuck": B[B_STUCK],
        "at_stop": B[B_AT_STOP].copy(),
        "amp_thermal": O[O_THERMAL],
        "amp_fault_cause": amp_cause.copy(),
        "amp_enabled": enabled & ~fault,
        "amp_watchdog_cause": watchdog.cause.copy(),
        "amp_watchdog_tripped": watchdog.latched,
        "encoder_x4": O[O_X4],
        "brake_engaged": brake_engaged.copy(),
    }
    return sensors_type(
        pot_v=O[O_POT],
        tach_v=O[O_TACH],
        imon_v=O[O_IMON],
        amp_fault=fault,
        encoder=events,
        switching=B[B_SWITCHING],
        switching_noise_v=O[O_SW_NOISE],
        truth=truth,
    )
