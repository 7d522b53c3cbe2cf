"""SENS.EncoderTotal (emulators.can.codec.EncoderTotals): the counts of answers a receiver never
got come back with the next one it gets — through the frames, across the 32-bit wrap."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from emulators.can.codec import EncoderTotals, shared_codec
from emulators.signals import QuadratureEvents

CODEC = shared_codec()
COUNT = st.integers(-(2**23), 2**23 - 1)


def _sens_frames(counts: list[int], seq: int, totals) -> dict[int, dict]:
    """One answer's SENS frames, encoded and decoded (raw values by joint)."""
    n = len(counts)
    raw = {k: [0] * n for k in ("PotVoltage", "TachVoltage", "CurrentMonitor", "EncoderIllegal", "EncoderPhase",
                                 "AmpFault", "Switching", "IndexCount", "IndexFirst", "IndexLast")}
    raw["EncoderCounts"] = counts
    frames = CODEC.sensor_frames(raw, seq, totals=totals)
    return {int(f.joint): f.raw for f in map(CODEC.decode, frames)}


@given(st.lists(st.tuples(st.lists(COUNT, min_size=2, max_size=2), st.booleans()), min_size=1, max_size=40),
       st.integers(0, 2**32 - 1))
def test_the_counts_received_add_up_to_every_count_sent_whatever_was_lost(answers, start) -> None:
    """Up to the last answer received, the receiver's counts add up to the sender's, from the
    first answer it got on (the reference), however many answers between were lost."""
    sender, receiver = EncoderTotals(), EncoderTotals()
    sent = [0, 0]  # the counts sent after the first answer received
    sent_until_received = [0, 0]
    got = [0, 0]
    first = True
    for k, (counts, arrives) in enumerate(answers):
        totals = sender.add([QuadratureEvents(counts=c) for c in counts])
        if k == 0:  # start anywhere on the 32-bit circle: the wrap is the receiver's business
            sender.total = totals = (totals + start) & (2**32 - 1)
        if not first:
            sent = [s + c for s, c in zip(sent, counts, strict=True)]
        if not arrives and not first:
            continue
        sens = _sens_frames(counts, k, totals)
        decoded = [QuadratureEvents(counts=int(sens[j]["EncoderCounts"])) for j in (0, 1)]
        events = receiver.recover(sens, [0, 1], decoded)
        if first:  # the first answer received is the reference: its own counts stand
            first = False
            continue
        got = [g + e.counts for g, e in zip(got, events, strict=True)]
        sent_until_received = list(sent)
    assert got == sent_until_received
    assert receiver.recovered <= sum(1 for _, a in answers if not a)


def test_a_sender_without_totals_leaves_the_frames_counts_alone() -> None:
    receiver = EncoderTotals()
    for k, counts in enumerate(([5, -3], [7, 1], [0, 2])):
        sens = _sens_frames(counts, k, None)
        events = receiver.recover(sens, [0, 1], [QuadratureEvents(counts=c) for c in counts])
        assert [e.counts for e in events] == counts
    assert receiver.recovered == 0
