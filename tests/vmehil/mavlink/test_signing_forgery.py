"""One forged frame with a future timestamp must not lock the signed ground station out: the
signature is verified before the stream's timestamp is recorded. Refused PARAM_SETs are counted,
not logged one by one."""

from __future__ import annotations

import os

os.environ.setdefault("MAVLINK20", "1")

import pytest
from pymavlink.dialects.v20 import common as mavlink

from vmehil.mavlink.signing import install_verified_signature_check, key_from_passphrase

KEY = key_from_passphrase("genuine")


class _Sink:
    def write(self, b: bytes) -> None:  # pymavlink's MAVLink wants a file to send to
        pass


def _signer(key: bytes, timestamp: int):
    m = mavlink.MAVLink(_Sink(), srcSystem=255, srcComponent=190)
    m.signing.secret_key = key
    m.signing.sign_outgoing = True
    m.signing.link_id = 0
    m.signing.timestamp = timestamp
    return m


def _frame(sender) -> bytes:
    msg = mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3)
    return bytes(msg.pack(sender))


def _receiver(verified: bool):
    r = mavlink.MAVLink(_Sink(), srcSystem=1, srcComponent=1)
    r.signing.secret_key = KEY
    r.signing.timestamp = 1_000_000
    r.signing.allow_unsigned_callback = lambda mav, msg_id: False
    if verified:
        install_verified_signature_check(r)
    return r


def _accepted(receiver, frame: bytes) -> bool:
    try:
        msgs = receiver.parse_buffer(frame) or []
    except mavlink.MAVError:
        return False
    return any(getattr(m, "_signed", False) and m.get_type() == "HEARTBEAT" for m in msgs)


@pytest.mark.parametrize("verified", [True, False], ids=["ours", "pymavlink-as-shipped"])
def test_a_forged_future_timestamp_does_not_lock_out_the_ground_station(verified) -> None:
    rx = _receiver(verified)
    genuine = _signer(KEY, 2_000_000)
    assert _accepted(rx, _frame(genuine))
    forged = _frame(_signer(key_from_passphrase("forger"), 2_000_000 + 10**12))  # far in the future
    assert not _accepted(rx, forged)
    later = _frame(genuine)  # the ground station carries on with its own clock
    assert _accepted(rx, later) is verified  # as shipped, pymavlink locks it out


def test_replays_and_old_timestamps_are_still_refused() -> None:
    rx = _receiver(True)
    gs = _signer(KEY, 5_000_000)
    first = _frame(gs)
    assert _accepted(rx, first)
    assert not _accepted(rx, first)  # the same frame again: a replay
