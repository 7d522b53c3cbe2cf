"""Joint-state telemetry: which messages carry what.

Default (``array``): one ``DEBUG_FLOAT_ARRAY`` per joint per sample, ``name`` = ``J<n>`` (1-based),
``array_id`` = joint index (0-based), ``time_usec`` = loop time (tick · period) in µs, and
``data[i]`` = :data:`FIELDS` [i] (SI units; the rest of the 58 floats are 0). All joints of one
sample come from the same tick.

Alternative (``named``): one ``NAMED_VALUE_FLOAT`` per joint and field, ``name`` =
``J<n>_<SHORT>`` (≤ 10 characters, e.g. ``J1_ERR``), ``time_boot_ms`` = loop time in ms. Plotted
directly by QGroundControl's MAVLink inspector and MAVProxy's ``graph`` module; 12 messages per
joint per sample, so keep the rate low with many joints.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

# (field, short name for NAMED_VALUE_FLOAT, unit, meaning)
FIELDS: tuple[tuple[str, str, str, str], ...] = (
    ("theta_d", "TGT", "rad", "target position (trajectory)"),
    ("theta", "POS", "rad", "measured position"),
    ("error", "ERR", "rad", "position error theta_d - theta"),
    ("omega_d", "VTGT", "rad/s", "target velocity"),
    ("omega", "VEL", "rad/s", "measured velocity"),
    ("torque", "TAU", "N·m", "commanded torque at the joint (after limits)"),
    ("current", "CUR", "A", "measured motor current (amplifier monitor)"),
    ("integrating", "INTEG", "0/1", "switch-off state: 1 integrators fed, 0 switched off"),
    ("kp_eff", "KPEFF", "1/s²", "position gain in force (boosted while switched off)"),
    ("ie", "IE", "rad·s", "position integrator state ∫e dt"),
    ("iv", "IV", "rad", "velocity integrator state ∫ė dt"),
    ("fault", "FAULT", "0/1", "1 once the loop has stopped on a fault (all joints)"),
)
FIELD_NAMES = tuple(f[0] for f in FIELDS)


def joint_rows(loop: Any) -> tuple[int, np.ndarray]:
    """(time in µs, array joints × len(FIELDS)) from the loop's last-tick snapshot and law state.
    NaN where a value is not available (e.g. no measurement after a fault)."""
    n = int(loop.n)
    last = loop.last or {}
    nan = np.full(n, np.nan)

    def get(name: str) -> np.ndarray:
        v = last.get(name)
        if callable(v):  # tolerate a method stored instead of its value
            v = v()
        return nan if v is None else np.broadcast_to(np.asarray(v, float), (n,))

    law = loop.law
    ie = np.asarray(law.state.ie, float) if law is not None else nan
    iv = np.asarray(law.state.iv, float) if law is not None else nan
    theta_d, theta = get("theta_d"), get("theta")
    cols = {
        "theta_d": theta_d, "theta": theta, "error": theta_d - theta, "omega_d": get("omega_d"),
        "omega": get("omega"), "torque": get("torque"), "current": get("current"),
        "integrating": get("integrating"), "kp_eff": get("kp_eff"), "ie": ie, "iv": iv,
        "fault": np.full(n, 1.0 if loop.fault is not None else 0.0),
    }
    tick = int(last.get("tick", max(int(loop.tick_count) - 1, 0)))
    t_us = round(tick * float(loop.period_s) * 1e6)
    return t_us, np.column_stack([cols[f] for f in FIELD_NAMES])


def array_messages(mav: Any, loop: Any) -> list[Any]:
    """DEBUG_FLOAT_ARRAY messages (one per joint) for the last tick."""
    t_us, rows = joint_rows(loop)
    out = []
    for j, row in enumerate(rows):
        data = [float(x) for x in row] + [0.0] * (58 - len(row))
        out.append(mav.debug_float_array_encode(t_us, f"J{j + 1}".encode(), j, data))
    return out


def named_messages(mav: Any, loop: Any) -> list[Any]:
    """NAMED_VALUE_FLOAT messages (one per joint and field) for the last tick."""
    t_us, rows = joint_rows(loop)
    t_ms = (t_us // 1000) & 0xFFFFFFFF
    out = []
    for j, row in enumerate(rows):
        for (_, short, _, _), x in zip(FIELDS, row, strict=True):
            name = f"J{j + 1}_{short}"[:10]
            out.append(mav.named_value_float_encode(t_ms, name.encode(), float(x) if math.isfinite(x) else math.nan))
    return out
