"""The compiled period kernel (numba; see :mod:`emulators.plant.kernel`). Importing this module
loads the machine code from numba's on-disk cache, or compiles it (and caches it) when the cache
is missing or stale: import it through :func:`emulators.plant.kernel.warm_up`."""

from __future__ import annotations

import math

import numba
import numpy as np

from emulators.plant.amplifier import FAULT_COMPLIANCE, FAULT_OVERCURRENT, FAULT_THERMAL
from emulators.plant.kernel_layout import (
    B_AT_STOP,
    B_FAULT,
    B_STUCK,
    B_SWITCHING,
    BJH,
    BRAKE_HOLD,
    BREAKOUT,
    C_FLEX,
    COMPLIANT,
    CONTACT_K,
    CONTACT_RAD,
    COULOMB,
    D_TS,
    E_COUNTS,
    E_ILLEGAL,
    E_NIDX,
    E_PHASE,
    EMF_GAIN,
    ENC_FS,
    ENC_SCALE,
    EXT_TORQUE,
    F_BRAKE,
    F_COMPLIANT,
    F_CONTACT,
    F_DIRECT,
    F_EXTERNAL,
    F_GRAVITY,
    F_KE,
    F_LAYOUT,
    F_TACH,
    F_TACH_RIPPLE,
    FR_PHASE,
    FR_RIPPLE,
    G_PHASE,
    G_TORQUE,
    GAIN,
    HB_DEADTIME,
    HB_LIMIT,
    HB_SUPPLY,
    HB_TRIP,
    INV_J,
    INV_N,
    INV_WS,
    IS_LIN,
    J_LINK,
    K_FLEX,
    KE_AMP,
    KE_PHASE,
    KT,
    LAYOUT_ID,
    LIN_LIMIT,
    LOOP,
    LOWER,
    MON_GAIN,
    MON_NOISE,
    MON_OFFSET,
    N_RATIO,
    O_CURRENT,
    O_FRICTION,
    O_IMON,
    O_OMEGA_J,
    O_OMEGA_M,
    O_POT,
    O_SW_NOISE,
    O_TACH,
    O_THERMAL,
    O_THETA_J,
    O_THETA_M,
    O_TORQUE,
    O_X4,
    POT_BOW,
    POT_CENTER,
    POT_CYCLES,
    POT_NOISE,
    POT_PERIODIC,
    POT_SPAN,
    POT_VHIGH,
    POT_VLOW,
    RAIL_GAIN,
    RL,
    RL_GAIN,
    SAT_FAULT_S,
    SW_NOISE,
    T_BRUSH,
    T_CYCLES,
    T_DECAY,
    T_GRADIENT,
    T_NOISE,
    T_OFFSET,
    T_PRESENT,
    T_RIPPLE,
    THERMAL,
    THERMAL_GAIN,
    UPPER,
    VISCOUS,
)

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


SIGNATURE = (
    "void(float64[:, ::1], int64[:, ::1], int64[::1], float64, int64, int64, float64[:, :, ::1], "
    "boolean[:, :, ::1], int64[::1], int64[::1], boolean[:, ::1], boolean[::1], float64[:, ::1], boolean[::1], "
    "int64[::1], boolean[::1], float64[:, ::1], float64[:, ::1], float64[::1], float64[:, ::1], boolean[:, ::1], "
    "int64[:, ::1], int64[:, ::1], boolean[::1], int64[:, ::1])"
)



@_jit
def _sign(x: float) -> float:
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0


@_jit
def _same(a: float, b: float) -> bool:
    """``a`` and ``b`` are the same number, zeros' signs included (NaN is never the same)."""
    return a == b and (a != 0.0 or math.copysign(1.0, a) == math.copysign(1.0, b))


@_jit
def _phi1(x: float) -> float:
    if x < 1e-8:
        return 1.0 - 0.5 * x
    return -math.expm1(-x) / x


@_jit
def _phi2(x: float) -> float:
    if x < 1e-3:
        return 0.5 - x / 6.0 + x * x / 24.0
    return (x + math.expm1(-x)) / (x * x)


@_jit
def _log1p_over(y: float) -> float:
    if y < 1e-8:
        return 1.0 - 0.5 * y
    return math.log1p(y) / y


@_jit
def _encoder(x: np.ndarray, steps: int, dt: float, fs: float, per: int, ph: int, j: int,
             enc: np.ndarray, idx: np.ndarray) -> None:
    """:func:`emulators.plant.encoder.encoder_events` for one joint (same definition, same
    arithmetic), into ``enc[:, j]`` and ``idx[j, :enc[E_NIDX, j]]``."""
    cap = idx.shape[1]
    f0 = math.floor(x[0])
    speed = 0.0
    for k in range(steps):
        d = abs(x[k + 1] - x[k])
        if d > speed:
            speed = d
    if steps > 0:
        speed = speed / dt
    nidx = 0
    if speed < fs:
        prev = f0
        for k in range(steps):
            cur = math.floor(x[k + 1])
            if (prev - ph) // per != (cur - ph) // per:
                lo, hi = prev, cur
                if hi > lo:
                    p = lo + 1 + ((ph - (lo + 1)) % per)
                    while p <= hi:
                        if nidx < cap:
                            idx[j, nidx] = p - f0
                        nidx += 1
                        p += per
                else:
                    p = lo - ((lo - ph) % per)
                    while p > hi:
                        if nidx < cap:
                            idx[j, nidx] = p - f0
                        nidx += 1
                        p -= per
            prev = cur
        enc[E_COUNTS, j] = prev - f0
        enc[E_ILLEGAL, j] = 0
        enc[E_PHASE, j] = prev % 4
        enc[E_NIDX, j] = nidx
        return
    m = max(round(steps * dt * fs), 1)
    ratio = steps / m
    prev = f0
    decoded = 0
    illegal = 0
    for k in range(1, m + 1):
        t = k * ratio
        if t >= steps:
            xs = x[steps]
        else:
            i0 = math.floor(t)
            if t == i0:
                xs = x[i0]
            else:
                xs = (x[i0 + 1] - x[i0]) * (t - i0) + x[i0]
        cur = math.floor(xs)
        d = (cur - prev) % 4
        if d == 1:
            decoded += 1
        elif d == 3:
            decoded -= 1
        elif d == 2:
            illegal += 1
        if (prev - ph) // per != (cur - ph) // per:
            if nidx < cap:
                idx[j, nidx] = decoded
            nidx += 1
        prev = cur
    enc[E_COUNTS, j] = decoded
    enc[E_ILLEGAL, j] = illegal
    enc[E_PHASE, j] = prev % 4
    enc[E_NIDX, j] = nidx


@numba.njit(SIGNATURE, cache=True, nogil=True, error_model="numpy")
def period_kernel(
    P: np.ndarray, ENCI: np.ndarray, F: np.ndarray, h: float, n_sub: int, n_old: int,
    cmd_f: np.ndarray, cmd_b: np.ndarray, seg_start: np.ndarray, seg_cmd: np.ndarray, seg_enable: np.ndarray,
    reset_edge: np.ndarray, X: np.ndarray, fault: np.ndarray, cause: np.ndarray, saturated: np.ndarray,
    noise: np.ndarray, held: np.ndarray, x4: np.ndarray, O: np.ndarray, B: np.ndarray, E: np.ndarray,
    idx: np.ndarray, brake_on: np.ndarray, flips: np.ndarray,
) -> None:
    """One servo period of every joint (state in place; see the module docstring).

    Args:
        P: per-joint parameters and step constants (rows ``IS_LIN`` ... ``SW_NOISE``).
        ENCI: ``[2, n]`` int64: encoder x4 counts per index pulse, index phase.
        F: flags (``F_*``).
        h, n_sub, n_old: substep (s), substeps in the period, substeps the previous command holds.
        cmd_f: ``[2, 2, n]``: per command (0 previous, 1 new) the amplifier command (V) and PWM duty.
        cmd_b: ``[2, 2, n]`` bool: per command the PWM direction and brake lines.
        seg_start, seg_cmd, seg_enable: the segments (first substep, command index, the enables
            the output stages obey: enable lines less watchdog latches).
        reset_edge: rising edges of the fault-reset line (cleared at substep ``n_old``).
        X: ``[8, n]`` state: θm, ωm, θl, ωl, i, tach filter, thermal, saturation time.
        fault, cause, saturated: amplifier latches (in place).
        noise: ``[3, n]`` standard-normal draws for pot, tach, imon; held: ``[2, n]`` injected pot
            and tach volts (NaN: healthy).
        x4: scratch, ``n_sub + 1`` floats.
        O, B, E, idx: outputs (rows ``O_*``, ``B_*``, ``E_*``; index offsets per joint).
        brake_on, flips: the holding brakes engaged at the period's start, and per joint the
            substeps at which the armature moves (``[k, j]``, -1: none;
            :class:`emulators.plant.brake.HoldingBrakes`).
    """
    n = P.shape[1]
    n_seg = seg_start.shape[0]
    if (x4.shape[0] < n_sub + 1 or O.shape[1] != n or B.shape[1] != n or E.shape[1] != n
            or idx.shape[0] != n or X.shape[1] != n or seg_enable.shape[0] != n_seg or n_seg < 1
            or seg_cmd.shape[0] != n_seg or cmd_f.shape[2] != n or cmd_b.shape[2] != n
            or brake_on.shape[0] != n or flips.shape[1] != n):
        raise ValueError("period_kernel: array shapes do not match the plant")
    if F[F_LAYOUT] != LAYOUT_ID:
        raise RuntimeError("period_kernel: numba's cached machine code is stale (kernel_layout.py changed): "
                           "delete emulators/plant/__pycache__/numba_kernel.*.nb[ic]")
    has_ext = F[F_EXTERNAL] != 0
    any_comp = F[F_COMPLIANT] != 0
    has_grav = F[F_GRAVITY] != 0
    has_ke = F[F_KE] != 0
    has_tach = F[F_TACH] != 0
    has_tach_ripple = F[F_TACH_RIPPLE] != 0
    direct = F[F_DIRECT] != 0
    has_brake = F[F_BRAKE] != 0
    has_contact = F[F_CONTACT] != 0
    n_flips = flips.shape[0]
    for j in range(n):
        is_lin = P[IS_LIN, j] != 0.0
        rl = P[RL, j]
        rl_gain = P[RL_GAIN, j]
        emf_gain = P[EMF_GAIN, j]
        rail_gain = P[RAIL_GAIN, j]
        loop = P[LOOP, j]
        th_decay = P[THERMAL, j]
        th_gain = P[THERMAL_GAIN, j]
        hb_limit = P[HB_LIMIT, j]
        hb_trip = P[HB_TRIP, j]
        hb_supply = P[HB_SUPPLY, j]
        kt = P[KT, j]
        n_ratio = P[N_RATIO, j]
        inv_n = P[INV_N, j]
        comp = P[COMPLIANT, j] != 0.0
        k_flex = P[K_FLEX, j]
        c_flex = P[C_FLEX, j]
        ke_amp = P[KE_AMP, j]
        ke_phase = P[KE_PHASE, j]
        g_torque = P[G_TORQUE, j]
        g_phase = P[G_PHASE, j]
        lower = P[LOWER, j]
        upper = P[UPPER, j]
        ext = P[EXT_TORQUE, j]
        contact_k = P[CONTACT_K, j]
        contact_rad = P[CONTACT_RAD, j]
        fr_ripple = P[FR_RIPPLE, j]
        fr_phase = P[FR_PHASE, j]
        inv_ws = P[INV_WS, j]
        d_ts = P[D_TS, j]
        coulomb = P[COULOMB, j]
        bjh = P[BJH, j]
        inv_j = P[INV_J, j]
        breakout = P[BREAKOUT, j]
        viscous = P[VISCOUS, j]
        t_present = P[T_PRESENT, j]
        t_gradient = P[T_GRADIENT, j]
        t_brush = P[T_BRUSH, j]
        t_ripple = P[T_RIPPLE, j]
        t_cycles = P[T_CYCLES, j]
        t_decay = P[T_DECAY, j]
        enc_scale = P[ENC_SCALE, j]
        j_link = P[J_LINK, j]
        brake_hold = P[BRAKE_HOLD, j]
        engaged = brake_on[j]
        kf = 0
        brk = 0.0

        theta_m = X[0, j]
        omega_m = X[1, j]
        theta_l = X[2, j]
        omega_l = X[3, j]
        cur = X[4, j]
        tach = X[5, j]
        thermal = X[6, j]
        sat_time = X[7, j]
        flt = fault[j]
        cse = cause[j]
        sat = saturated[j]
        at_stop = False
        switching = False
        # friction at the end of the last substep (what friction_torque reports)
        f_hold = False
        f_td = 0.0
        f_s = 0.0
        f_tk = 0.0
        f_r = 0.0
        f_w1 = 0.0

        # Memos of the transcendental calls of the substep loop, per joint and period: a call
        # whose argument equals the previous one's returns what that one returned (the same
        # function of the same value, so the same bits). Equal is not identical for zeros:
        # sin(-0.0) is -0.0, so a sin's zero argument must have the memo's sign (cos and exp are
        # even there).
        # A joint at rest (stuck: its angle unchanged) then skips its sin/cos/exp calls.
        m_ke_a = math.nan
        m_ke = 0.0
        m_g_a = math.nan
        m_g = 0.0
        m_r_a = math.nan
        m_r = 0.0
        m_q_a = math.nan
        m_q = 0.0
        m_x = math.nan
        m_e = 0.0
        m_p1 = 0.0
        m_p2 = 0.0
        m_t_a = math.nan
        m_t = 0.0

        x4[0] = theta_m * enc_scale
        seg = -1
        lin_on = False
        i_ref = 0.0
        hb_brake = False
        hb_drive = False
        hb_v = 0.0
        hb_sign = 1.0
        sw = False
        for s in range(n_sub):
            if s == n_old and reset_edge[j]:
                flt = False
                cse = 0
                sat_time = 0.0
            if seg + 1 < n_seg and s == seg_start[seg + 1]:
                seg += 1
                c = seg_cmd[seg]
                enable = seg_enable[seg, j]
                v = cmd_f[c, 0, j]
                a = P[GAIN, j] * v
                a = max(a, -P[LIN_LIMIT, j])
                a = min(a, P[LIN_LIMIT, j])
                duty = cmd_f[c, 1, j]
                if math.isnan(duty):
                    duty = 0.0
                duty = min(max(duty, 0.0), 1.0)
                d_eff = max(duty - P[HB_DEADTIME, j], 0.0)
                hb_sign = 1.0 if cmd_b[c, 0, j] else -1.0
                hb_brake = (not is_lin) and cmd_b[c, 1, j]
                hb_drive = (not is_lin) and enable and (not hb_brake) and d_eff > 0.0
                lin_on = is_lin and enable
                i_ref = a if is_lin else 0.0
                hb_v = hb_sign * d_eff * hb_supply if hb_drive else 0.0
                sw = hb_drive and abs(hb_v) < hb_supply
            # ---- amplifier → winding current
            i0 = cur
            i0d = i0 * rl
            g = omega_m * emf_gain
            lin_active = lin_on and not flt
            if lin_active:
                i_loop = i_ref + (i0 - i_ref) * loop
                i_up = i0d + rail_gain - g
                i_dn = i0d - rail_gain - g
                i1 = min(max(i_loop, i_dn), i_up)
                sat = i1 != i_loop
            else:
                sat = False
                if (hb_brake or hb_drive) and not flt:
                    i1 = i0d + hb_v * rl_gain - g
                    if hb_drive and hb_sign * i1 > hb_limit:
                        i1 = hb_sign * hb_limit
                else:
                    i1 = i0d - _sign(i0) * rail_gain - g
                    if not i1 * i0 > 0.0:
                        i1 = 0.0
            sat_time = sat_time + h if sat else 0.0
            thermal = thermal * th_decay + (i1 * i1) * th_gain
            if (not is_lin) and abs(i1) > hb_trip:
                if not flt:
                    cse = cse | FAULT_OVERCURRENT
                flt = True
            cur = i1
            # ---- drive torque less the reflected load
            t_drive = kt * i1
            if has_ext:
                t_drive = t_drive + (0.0 if comp else 1.0) * ext * inv_n
            if has_contact and contact_k != 0.0:  # a one-sided spring below contact_rad (rigid joints)
                th_c = theta_m * inv_n
                if th_c < contact_rad:
                    t_drive = t_drive + contact_k * (contact_rad - th_c) * inv_n
            tau_s = 0.0
            if any_comp:
                th_out = theta_m / n_ratio
                if has_ke:
                    a_ke = 2.0 * theta_m + ke_phase
                    if not _same(a_ke, m_ke_a):
                        m_ke_a = a_ke
                        m_ke = math.sin(a_ke)
                    th_out = th_out + ke_amp * m_ke
                if comp:
                    tau_s = k_flex * (th_out - theta_l) + c_flex * (omega_m * inv_n - omega_l)
                load = tau_s
                if has_grav:
                    a_g = th_out + g_phase
                    if a_g != m_g_a:
                        m_g_a = a_g
                        m_g = math.cos(a_g)
                    load = load + (0.0 if comp else 1.0) * (g_torque * m_g)
                t_drive = t_drive - load * inv_n
            elif has_grav:
                th_out = theta_m / n_ratio
                if has_ke:
                    a_ke = 2.0 * theta_m + ke_phase
                    if not _same(a_ke, m_ke_a):
                        m_ke_a = a_ke
                        m_ke = math.sin(a_ke)
                    th_out = th_out + ke_amp * m_ke
                a_g = th_out + g_phase
                if a_g != m_g_a:
                    m_g_a = a_g
                    m_g = math.cos(a_g)
                t_drive = t_drive - g_torque * m_g * inv_n
            # ---- holding brake: the armature moves at its flip substeps
            if has_brake:
                while kf < n_flips and flips[kf, j] == s:
                    engaged = not engaged
                    kf += 1
                brk = brake_hold if engaged else 0.0
            # ---- exact stick/slip step of the motor shaft
            omega = omega_m
            a_r = 2.0 * theta_m + fr_phase
            if not _same(a_r, m_r_a):
                m_r_a = a_r
                m_r = math.sin(a_r)
            r = 1.0 + fr_ripple * m_r
            stuck0 = omega == 0.0
            sgn = _sign(omega) + (_sign(t_drive) if stuck0 else 0.0)
            q = omega * inv_ws
            a_q = -(q * q)
            if a_q != m_q_a:
                m_q_a = a_q
                m_q = math.exp(a_q)
            tk = (coulomb + d_ts * m_q) * r
            if has_brake:
                tk = tk + brk
            x = bjh * r
            if x == m_x and x != 0.0:
                e = m_e
                p1 = m_p1
                p2 = m_p2
            else:
                e = math.exp(-x)
                if direct:
                    p1 = (1.0 - e) / x
                    p2 = (x - 1.0 + e) / (x * x)
                else:
                    p1 = _phi1(x)
                    p2 = _phi2(x)
                m_x = x
                m_e = e
                m_p1 = p1
                m_p2 = p2
            acc0 = (t_drive - sgn * tk) * inv_j
            w1 = omega * e + acc0 * (h * p1)
            dth = h * (omega * p1 + acc0 * (h * p2))
            brk_s = breakout * r
            if has_brake:
                brk_s = brk_s + brk
            hold = stuck0 and abs(t_drive) <= brk_s
            cross = (w1 * sgn <= 0.0) and not stuck0
            if hold:
                w1 = w1 * 0.0
                dth = dth * 0.0
            if cross:
                om = omega
                ac = acc0
                if ac == 0.0:
                    ac = -_sign(om) * 1e-300
                ai = x / h
                y = -ai * om / ac
                tc = (-om / ac) * _log1p_over(max(y, 0.0))
                tc = min(max(tc, 0.0), h)
                xc = ai * tc
                dth_c = om * tc * _phi1(xc) + ac * tc * tc * _phi2(xc)
                th_c = theta_m + dth_c
                rc = 1.0 + fr_ripple * math.sin(2.0 * th_c + fr_phase)
                brk_c = breakout * rc
                if has_brake:
                    brk_c = brk_c + brk
                rev = abs(t_drive) > brk_c
                rem = h - tc
                s2 = _sign(t_drive)
                w2 = 0.0
                d2 = 0.0
                if rev:
                    acc2 = (t_drive - s2 * brk_c) * inv_j
                    x2 = bjh * rc * (rem / h)
                    w2 = acc2 * rem * _phi1(x2)
                    d2 = acc2 * rem * rem * _phi2(x2)
                bad = rev and w2 * s2 < 0.0
                if bad:
                    w2 = 0.0
                    d2 = 0.0
                w1 = w2
                dth = dth_c + d2
                hold = (not rev) or bad
                sgn = s2
                tk = brk_c
                r = rc
            f_hold = hold
            f_td = t_drive
            f_s = sgn
            f_tk = tk
            f_r = r
            f_w1 = w1
            theta_m = theta_m + dth
            omega_m = w1
            # ---- link, hard stops
            if any_comp:
                if comp:
                    acc_l = (tau_s - g_torque * math.cos(theta_l + g_phase) + ext) / j_link
                    omega_l = omega_l + h * acc_l
                    theta_l = theta_l + h * omega_l
                else:
                    omega_l = omega_m * inv_n
                    th_o = theta_m / n_ratio
                    if has_ke:
                        a_ke = 2.0 * theta_m + ke_phase
                        if not _same(a_ke, m_ke_a):
                            m_ke_a = a_ke
                            m_ke = math.sin(a_ke)
                        th_o = th_o + ke_amp * m_ke
                    theta_l = th_o
                th_j = theta_l
            elif has_ke:
                a_ke = 2.0 * theta_m + ke_phase
                if not _same(a_ke, m_ke_a):
                    m_ke_a = a_ke
                    m_ke = math.sin(a_ke)
                th_j = theta_m / n_ratio + ke_amp * m_ke
            else:
                th_j = theta_m * inv_n
            hit = th_j > upper or th_j < lower
            if hit:
                over = th_j - upper if th_j > upper else th_j - lower
                if not comp:
                    theta_m = theta_m - over * n_ratio
                    omega_m = omega_m * 0.0
                if any_comp:
                    theta_l = theta_l - over
                    omega_l = omega_l * 0.0
                th_j = th_j - over
            at_stop = hit
            # ---- tachometer generator on the joint axis, then its ripple filter
            if has_tach:
                w_j = omega_m * inv_n
                if any_comp and comp:
                    w_j = omega_l
                emf = t_gradient * w_j
                if has_tach_ripple:
                    a_t = t_cycles * th_j
                    if not _same(a_t, m_t_a):
                        m_t_a = a_t
                        m_t = math.sin(a_t)
                    emf = emf * (1.0 + t_ripple * m_t)
                gt = (emf - min(max(emf, -t_brush), t_brush)) * t_present
                tach = gt + (tach - gt) * t_decay
            if sw and not flt:
                switching = True
            x4[s + 1] = theta_m * enc_scale
        if n_old >= n_sub and reset_edge[j]:
            flt = False
            cse = 0
            sat_time = 0.0
        # ---- slow faults (once per period)
        if thermal > 1.0:
            if not flt:
                cse = cse | FAULT_THERMAL
            flt = True
        if is_lin and P[SAT_FAULT_S, j] > 0.0 and sat_time >= P[SAT_FAULT_S, j]:
            if not flt:
                cse = cse | FAULT_COMPLIANCE
            flt = True
        X[0, j] = theta_m
        X[1, j] = omega_m
        X[2, j] = theta_l
        X[3, j] = omega_l
        X[4, j] = cur
        X[5, j] = tach
        X[6, j] = thermal
        X[7, j] = sat_time
        fault[j] = flt
        cause[j] = cse
        saturated[j] = sat
        # ---- encoder events of the period
        _encoder(x4, n_sub, h, P[ENC_FS, j], ENCI[0, j], ENCI[1, j], j, E, idx)
        # ---- sensors at the end of the period
        if comp:
            th_e = theta_l
            w_e = omega_l
        else:
            th_e = theta_m / n_ratio
            if has_ke:
                th_e = th_e + ke_amp * math.sin(2.0 * theta_m + ke_phase)
            w_e = omega_m / n_ratio
        xp = (th_e - P[POT_CENTER, j]) / P[POT_SPAN, j] + 0.5
        xp = min(max(xp, 0.0), 1.0)
        frac = (xp + P[POT_BOW, j] * 4.0 * xp * (1.0 - xp)
                + P[POT_PERIODIC, j] * math.sin(2.0 * math.pi * P[POT_CYCLES, j] * xp))
        pot_v = P[POT_VLOW, j] + (P[POT_VHIGH, j] - P[POT_VLOW, j]) * frac + P[POT_NOISE, j] * noise[0, j]
        if t_present != 0.0:
            tach_v = tach + P[T_OFFSET, j] + P[T_NOISE, j] * noise[1, j]
        else:
            tach_v = 0.0
        if not math.isnan(held[0, j]):
            pot_v = held[0, j]
        if not math.isnan(held[1, j]):
            tach_v = held[1, j]
        O[O_POT, j] = pot_v
        O[O_TACH, j] = tach_v
        O[O_IMON, j] = cur * P[MON_GAIN, j] + P[MON_OFFSET, j] + P[MON_NOISE, j] * noise[2, j]
        O[O_SW_NOISE, j] = P[SW_NOISE, j] if switching else 0.0
        O[O_THETA_J, j] = th_e
        O[O_OMEGA_J, j] = w_e
        O[O_THETA_M, j] = theta_m
        O[O_OMEGA_M, j] = omega_m
        O[O_CURRENT, j] = cur
        O[O_TORQUE, j] = kt * cur
        O[O_FRICTION, j] = f_td if f_hold else f_s * f_tk + viscous * f_r * f_w1
        O[O_THERMAL, j] = thermal
        O[O_X4, j] = x4[n_sub]
        B[B_SWITCHING, j] = switching
        B[B_STUCK, j] = omega_m == 0.0
        B[B_AT_STOP, j] = at_stop
        B[B_FAULT, j] = flt
