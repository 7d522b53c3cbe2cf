"""The MAVLink endpoint against a pymavlink client on loopback UDP: parameter protocol, safety of
live changes, signing, telemetry, heartbeat and arming (over a real ServoLoop on ideal joints)."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from tests.support.fakes import fake_loop
from vmehil.mavlink.client import Client
from vmehil.mavlink.endpoint import MavlinkEndpoint, free_udp_port
from vmehil.mavlink.signing import key_from_passphrase


@pytest.fixture
def rig():
    """(loop, io, runner, endpoint, client); closed afterwards."""
    made = []

    def make(n=2, key=None, client_key=None, **kw):
        loop, io, runner = fake_loop(n)
        port = free_udp_port()
        ep = MavlinkEndpoint(loop, f"udpin:127.0.0.1:{port}", key=key, **kw)
        runner.after_tick.append(ep.after_tick)
        client = Client(port, key=client_key)
        client.hello()
        made.append((ep, client))
        return loop, io, runner, ep, client

    yield make
    for ep, client in made:
        client.close()
        ep.close()


def param_values(client, name=None):
    return [m for m in client.of("PARAM_VALUE") if name is None or m.param_id == name]


def test_request_list_sends_every_parameter_once_with_count_and_index(rig):
    loop, _, runner, ep, c = rig(n=3)
    c.request_list()
    n = len(ep.table)
    c.wait(lambda: len(param_values(c)) >= n, runner.tick)
    got = param_values(c)
    assert len(got) == n == 3 * 12 + 1
    assert sorted(m.param_index for m in got) == list(range(n))
    assert {m.param_count for m in got} == {n}
    assert {m.param_type for m in got} == {c.ml.MAV_PARAM_TYPE_REAL32}
    by_name = {m.param_id: m for m in got}
    assert all(len(name) <= 16 for name in by_name)
    assert by_name["J2_KP"].param_value == pytest.approx(float(loop.law.gains.kp[1]))
    assert by_name["J3_KVI"].param_value == pytest.approx(1000.0)
    assert by_name["J1_TAU_MAX"].param_value == pytest.approx(50.0)
    assert by_name["SERVO_RATE_HZ"].param_value == pytest.approx(125.0)
    assert [by_name[s.name].param_index for s in ep.table.specs] == list(range(n))
    assert ep.stats.errors == []


def test_read_by_name_and_by_index(rig):
    _loop, _, runner, ep, c = rig()
    c.read("J2_KV")
    idx = ep.table.find("J1_SO_OUT")[0]
    c.read(index=idx)
    c.wait(lambda: len(param_values(c)) >= 2, runner.tick)
    kv, so = param_values(c)[:2]
    assert (kv.param_id, kv.param_index, kv.param_value) == ("J2_KV", ep.table.find("J2_KV")[0], 50.0)
    assert so.param_id == "J1_SO_OUT" and so.param_index == idx
    assert so.param_value == pytest.approx(math.radians(1.0), rel=1e-6)
    assert {m.param_count for m in param_values(c)} == {len(ep.table)}


def test_unknown_name_and_index_get_param_error_does_not_exist(rig):
    _, _, runner, ep, c = rig()
    c.read("J9_KP")
    c.read(index=len(ep.table))
    c.set("NO_SUCH", 1.0)
    c.wait(lambda: len(c.of("PARAM_ERROR")) >= 3, runner.tick)
    errs = c.of("PARAM_ERROR")
    assert {e.error for e in errs} == {c.ml.MAV_PARAM_ERROR_DOES_NOT_EXIST}
    assert [e.param_id for e in errs] == ["J9_KP", "", "NO_SUCH"]
    assert errs[1].param_index == len(ep.table)
    assert all(e.target_system == 255 and e.target_component == 190 for e in errs)
    assert param_values(c) == []


def test_set_gain_applies_at_a_tick_boundary_and_is_logged(rig):
    loop, _, runner, ep, c = rig()
    runner.run(10)
    kp_seen = []
    runner.after_tick.insert(0, lambda lp: kp_seen.append((lp.tick_count - 1, float(lp.law.gains.kp[0]))))
    c.set("J1_KP", 120.0)
    reply = c.wait(lambda: param_values(c, "J1_KP"), runner.tick)[0]
    assert reply.param_value == 120.0 and reply.param_index == ep.table.find("J1_KP")[0]
    assert float(loop.law.gains.kp[0]) == 120.0 and float(loop.law.gains.kp[1]) == 100.0
    note = [entry for entry in loop.log if "J1_KP" in entry[2]]
    assert len(note) == 1
    t, source, text = note[0]
    assert source == "mavlink" and "100 -> 120" in text and "sys 255 comp 190" in text
    k_change = round(t / loop.period_s)
    assert t == pytest.approx(k_change * loop.period_s)
    # the tick that drained the command ran with the new gain from its start; the one before with the old
    assert dict(kp_seen)[k_change] == 120.0 and dict(kp_seen)[k_change - 1] == 100.0
    assert ep.stats.sets_applied == 1


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, -1.0, 2e5])
def test_non_finite_or_out_of_range_gain_refused_with_old_value(rig, value):
    loop, _, runner, _ep, c = rig()
    c.set("J1_KV", value)
    c.wait(lambda: c.of("PARAM_ERROR") and param_values(c, "J1_KV") and c.of("STATUSTEXT"), runner.tick)
    err = c.of("PARAM_ERROR")[0]
    assert err.error == c.ml.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE and err.param_id == "J1_KV"
    assert param_values(c, "J1_KV")[0].param_value == 50.0
    assert float(loop.law.gains.kv[0]) == 50.0
    assert any("refused" in text for _, _, text in loop.log)


def test_read_only_parameter_refused(rig):
    _loop, _, runner, _ep, c = rig()
    c.set("J1_VEL_MAX", 3.0)
    c.wait(lambda: c.of("PARAM_ERROR") and param_values(c, "J1_VEL_MAX"), runner.tick)
    assert c.of("PARAM_ERROR")[0].error == c.ml.MAV_PARAM_ERROR_READ_ONLY
    assert param_values(c, "J1_VEL_MAX")[0].param_value == pytest.approx(0.5)


def test_a_refusal_reaches_the_ground_station_in_ascii(rig):
    """The reason says "1/s²" and "0 … 1e5"; MAVProxy shows "?" for those, so they go out as ASCII."""
    _loop, _, runner, _ep, c = rig()
    c.set("J1_KP", 1e6)
    text = "".join(m.text for m in c.wait(lambda: c.of("STATUSTEXT"), runner.tick))
    assert text == "J1_KP: 1e+06 1/s^2 is out of range (allowed: 0 ... 100000)", text
    assert text.isascii() and "?" not in text, text


def test_gain_making_the_sampled_loop_unstable_is_refused_with_old_value(rig):
    loop, _, runner, _ep, c = rig()
    c.set("J1_KP", 90000.0)  # in range, but Kp·T² ≫ 4: the sampled loop diverges
    c.wait(lambda: c.of("PARAM_ERROR") and param_values(c, "J1_KP"), runner.tick)
    assert c.of("PARAM_ERROR")[0].error == c.ml.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE
    assert param_values(c, "J1_KP")[0].param_value == 100.0
    text = "".join(m.text for m in c.wait(lambda: c.of("STATUSTEXT"), runner.tick))
    assert "unstable" in text
    runner.run(50)
    assert float(loop.law.gains.kp[0]) == 100.0 and loop.fault is None


def test_boost_making_the_switched_off_loop_unstable_is_refused(rig):
    from servo.control.gains import Gains
    from servo.gain_guard import judge

    # premises: Kv 20, Kp 1000 is stable integrating and switched off with the auto boost (Kp_off = Kp + KvI),
    # but a boost of 10 (Kp_off = 10000) makes the switched-off loop unstable
    assert judge(Gains(kp=100, kpi=5000, kv=20, kvi=1000), 0.008, kp_off=1100).ok
    assert judge(Gains(kp=1000, kpi=5000, kv=20, kvi=1000), 0.008, kp_off=2000).ok
    verdict = judge(Gains(kp=1000, kpi=5000, kv=20, kvi=1000), 0.008, kp_off=10000)
    assert not verdict.ok and verdict.margin_integrating > 0 and verdict.margin_switched_off < 0
    loop, _, runner, _ep, c = rig()
    c.set("J1_KV", 20.0)
    c.set("J1_KP", 1000.0)
    c.wait(lambda: param_values(c, "J1_KP"), runner.tick)
    assert float(loop.law.gains.kp[0]) == 1000.0
    c.set("J1_SO_BOOST", 10.0)
    c.wait(lambda: c.of("PARAM_ERROR") and param_values(c, "J1_SO_BOOST"), runner.tick)
    assert param_values(c, "J1_SO_BOOST")[-1].param_value == 0.0  # still auto
    assert np.isnan(loop.law.switch_off.kp_boost[0])
    c.set("J1_SO_BOOST", 1.5)  # Kp_off = 1500: fine
    c.wait(lambda: len(param_values(c, "J1_SO_BOOST")) >= 2, runner.tick)
    runner.tick()
    assert loop.law.switch_off.kp_boost[0] == 1.5


def test_switch_off_bands_must_keep_their_order(rig):
    loop, _, runner, _ep, c = rig()
    c.set("J2_SO_IN", 0.1)  # above the 1° outer band
    c.wait(lambda: c.of("PARAM_ERROR"), runner.tick)
    assert c.of("PARAM_ERROR")[0].param_id == "J2_SO_IN"
    c.set("J2_SO_OUT", 0.2)
    c.set("J2_SO_IN", 0.1)
    c.wait(lambda: len(param_values(c, "J2_SO_IN")) >= 2, runner.tick)
    runner.tick()
    assert loop.law.switch_off.outer_band[1] == pytest.approx(0.2)
    assert loop.law.switch_off.inner_band[1] == pytest.approx(0.1)
    assert loop.law.switch_off.inner_band[0] == pytest.approx(math.radians(0.1))


def test_limit_can_be_tightened_but_not_raised_above_the_start_value(rig):
    loop, _, runner, _ep, c = rig()
    c.set("J1_TAU_MAX", 80.0)
    c.set("J1_TAU_MAX", 20.0)
    c.set("J2_FERR_MAX", 0.1)
    c.wait(lambda: len(param_values(c)) >= 3, runner.tick)
    assert c.of("PARAM_ERROR")[0].param_id == "J1_TAU_MAX"
    tl = loop.controller.active.find("torque_limit")
    assert list(tl.tau_max) == [20.0, 50.0]
    assert loop.watchdog.following_error_rad[1] == pytest.approx(0.1)


def _record_theta(runner):
    rows = []
    runner.after_tick.insert(0, lambda lp: rows.append(np.asarray(lp.last["theta"], float).copy()))
    return rows


def test_gain_set_over_mavlink_changes_the_loop_like_the_same_change_made_in_process(rig):
    loop, _, runner, _ep, c = rig()
    rows = _record_theta(runner)
    runner.run(20)
    c.set("J1_KV", 20.0)
    c.wait(lambda: param_values(c, "J1_KV"), runner.tick)
    runner.run(300 - len(rows))
    k_change = round(next(t for t, _, text in loop.log if "J1_KV" in text) / loop.period_s)
    # the same run with the gain staged directly for the same tick
    ref_loop, _, ref_runner = fake_loop(2)
    ref_rows = _record_theta(ref_runner)
    ref_runner.run(k_change)
    ref_loop.submit(lambda lp: lp.law.set_gains(kv=20.0, joint=0))
    ref_runner.run(300 - k_change)
    # and without it
    _base_loop, _, base_runner = fake_loop(2)
    base_rows = _record_theta(base_runner)
    base_runner.run(300)
    a, ref, base = np.array(rows), np.array(ref_rows), np.array(base_rows)
    np.testing.assert_array_equal(a, ref)
    np.testing.assert_array_equal(a[:k_change + 1], base[:k_change + 1])
    assert np.abs(a[k_change + 2:, 0] - base[k_change + 2:, 0]).max() > 1e-6
    np.testing.assert_array_equal(a[:, 1], base[:, 1])


KEY = key_from_passphrase("correct horse battery staple")


def test_signing_unsigned_set_refused_signed_set_applied(rig):
    loop, _, runner, ep, unsigned = rig(key=KEY)
    port = int(ep.url.rsplit(":", 1)[1])
    unsigned.set("J1_KP", 130.0)
    unsigned.wait(lambda: unsigned.of("PARAM_ERROR"), runner.tick)
    assert unsigned.of("PARAM_ERROR")[0].error == unsigned.ml.MAV_PARAM_ERROR_PERMISSION_DENIED
    assert ep.stats.received >= 2  # the unsigned heartbeat was accepted
    assert float(loop.law.gains.kp[0]) == 100.0
    signed = Client(port, key=KEY, sysid=254)
    try:
        signed.hello()
        signed.set("J1_KP", 130.0)
        signed.wait(lambda: param_values(signed, "J1_KP"), runner.tick)
        assert param_values(signed, "J1_KP")[-1].param_value == 130.0
        assert float(loop.law.gains.kp[0]) == 130.0
        assert any("signed" in text and "unsigned" not in text for _, _, text in loop.log if "J1_KP 100" in text)
    finally:
        signed.close()
    assert any("refused PARAM_SET J1_KP" in text for _, _, text in loop.log)


def test_signing_wrong_key_is_refused(rig):
    loop, _, runner, ep, c = rig(key=KEY, client_key=key_from_passphrase("wrong"))
    c.set("J1_KP", 130.0)
    # the client cannot check our signatures either: it drops our replies; watch the endpoint
    for _ in range(2000):
        runner.tick()
        if ep.stats.unsigned_refused:
            break
    assert ep.stats.unsigned_refused == 1 and float(loop.law.gains.kp[0]) == 100.0


@pytest.mark.parametrize("allow", [False, True])
def test_signing_unsigned_reads(rig, allow):
    _loop, _, runner, _ep, c = rig(key=KEY, allow_unsigned_read=allow)
    c.read("J1_KP")
    c.wait(lambda: c.of("PARAM_ERROR") or param_values(c), runner.tick)
    if allow:
        assert param_values(c, "J1_KP")[0].param_value == 100.0 and not c.of("PARAM_ERROR")
    else:
        assert c.of("PARAM_ERROR")[0].error == c.ml.MAV_PARAM_ERROR_PERMISSION_DENIED
    assert all(m._header.incompat_flags & 1 for m in c.inbox)  # everything we sent is signed


def test_telemetry_rate_and_content(rig):
    loop, _, runner, _ep, c = rig(rate_hz=25.0)
    c.wait(lambda: c.of("HEARTBEAT"), runner.tick)  # our address is known now
    snapshots = {}
    runner.after_tick.insert(0, lambda lp: snapshots.setdefault(lp.tick_count - 1, (
        dict(lp.last), lp.law.state.ie.copy())))
    k0 = loop.tick_count
    c.inbox.clear()
    for _ in range(250):
        runner.tick()
        c.pump()
    c.wait(lambda: len(c.of("DEBUG_FLOAT_ARRAY")) >= 100, lambda: None)
    arr = c.of("DEBUG_FLOAT_ARRAY")
    assert len(arr) == 250 // 5 * 2  # 25 Hz of loop time at 125 Hz: every 5th tick, one per joint
    times = sorted({m.time_usec for m in arr})
    assert np.all(np.diff(times) == 40000)
    for m in arr:
        k = round(m.time_usec / 8000)
        assert k >= k0
        last, ie = snapshots[k]
        j = m.array_id
        assert m.name == f"J{j + 1}"
        th_d, th = last["theta_d"][j], last["theta"][j]
        assert m.data[0] == pytest.approx(th_d, rel=1e-6, abs=1e-9)
        assert m.data[1] == pytest.approx(th, rel=1e-6, abs=1e-9)
        assert m.data[2] == pytest.approx(th_d - th, rel=1e-5, abs=1e-9)
        assert m.data[5] == pytest.approx(last["torque"][j], rel=1e-5, abs=1e-6)
        assert m.data[7] in (0.0, 1.0) and m.data[11] == 0.0
        assert m.data[9] == pytest.approx(ie[j], rel=1e-5, abs=1e-12)


def test_named_telemetry(rig):
    _loop, _, runner, _ep, c = rig(n=1, rate_hz=125.0, telemetry="named")
    c.wait(lambda: len(c.of("NAMED_VALUE_FLOAT")) >= 24, runner.tick)
    names = [m.name for m in c.of("NAMED_VALUE_FLOAT")[:12]]
    assert names == ["J1_TGT", "J1_POS", "J1_ERR", "J1_VTGT", "J1_VEL", "J1_TAU", "J1_CUR", "J1_INTEG",
                     "J1_KPEFF", "J1_IE", "J1_IV", "J1_FAULT"]


def test_heartbeat_once_per_second_of_loop_time_and_emergency_on_fault(rig):
    loop, io, runner, _ep, c = rig()
    c.wait(lambda: c.of("HEARTBEAT"), runner.tick)
    c.inbox.clear()
    k0 = loop.tick_count
    while loop.tick_count < k0 + 375:
        runner.tick()
        c.pump()
    c.wait(lambda: len(c.of("HEARTBEAT")) >= 3, lambda: None)
    hb = c.of("HEARTBEAT")
    assert len(hb) == 3
    assert {(m.type, m.system_status) for m in hb} == {(c.ml.MAV_TYPE_SERVO, c.ml.MAV_STATE_ACTIVE)}
    assert all(m.base_mode & c.ml.MAV_MODE_FLAG_SAFETY_ARMED for m in hb)
    io.fault[0] = True
    c.inbox.clear()
    c.wait(lambda: c.of("HEARTBEAT") and c.of("STATUSTEXT"), runner.tick)
    assert c.of("HEARTBEAT")[0].system_status == c.ml.MAV_STATE_EMERGENCY
    assert "amplifier_fault" in c.of("STATUSTEXT")[0].text


def test_disarm_safe_stops_the_loop(rig):
    loop, _, runner, _ep, c = rig()
    c.arm(False)
    acks = c.wait(lambda: c.of("COMMAND_ACK"), runner.tick)
    assert acks[0].result == c.ml.MAV_RESULT_ACCEPTED
    assert loop.fault is not None and loop.fault.cause == "operator_stop"


def test_wait_for_start_applies_changes_from_tick_zero_and_starts_on_arm():
    loop, _, runner = fake_loop(1)
    port = free_udp_port()
    ep = MavlinkEndpoint(loop, f"udpin:127.0.0.1:{port}")
    c = Client(port)
    stop = threading.Event()

    def ground_station():
        c.hello()
        c.set("J1_KV", 40.0)
        c.wait(lambda: param_values(c, "J1_KV") or stop.is_set(), lambda: None)
        c.arm(True)

    th = threading.Thread(target=ground_station)
    th.start()
    try:
        assert ep.wait_for_start(5.0)
    finally:
        stop.set()
        th.join(5)
        c.close()
    assert loop.tick_count == 0
    runner.run(1)
    assert float(loop.law.gains.kv[0]) == 40.0
    assert [text for _, _, text in loop.log][-1].startswith("armed")
    ep.close()


def test_wait_for_start_times_out_without_a_client():
    loop, _, _ = fake_loop(1)
    ep = MavlinkEndpoint(loop, f"udpin:127.0.0.1:{free_udp_port()}")
    fake_now = iter(np.arange(0.0, 100.0, 0.25))
    assert not ep.wait_for_start(2.0, clock=lambda: float(next(fake_now)), sleep=lambda s: None)
    assert ep.stats.heartbeats_sent == 2
    ep.close()


def test_a_hammering_client_is_counted_not_logged_entry_by_entry(rig):
    """500 unsigned sets from one client: 500 refusals counted, one log entry."""
    loop, _, runner, ep, unsigned = rig(key=KEY)
    for batch in range(1, 6):  # batches of 100: more at once would overflow the UDP socket buffer
        for _ in range(100):
            unsigned.set("J1_KP", 130.0)
        unsigned.wait(lambda b=batch: ep.stats.unsigned_refused >= 100 * b, runner.tick, timeout_s=60)
    notes = [text for _, source, text in loop.log if source == "mavlink" and "refused" in text]
    assert len(notes) == 1 and "repeats are counted" in notes[0]
    assert sum(ep.stats.refusals.values()) == 500
    assert float(loop.law.gains.kp[0]) == 100.0
