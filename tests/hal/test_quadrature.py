"""Quadrature decoder: edge sampling model, registers, modes, latching, wrap-around, index,
faults, and the driver's unwrapping, velocity estimate and error reporting."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulators.crate import Crate
from emulators.crate_file import build_crate
from emulators.encoder_edges import EncoderSampler, SamplerState, initial_state, quadrature_events
from emulators.quadrature import BOARD_MAP, QuadratureBoard
from emulators.signals import QuadratureEvents
from hal.config import ConfigError, ConfigTable
from hal.quadrature import (
    CountJumpError,
    IllegalTransitionError,
    IndexMismatchError,
    IndexNotSeenError,
    QuadratureDriver,
    TrackingLostError,
)
from hal.vme import BusError, BusErrorCause, Width
from vmehil.commands.crate import probe_all

BASE = 0x5000
CPR = 2000  # 500-line encoder, x4
M = 1 << 24
H = 1 << 23
NETS = {0: "enc0", 1: "enc1", 2: "enc2", 3: "enc3"}


def _rig(nets: dict[int, str] | None = None, **kw) -> tuple[Crate, QuadratureBoard, QuadratureDriver]:
    c = Crate("quad-test")
    b = QuadratureBoard("quad0", nets=NETS if nets is None else nets, sample_hz=1e6)
    c.install(b, base=BASE, space="A16", slot=5)
    return c, b, QuadratureDriver(c, BASE, counts_per_rev=kw.pop("counts_per_rev", CPR), **kw)


def _pub(c: Crate, counts: int = 0, ch: int = 0, **kw) -> None:
    c.signals.publish_quadrature(NETS[ch], QuadratureEvents(counts=counts, **kw))


# register-level checks of the emulator address it through its own declaration (the doc's table)
def _r(c: Crate, reg: str, width: Width | None = None, delta: int = 0) -> int:
    r = BOARD_MAP[reg]
    return c.read(BASE + r.offset + delta, space="A16", width=width or r.width)


def _w(c: Crate, reg: str, value: int) -> None:
    r = BOARD_MAP[reg]
    c.write(BASE + r.offset, value, space="A16", width=r.width)


# --- the edge-sampling model (plant side) ------------------------------------------------
def _reference(waypoints, durations, fs, period, phase):
    """Per-sample decoding with the hardware rule, written out plainly."""
    state = initial_state(waypoints[0], period, phase)
    pos, t_next, z_prev = state.position, state.next_sample_s, state.index_high
    total = illegal = 0
    index_at: list[int] = []
    for x0, x1, dur in zip(waypoints, waypoints[1:], durations, strict=False):
        slope = (x1 - x0) / dur
        j = 0
        while t_next + j / fs < dur:
            f = math.floor(x0 + slope * (t_next + j / fs))
            d = (f - pos) % 4
            if d == 1:
                total += 1
            elif d == 3:
                total -= 1
            elif d == 2:
                illegal += 1
            z = period > 0 and f % period == phase
            if z and not z_prev:
                index_at.append(total)
            z_prev, pos = z, f
            j += 1
        t_next = min(max(t_next + j / fs - dur, 0.0), 1 / fs)
    return total, illegal, index_at, pos % 4


@settings(max_examples=150, deadline=None)
@given(
    waypoints=st.lists(st.floats(-60, 60, allow_nan=False), min_size=2, max_size=8),
    durations=st.lists(st.floats(1e-4, 5e-3), min_size=7, max_size=7),
    fs=st.sampled_from([997.0, 2000.0, 10_000.0]),
    period=st.sampled_from([0, 4, 7, 16]),
    phase_seed=st.integers(0, 100),
)
def test_edge_model_matches_per_sample_decoding(waypoints, durations, fs, period, phase_seed) -> None:
    phase = phase_seed % period if period else 0
    state: SamplerState | None = None
    total = illegal = 0
    index_at: list[int] = []
    last = None
    for x0, x1, dur in zip(waypoints, waypoints[1:], durations, strict=False):
        ev, state = quadrature_events(x0, x1, dur, fs, period, phase, state)
        index_at += [total + o for o in ev.index_offsets]
        total += ev.counts
        illegal += ev.illegal
        last = ev
    ref = _reference(waypoints, durations, fs, period, phase)
    assert (total, illegal, index_at, last.phase) == ref


@pytest.mark.parametrize("states_per_sample,counts,illegal", [
    (0.5, 5, 0), (1, 9, 0), (2, 0, 9), (3, -9, 0), (4, 0, 0), (5, 9, 0), (6, 0, 9),
])
def test_too_fast_a_shaft_is_illegal_or_aliased_like_hardware(states_per_sample, counts, illegal) -> None:
    fs, n = 1000.0, 10
    x0 = 0.5
    x1 = x0 + states_per_sample * n
    ev, st_ = quadrature_events(x0, x1, n / fs, fs)  # samples at x0 + k·step, k = 0..9
    assert (ev.counts, ev.illegal) == (counts, illegal)
    assert st_.position == math.floor(x0 + states_per_sample * (n - 1))
    assert ev.phase == st_.position % 4


def test_slow_motion_is_closed_form_even_at_absurd_sample_rates() -> None:
    # 10^12 samples: per-sample evaluation could not run; the closed form is O(1).
    ev, st_ = quadrature_events(0.25, 5000.75, 1.0, 1e12, index_period_x4=2000, index_phase_x4=1234)
    assert ev.counts == 5000 and ev.illegal == 0 and ev.index_offsets == (1234, 3234)
    ev, _ = quadrature_events(5000.75, 0.25, 1.0, 1e12, 2000, 1234, st_)
    assert ev.counts == -5000 and ev.index_offsets == (3234 - 5000, 1234 - 5000)


def test_a_fast_shaft_can_step_over_the_index() -> None:
    # two states per sample from 0.5: the sampler sees even states only
    ev, _ = quadrature_events(0.5, 40.5, 0.02, 1000.0, index_period_x4=8, index_phase_x4=3)
    assert ev.index_offsets == () and ev.illegal == 19
    ev, _ = quadrature_events(0.5, 40.5, 0.02, 1000.0, index_period_x4=8, index_phase_x4=2)
    assert len(ev.index_offsets) == 5


def test_edge_model_argument_checks() -> None:
    with pytest.raises(ValueError):
        quadrature_events(0, 1, 0.0, 1e6)
    with pytest.raises(ValueError):
        quadrature_events(0, 1, 1e-3, 0.0)
    with pytest.raises(ValueError):
        quadrature_events(0, 1, 1e-3, 1e6, index_period_x4=4, index_phase_x4=4)


def test_sampler_clock_carries_across_intervals() -> None:
    # 0.25 ms intervals at 1 kHz sampling: one sample every fourth interval
    state = initial_state(0.5)
    seen = []
    x = 0.5
    for _ in range(12):
        ev, state = quadrature_events(x, x + 0.25, 0.25e-3, 1000.0, state=state)
        x += 0.25
        seen.append(ev.counts)
    assert sum(seen) == 2 and seen.count(1) == 2  # samples at 0, 1, 2 ms → floors 0, 1, 2


# --- registers ---------------------------------------------------------------------------
def test_id_is_the_first_readable_register_and_the_crate_probe_reads_it() -> None:
    c, _, _ = _rig()
    assert _r(c, "ID") == 0x5101
    (probe,) = probe_all(c)
    assert probe["ok"] and probe["value"] == "0x5101"


def test_register_access_rules_and_byte_lanes() -> None:
    c, _, d = _rig()
    d.preset(0, 0x123456)
    _w(c, "CH0_CMD", 1)
    assert _r(c, "CH0_OL_HI") == 0x0012 and _r(c, "CH0_OL_LO") == 0x3456
    assert [_r(c, "CH0_OL_HI", Width.D8, i) for i in (0, 1)] == [0x00, 0x12]
    assert [_r(c, "CH0_OL_LO", Width.D8, i) for i in (0, 1)] == [0x34, 0x56]
    assert _r(c, "CH0_PRE_HI") == 0x12 and _r(c, "CH0_PRE_LO") == 0x3456
    for reg, cause in (("CH0_CMD", BusErrorCause.ACCESS), ("GCMD", BusErrorCause.ACCESS)):
        with pytest.raises(BusError) as ei:
            _r(c, reg)
        assert ei.value.cause is cause
    with pytest.raises(BusError) as ei:
        _w(c, "CH1_OL_LO", 0)
    assert ei.value.cause is BusErrorCause.ACCESS
    with pytest.raises(BusError) as ei:
        c.read(BASE + BOARD_MAP["CH0_OL_HI"].offset, space="A16", width=Width.D32)
    assert ei.value.cause is BusErrorCause.UNSUPPORTED_WIDTH
    assert _r(c, "CH2_CTL") == 2  # power-up: x4, index disarmed


def test_status_w1c_clears_only_written_flags_and_shows_ab_levels() -> None:
    c, _, _ = _rig()
    _pub(c, 0, illegal=1, phase=2)
    _pub(c, -1, phase=1)  # 0 → 0xFFFFFF: underflow
    assert _r(c, "CH0_STATUS") == 0b1010 | 1 << 8  # phase 1: A high, B low
    _w(c, "CH0_STATUS", 0b0010)
    assert _r(c, "CH0_STATUS") == 0b1000 | 1 << 8
    _w(c, "CH0_STATUS", 0xFFFF)
    assert _r(c, "CH0_STATUS") == 1 << 8


def test_commands_latch_clear_preset_and_global_latch() -> None:
    c, _, _ = _rig()
    _pub(c, 100, ch=0)
    _pub(c, 200, ch=1)
    _w(c, "GCMD", 0b0011)
    _pub(c, 5, ch=0)
    _pub(c, 5, ch=1)
    assert _r(c, "CH0_OL_LO") == 100 and _r(c, "CH1_OL_LO") == 200  # latched at the same instant
    _w(c, "CH0_CMD", 0b011)  # latch, then clear
    assert _r(c, "CH0_OL_LO") == 105 and _r(c, "CH0_CNT_LO") == 0
    _w(c, "CH1_PRE_HI", 0xAB)
    _w(c, "CH1_PRE_LO", 0xCDEF)
    _w(c, "CH1_CMD", 0b100)
    assert _r(c, "CH1_CNT_HI") == 0xAB and _r(c, "CH1_CNT_LO") == 0xCDEF


def test_hold_mode_inhibits_counting() -> None:
    c, _, d = _rig()
    _pub(c, 10)
    d.hold(0)
    _pub(c, 50)
    assert d.read_count(0) == 10
    d.set_mode(0, 4)
    _pub(c, 1)
    assert d.read_count(0) == 11


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(-300, 300), min_size=1, max_size=30))
def test_x1_x2_x4_count_the_same_events(steps) -> None:
    nets = {0: "enc", 1: "enc", 2: "enc"}  # one encoder into three channels
    c, _, d = _rig(nets=nets, channels=(0, 1, 2))
    d.set_mode(0, 1)
    d.set_mode(1, 2)
    acc = 0
    for s in steps:
        c.signals.publish_quadrature("enc", QuadratureEvents(counts=s))
        acc += s
        assert d.read_count(2) == acc % M
        assert d.read_count(1) == (acc // 2) % M
        assert d.read_count(0) == (acc // 4) % M
        assert [d.position_counts(ch) for ch in (0, 1, 2)] == [acc // 4, acc // 2, acc]


# --- latch-then-read vs the live counter -------------------------------------------------
def test_live_counter_read_tears_and_the_latch_does_not() -> None:
    c, _, d = _rig()
    d.preset(0, 0x00FFFF)
    # a count arrives between the two cycles of the read (each cycle takes 300 ns)
    c.clock.schedule(c.clock.now_ns + 450, lambda: _pub(c, 1))
    assert d.read_count_unlatched(0) == 0x000000  # high part before, low part after: torn
    d.preset(0, 0x00FFFF)
    c.clock.schedule(c.clock.now_ns + 450, lambda: _pub(c, 1))
    assert d.read_count(0) == 0x00FFFF  # the latch holds the instant of the command
    assert d.read_count(0) == 0x010000
    # three D8 byte reads of the output latch
    assert [_r(c, "CH0_OL_HI", Width.D8, 1), _r(c, "CH0_OL_LO", Width.D8, 0),
            _r(c, "CH0_OL_LO", Width.D8, 1)] == [0x01, 0x00, 0x00]


# --- wrap-around and unwrapping ----------------------------------------------------------
@settings(max_examples=80, deadline=None)
@given(
    start=st.integers(0, M - 1),
    steps=st.lists(st.integers(-(H - 1), H - 1), min_size=1, max_size=40),
    bias=st.sampled_from([0, 3_000_000, -3_000_000]),
)
def test_unwrapped_count_is_exact_across_any_number_of_wraps(start, steps, bias) -> None:
    c, b, d = _rig(channels=(0,))
    d.preset(0, start)
    base = d.position_counts(0)
    total = 0
    for s in steps:
        s = max(-(H - 1), min(H - 1, s // 3 + bias))
        _pub(c, s)
        total += s
        assert d.position_counts(0) == base + total
        assert b.ch[0].counter == (start + total) % M
        assert b.ch[0].status & 0b1100 == 0  # the driver consumed the wrap flags


def test_long_runs_wrap_many_times_in_both_directions() -> None:
    c, b, d = _rig(channels=(0,))
    seen_flags = set()
    step = 4_000_000
    for direction in (1, -1, -1, 1):
        for _ in range(20):  # 80 M counts: ~5 wraps per leg
            _pub(c, direction * step)
            seen_flags.add(b.ch[0].status & 0b1100)
            d.position_counts(0)
    assert d.position_counts(0) == 0 and d.read_count(0) == 0
    assert {0b0100, 0b1000} <= seen_flags


def test_more_than_half_a_range_between_reads_is_reported_not_guessed() -> None:
    c, _, d = _rig(channels=(0,))
    _pub(c, int(0.6 * M))  # no wrap, but it looks like -0.4 M
    with pytest.raises(TrackingLostError, match=(
            r"^quadrature channel 0: count moved -\d+ \(more than a quarter of the 24-bit range\) since the "
            r"last read and the wrap flags \(overflow=False, underflow=False\) disagree: more than half a range "
            r"of travel between reads; read the channel more often and re-home$")) as lost:
        d.position_counts(0)
    assert lost.value.channel == 0
    d.preset(0, M - 10)
    before = d.position_counts(0)
    _pub(c, int(0.45 * M))  # wraps, overflow flag set: consistent, accepted
    assert d.position_counts(0) - before == int(0.45 * M)
    assert d.read_count(0) == (M - 10 + int(0.45 * M)) % M


# --- illegal transitions at speed --------------------------------------------------------
def test_too_fast_a_shaft_is_reported_as_illegal_and_the_count_falls_behind() -> None:
    c, _, d = _rig(channels=(0,))
    dt = 0.008
    slow_decoder_hz = 20_000.0
    enc = EncoderSampler(CPR, slow_decoder_hz, index_phase_x4=None)
    omega = 2.2 * slow_decoder_hz / CPR * 2 * math.pi  # 2.2 states per decoder sample
    with pytest.raises(IllegalTransitionError, match=(
            r"^quadrature channel 0: illegal transition \(A and B changed in one decoder sample\): counts were "
            r"lost — the shaft outran the decoder's sampling rate or the signals are noisy; re-home, then "
            r"clear_errors\(\)$")) as ei:
        theta = 0.0
        for _ in range(3):
            theta += omega * dt
            _pub(c, **_ev(enc.step(theta, dt)))
            d.update(dt)
    r = ei.value.readings[0]
    assert r.status.illegal and ei.value.channel == 0
    true_counts = math.floor(theta * CPR / (2 * math.pi))
    assert abs(r.counts) < 0.5 * true_counts  # most transitions were lost
    with pytest.raises(IllegalTransitionError):  # sticky until cleared
        d.update(dt)
    _pub(c, **_ev(enc.step(theta, dt)))  # the shaft stops (the first sample may still jump)
    d.clear_errors(0)
    _pub(c, **_ev(enc.step(theta + 0.01, dt)))  # slow again
    assert not d.update(dt)[0].status.illegal


def test_below_one_state_per_sample_the_count_is_exact() -> None:
    c, _, d = _rig(channels=(0,))
    enc = EncoderSampler(CPR, 20_000.0, index_phase_x4=None)
    omega = 0.95 * 20_000.0 / CPR * 2 * math.pi
    theta = 0.0
    for _ in range(50):
        theta += omega * 0.008
        _pub(c, **_ev(enc.step(theta, 0.008)))
        r = d.update(0.008)[0]
    assert abs(r.counts - theta * CPR / (2 * math.pi)) <= 1.0 + omega * CPR / (2 * math.pi) / 20_000.0


def _ev(ev: QuadratureEvents) -> dict:
    return {"counts": ev.counts, "illegal": ev.illegal, "index_offsets": ev.index_offsets, "phase": ev.phase}


def test_report_mode_returns_flags_instead_of_raising() -> None:
    c, _, d = _rig(errors="report", channels=(0, 1))
    _pub(c, 3, illegal=2)
    r = d.update(0.008)
    assert r[0].status.illegal and r[0].counts == 3 and not r[1].status.illegal


# --- index and homing --------------------------------------------------------------------
def _drive(c: Crate, enc: EncoderSampler, theta: float, dt: float = 0.008) -> None:
    _pub(c, **_ev(enc.step(theta, dt)))


def test_index_latch_and_homing_define_zero_at_the_index() -> None:
    c, _, d = _rig(channels=(0,))
    index_state = 777
    enc = EncoderSampler(CPR, 1e6, index_phase_x4=index_state, theta0_rad=0.1)
    with pytest.raises(IndexNotSeenError, match=r"^quadrature channel 0: no index captured; arm_index\(\) and "
                                                r"move through the index first$") as unseen:
        d.home_at_index(0)
    assert unseen.value.channel == 0
    d.arm_index(0)
    theta = 0.1
    while not d.index_seen(0):
        theta += 0.05
        _drive(c, enc, theta)
    assert _r(c, "CH0_CTL") & 0x10 == 0  # the arm bit cleared itself
    start = math.floor(0.1 * CPR / (2 * math.pi))
    assert d.home_at_index(0) == index_state - start
    theta_index = index_state * 2 * math.pi / CPR
    assert abs(d.position_rad(0) - (theta - theta_index)) <= 2 * math.pi / CPR
    # one more revolution: the index comes back on the grid
    for _ in range(130):
        theta += 0.05
        _drive(c, enc, theta)
    assert d.check_index(0) == 0.0
    assert d.check_index(0) is None  # not seen again yet
    # downwards through the index: same state, same count
    for _ in range(130):
        theta -= 0.05
        _drive(c, enc, theta)
    assert d.check_index(0) == 0.0


def test_index_latch_uses_the_count_at_the_pulse_in_every_mode() -> None:
    c, _, d = _rig(channels=(0,))
    d.set_mode(0, 1)
    d.arm_index(0)
    _pub(c, 10, index_offsets=(6, 9))
    assert d.index_seen(0)
    assert (_r(c, "CH0_IDX_HI") << 16 | _r(c, "CH0_IDX_LO")) == 1  # floor(6/4)
    assert d.read_count(0) == 2  # floor(10/4)
    _pub(c, 10, index_offsets=(3,))  # disarmed: the latch keeps the first capture
    assert _r(c, "CH0_IDX_LO") == 1


# --- faults ------------------------------------------------------------------------------
def test_glitch_fault_is_seen_as_an_illegal_transition_and_a_count_error() -> None:
    c, b, d = _rig(channels=(0,))
    d.update(0.008)
    b.inject("glitch", channel=0, counts=5, illegal=1)
    _pub(c, 0)
    with pytest.raises(IllegalTransitionError) as ei:
        d.update(0.008)
    assert ei.value.readings[0].counts == 5
    d.clear_errors(0)
    _pub(c, 0)  # one interval only
    assert d.update(0.008)[0].counts == 5


def test_missed_counts_fault_is_caught_by_the_index_check() -> None:
    c, b, d = _rig(channels=(0,))
    enc = EncoderSampler(CPR, 1e6, index_phase_x4=500)
    d.arm_index(0)
    theta = 0.0
    while not d.index_seen(0):
        theta += 0.05
        _drive(c, enc, theta)
    d.home_at_index(0)
    b.inject("missed_counts", channel=0, counts=3)
    for _ in range(130):
        theta += 0.05
        _drive(c, enc, theta)
    with pytest.raises(IndexMismatchError) as ei:
        d.check_index(0)
    assert ei.value.error_counts == -3.0
    assert str(ei.value) == ("quadrature channel 0: index captured -3 counts off the homed grid: counts were missed "
                             "or gained (check encoder wiring, speed vs decoder sampling rate); re-home the axis")
    truth = math.floor(theta * CPR / (2 * math.pi))
    assert d.position_counts(0) == truth - 3


def test_counter_jump_fault_is_caught_by_the_plausibility_limit() -> None:
    c, b, d = _rig(channels=(0,), max_counts_per_tick=1000)
    d.update(0.008)
    _pub(c, 900)
    d.update(0.008)
    b.inject("counter_jump", channel=0, counts=-5000)
    with pytest.raises(CountJumpError, match=r"^quadrature channel 0: count changed by -5000 in one tick "
                                             r"\(limit 1000\): a counter jump or noise burst; check the encoder "
                                             r"and re-home$") as ei:
        d.update(0.008)
    assert ei.value.channel == 0
    assert d.read_count(0) == (900 - 5000) % M  # the jump wrapped below zero
    assert b.ch[0].status & 0b1000 == 0  # and the driver consumed the underflow flag while unwrapping


def test_each_reading_of_update_names_its_channel() -> None:
    _, _, d = _rig(channels=(0, 2))
    assert [(ch, r.channel) for ch, r in d.update(0.008).items()] == [(0, 0), (2, 2)]


def test_a_jump_seen_by_velocity_of_one_channel_names_that_channel() -> None:
    c, _, d = _rig(channels=(1,), max_counts_per_tick=1000)
    d.velocity(1, 0.008)
    _pub(c, 1001, ch=1)
    with pytest.raises(CountJumpError, match=r"count changed by \+1001 in one tick \(limit 1000\)") as ei:
        d.velocity(1, 0.008)
    assert ei.value.channel == 1


def test_huge_counter_jump_is_tracking_lost() -> None:
    _, b, d = _rig(channels=(0,))
    b.inject("counter_jump", channel=0, counts=int(0.7 * M))
    with pytest.raises(TrackingLostError):
        d.update(0.008)
    d.update(0.008)  # tracking resumes from the new value


def test_fault_parameter_checks() -> None:
    _, b, _ = _rig()
    with pytest.raises(ValueError, match="channel 7"):
        b.inject("counter_jump", channel=7, counts=1)
    with pytest.raises(KeyError):
        b.inject("encoder_on_fire", channel=0)


# --- velocity ----------------------------------------------------------------------------
def test_velocity_is_count_difference_per_tick_at_speed() -> None:
    c, _, d = _rig(channels=(0,))
    dt = 0.008
    d.update(dt)
    for _ in range(5):
        _pub(c, 40)
        r = d.update(dt)[0]
    assert r.velocity_counts_s == 40 / dt
    assert r.velocity_rad_s == pytest.approx(40 / dt * 2 * math.pi / CPR)


def test_velocity_uses_one_over_t_at_low_speed_and_decays_to_zero() -> None:
    c, _, d = _rig(channels=(0,), stop_ticks=50)
    dt = 0.008
    d.update(dt)
    v = []
    for k in range(20):
        if k % 5 == 4:
            _pub(c, 1)  # one count every five ticks
        v.append(d.update(dt)[0].velocity_counts_s)
    assert v[9] == pytest.approx(1 / (5 * dt)) and v[14] == pytest.approx(1 / (5 * dt))
    assert all(x == pytest.approx(1 / (5 * dt)) for x in v[10:])  # bounded, no dips between counts
    for _ in range(10):
        v.append(d.update(dt)[0].velocity_counts_s)
    assert v[-1] == pytest.approx(1 / (10 * dt))  # no count for 10 ticks: at most 1 count / 10 ticks
    for _ in range(50):
        v.append(d.update(dt)[0].velocity_counts_s)
    assert v[-1] == 0.0
    _pub(c, -1)
    assert d.velocity(0, dt) < 0


def test_velocity_argument_check() -> None:
    _, _, d = _rig(channels=(0,))
    with pytest.raises(ValueError, match=r"^dt must be > 0 s \(got 0\.0\)$"):
        d.velocity(0, 0.0)
    with pytest.raises(ValueError, match=r"^quadrature channel 3 is not in use \(channels \(0,\)\)$"):
        d.position_counts(3)  # not in use


# --- modes, preset and position ----------------------------------------------------------
def test_mode_change_keeps_position_continuous() -> None:
    c, _, d = _rig(channels=(0,), counts_per_rev={0: 2000.0})
    _pub(c, 1234)
    before = d.position_rad(0)
    d.set_mode(0, 1)
    assert d.counts_per_rev(0) == 500.0
    assert abs(d.position_rad(0) - before) < 2 * math.pi / 500
    p0 = d.position_rad(0)
    _pub(c, 400)
    assert d.position_rad(0) - p0 == pytest.approx(400 * 2 * math.pi / 2000)
    with pytest.raises(ValueError, match=r"^quadrature mode 3 is not 1, 2 or 4$"):
        d.set_mode(0, 3)


def test_preset_and_clear_keep_the_position() -> None:
    c, _, d = _rig(channels=(0,))
    _pub(c, 300)
    d.set_zero(0, 1.0)
    d.preset(0, 0xFFFF00)
    assert d.position_rad(0) == pytest.approx(1.0)
    _pub(c, 0x200)  # wraps after the preset
    assert d.position_rad(0) == pytest.approx(1.0 + 0x200 * 2 * math.pi / CPR)
    d.clear(0)
    assert d.read_count(0) == 0
    assert d.position_rad(0) == pytest.approx(1.0 + 0x200 * 2 * math.pi / CPR)
    with pytest.raises(ValueError, match=r"^preset 16777216 is not a 24-bit count$"):
        d.preset(0, M)


def test_counts_per_rev_validation() -> None:
    c, _, _ = _rig()
    with pytest.raises(ValueError, match="channel"):
        QuadratureDriver(c, BASE, counts_per_rev={0: 2000.0}, channels=(0, 1))
    with pytest.raises(ValueError, match=r"^counts_per_rev for channel 0 must be > 0 \(got 0\.0\)$"):
        QuadratureDriver(c, BASE, counts_per_rev=0.0)
    with pytest.raises(ValueError, match=r"^errors must be 'raise' or 'report' \(got 'ignore'\)$"):
        QuadratureDriver(c, BASE, counts_per_rev=2000.0, errors="ignore")


# --- wiring ------------------------------------------------------------------------------
def test_a_quadrature_net_must_carry_quadrature_events() -> None:
    c, _, _ = _rig()
    with pytest.raises(TypeError, match="publish_quadrature"):
        c.signals.set_analog("enc0", 1.0)


def test_crate_file_builds_a_wired_decoder() -> None:
    cfg = ConfigTable({"crate": {"board": [{
        "type": "quad", "name": "quad0", "space": "A16", "base": BASE,
        "channels": ["j1.enc", "", "j3.enc"], "sample_hz": 2e6}]}}, "<test>")
    c = build_crate(cfg)
    b = c.board("quad0")
    assert b.describe() == {"type": "quad", "channels": {0: "j1.enc", 2: "j3.enc"}, "sample_hz": 2e6}
    d = QuadratureDriver(c, BASE, counts_per_rev=CPR, channels=(0, 2))
    c.signals.publish_quadrature("j3.enc", QuadratureEvents(counts=-7))
    assert d.update(0.008)[2].counts == -7
    bad = ConfigTable({"crate": {"board": [{"type": "quad", "name": "q", "space": "A16", "base": BASE,
                                            "channels": ["a", "b", "c", "d", "e"]}]}}, "<test>")
    with pytest.raises(ConfigError, match="channels"):
        build_crate(bad)

