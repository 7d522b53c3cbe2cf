"""`Endpoint.recv` skips the node's own frames looped back by the bus (udp_multicast does that)
without ending a poll early: a frame from the other node queued behind them is still returned by
`recv(0)`. Before, a poll returned "nothing" at the first own frame, so a free-running link that
polls stopped draining at its own frames and its answers went stale (docs/can.md)."""

from __future__ import annotations

import itertools

import can

from emulators.can.bus import Endpoint

_channels = itertools.count()


def _pair() -> tuple[Endpoint, can.BusABC]:
    chan = f"endpoint-poll-{next(_channels)}"
    mine = can.Bus(interface="virtual", channel=chan, receive_own_messages=True)
    other = can.Bus(interface="virtual", channel=chan)
    return Endpoint(mine, own_ids={0x10, 0x11}), other


def test_a_poll_returns_the_peers_frame_queued_behind_our_own_looped_back_frames() -> None:
    ep, other = _pair()
    try:
        for own in (0x10, 0x11, 0x10):
            ep.send(can.Message(arbitration_id=own, data=b"\x00", is_extended_id=False))
        other.send(can.Message(arbitration_id=0x20, data=b"\x01", is_extended_id=False))
        got = ep.recv(0)
        assert got is not None and got.arbitration_id == 0x20
        assert ep.recv(0) is None  # nothing left: the poll ends, it does not wait
    finally:
        ep.bus.shutdown()
        other.shutdown()


def test_a_poll_over_only_our_own_frames_returns_nothing() -> None:
    ep, other = _pair()
    try:
        for own in (0x10, 0x11):
            ep.send(can.Message(arbitration_id=own, data=b"\x00", is_extended_id=False))
        assert ep.recv(0) is None
        assert ep.received == 0
    finally:
        ep.bus.shutdown()
        other.shutdown()
