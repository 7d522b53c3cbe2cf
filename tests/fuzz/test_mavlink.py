"""Fuzzed MAVLink input never crashes the endpoint (vmehil/mavlink): random bytes, valid messages of
the types it handles with random fields, and PARAM_SET above all (real and mangled parameter
names, any float32 value, signed and unsigned). Property: no handler error, every PARAM_SET meant
for the endpoint is applied or refused exactly once, every parameter stays finite, and after the
fuzzing the endpoint still answers."""

from __future__ import annotations

import math
import socket

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz.harness import refused
from tests.support.fakes import fake_loop
from vmehil.mavlink.client import Client
from vmehil.mavlink.endpoint import MavlinkEndpoint, _mavutil, free_udp_port
from vmehil.mavlink.signing import key_from_passphrase

ml = _mavutil().mavlink
KEY = key_from_passphrase("fuzz")


@pytest.fixture(scope="module", params=[None, KEY], ids=["unsigned", "signed"])
def target(request):
    loop, _, runner = fake_loop(2)
    port = free_udp_port()
    ep = MavlinkEndpoint(loop, f"udpin:127.0.0.1:{port}", key=request.param, rate_hz=25.0)
    runner.after_tick.append(ep.after_tick)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    yield loop, runner, ep, sock, port, request.param
    sock.close()
    ep.close()


def _still_answers(ep, runner, port, key):
    c = Client(port, key=key, sysid=77)
    try:
        c.hello()
        c.read("J1_KP")
        got = c.wait(lambda: [m for m in c.of("PARAM_VALUE") if m.param_id == "J1_KP"], runner.tick, timeout_s=5.0)
        assert got[0].param_count == len(ep.table)
    finally:
        c.close()


def _check(ep, loop):
    assert ep.stats.handler_errors == 0, ep.stats.errors
    assert not [e for e in ep.stats.errors if not e.startswith("receive")], ep.stats.errors


@given(data=st.binary(min_size=0, max_size=300))
def test_random_bytes_never_crash_the_endpoint(target, data):
    loop, runner, ep, sock, port, _ = target
    sock.sendto(data, ("127.0.0.1", port))
    for _ in range(3):
        runner.tick()
    _check(ep, loop)


name = st.binary(min_size=0, max_size=16)
u8 = st.integers(0, 255)
f32 = st.floats(width=32, allow_nan=True, allow_infinity=True)

messages = st.one_of(
    st.builds(lambda ts, tc, n, v, t: ml.MAVLink_param_set_message(ts, tc, n, v, t),
              st.sampled_from([0, 1, 2]), st.sampled_from([0, 1, 5]),
              st.one_of(name, st.sampled_from([b"J1_KP", b"J2_KV", b"J1_SO_BOOST", b"J2_SO_IN", b"J1_TAU_MAX",
                                               b"J1_VEL_MAX", b"SERVO_RATE_HZ", b"J1_SO_EN"])), f32, u8),
    st.builds(lambda ts, tc, n, i: ml.MAVLink_param_request_read_message(ts, tc, n, i),
              st.sampled_from([0, 1]), st.sampled_from([0, 1]), name, st.integers(-32768, 32767)),
    st.builds(lambda ts, tc: ml.MAVLink_param_request_list_message(ts, tc), u8, u8),
    st.builds(lambda ts, tc, cmd, p: ml.MAVLink_command_long_message(ts, tc, cmd, 0, *p),
              st.sampled_from([0, 1]), st.sampled_from([0, 1]),
              st.one_of(st.just(ml.MAV_CMD_COMPONENT_ARM_DISARM), st.integers(0, 65535)),
              st.lists(f32.filter(lambda x: x != 0.0), min_size=7, max_size=7)),
    st.builds(lambda a, b, c, d, e: ml.MAVLink_heartbeat_message(a, b, c, d, e, 3), u8, u8, u8,
              st.integers(0, 2**32 - 1), u8),
)


@given(msg=messages, sign=st.booleans(), src=st.integers(1, 255))
def test_random_valid_messages_never_crash_the_endpoint(target, msg, sign, src):
    loop, runner, ep, sock, port, key = target
    mav = ml.MAVLink(None, srcSystem=src, srcComponent=190)
    if sign and key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = 1
        mav.signing.timestamp = 10**12 + (ep.stats.received + 1) * 1000
    if msg.get_type() == "COMMAND_LONG" and msg.command == ml.MAV_CMD_COMPONENT_ARM_DISARM:
        msg.param1 = 1.0  # a disarm stops the loop (tested elsewhere); keep it running for the fuzzing
    sock.sendto(msg.pack(mav), ("127.0.0.1", port))
    for _ in range(3):
        runner.tick()
    _check(ep, loop)


NAMES = [b"J1_KP", b"J1_KPI", b"J1_KV", b"J1_KVI", b"J2_KP", b"J2_KV", b"J1_SO_BOOST", b"J2_SO_IN", b"J1_SO_EN",
         b"J1_TAU_MAX", b"J1_VEL_MAX", b"SERVO_RATE_HZ", b"J3_KP", b"J0_KP"]
param_name = st.one_of(
    st.sampled_from(NAMES),
    st.sampled_from(NAMES).map(bytes.lower),
    st.tuples(st.sampled_from(NAMES), st.binary(max_size=6)).map(lambda t: (t[0] + t[1])[:16]),
    st.sampled_from(NAMES).map(lambda n: n + b"\x00" * (16 - len(n))),
    st.binary(min_size=0, max_size=16),
)
param_value = st.one_of(f32, st.sampled_from([0.0, -0.0, 1e-45, 3.4e38, -3.4e38, 1.0, -1.0, 1e6, 125.0, 0.5]))


def _settled(ep) -> int:
    return ep.stats.sets_applied + ep.stats.sets_refused + ep.stats.unsigned_refused


@given(pid=param_name, value=param_value, ptype=u8, ts=st.sampled_from([0, 1, 2]), tc=st.sampled_from([0, 1, 5]),
       sign=st.booleans())
def test_param_set_is_applied_or_refused_once_and_parameters_stay_finite(target, pid, value, ptype, ts, tc, sign):
    loop, runner, ep, sock, port, key = target
    mav = ml.MAVLink(None, srcSystem=200, srcComponent=190)
    if sign and key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = 2
        mav.signing.timestamp = 2 * 10**12 + (ep.stats.received + 1) * 1000
    before, refused_before = _settled(ep), ep.stats.sets_refused + ep.stats.unsigned_refused
    sock.sendto(ml.MAVLink_param_set_message(ts, tc, pid, value, ptype).pack(mav), ("127.0.0.1", port))
    for_me = ts in (0, ep.sysid) and tc in (0, ep.compid)
    for _ in range(20):  # the change is applied at a tick boundary and answered at the next service
        runner.tick()
        if _settled(ep) > before:
            break
    _check(ep, loop)
    assert _settled(ep) - before == (1 if for_me else 0), (pid, value, ep.stats)
    if ep.stats.sets_refused + ep.stats.unsigned_refused > refused_before:
        refused("PARAM_SET refused")
    for i in range(len(ep.table)):
        v = ep.table.value(ep.table.at(i))
        assert math.isfinite(v), (ep.table.at(i).name, v)


def test_endpoint_still_answers_after_fuzzing(target):
    loop, runner, ep, _sock, port, key = target
    _still_answers(ep, runner, port, key)
    _check(ep, loop)
