"""The controller's CAN link stops a run on what proves the plant node restarted, never on one
frame: a status, heartbeat or session frame of another boot id (a stray frame, a corrupted one,
another session's node) is dropped and counted, and the run is identical. A restarted node (three
frames in a row from its new boot id, none from ours) still stops it (`test_link.py`)."""

from __future__ import annotations

import numpy as np

from emulators.can.bus import open_bus
from tests.emulators.can.test_link import assert_same, pair, reference, run_ticks


def _forged(codec, kind: str, rng: np.random.Generator, boot: int):
    """One frame of the node's own kinds with random fields and boot id ``boot``."""
    if kind == "PLANT_STATUS":
        return codec.frame(kind, Tick=int(rng.integers(0, 2**32)), BootId=boot, NJoints=int(rng.integers(0, 256)),
                           Session=int(rng.integers(0, 16)), ResetAck=int(rng.integers(0, 2)),
                           StepError=int(rng.integers(0, 2)), FreeRunning=int(rng.integers(0, 2)))
    if kind == "HEARTBEAT_PLANT":
        return codec.frame(kind, State=int(rng.integers(0, 256)), BootId=boot, Tick=int(rng.integers(0, 2**32)))
    return codec.frame(kind, Owner=boot, Active=1, Session=int(rng.integers(0, 16)))


def test_frames_of_another_boot_id_between_ticks_are_dropped_and_counted() -> None:
    ref = reference(60)
    rng = np.random.default_rng(8)
    with pair("virtual") as p:
        noise = open_bus("virtual", p.channel, **p.kw)
        got = run_ticks(p.link, 2)
        own = p.link.peer_boot
        try:
            for k in range(2, 60):
                for kind in ("PLANT_STATUS", "HEARTBEAT_PLANT", "PLANT_SESSION"):
                    boot = int(rng.integers(0, 2**16))
                    if boot != own:
                        noise.send(_forged(p.link.codec, kind, rng, boot))
                got += run_ticks(p.link, 1, start=k)
        finally:
            noise.shutdown()
        assert_same(got, ref)
        assert p.link.failed is None
        assert p.link.counters.other_boot >= 2 * 58  # every forged status and heartbeat frame that arrived


def test_restart_evidence_is_a_few_frames_of_one_new_boot_id() -> None:
    from emulators.can.can_plant_link import RESTART_EVIDENCE_FRAMES

    assert 2 <= RESTART_EVIDENCE_FRAMES <= 5  # a restarted node shows within a tick or two; one frame never
