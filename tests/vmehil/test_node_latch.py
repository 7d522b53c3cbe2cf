"""The controller learns the plant node's own amplifier latch from its status frame and stops with
that cause (it stopped on `current_mismatch … no current reaches the motor?` ticks later, without
naming the node's latch). In-process plant node on python-can's virtual bus; no network."""

from __future__ import annotations

import time

from servo.runner import LockstepRunner
from tests.support.boards import driving
from vmehil.option_groups.can_options import CanPlantOptions
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig


def test_the_controller_stops_with_the_nodes_latch_named_when_its_command_timeout_fires() -> None:
    link = CanPlantOptions("virtual", "node-latch", own_node=True).open_link("jpl-arm", 0)
    system = build_emulated_rig("jpl-arm", seed=0, link=link)
    try:
        loop = build_loop(system, n_ticks=100)
        loop.start()
        runner = LockstepRunner(system, loop)
        runner.run(20)
        assert driving(system) and loop.fault is None
        node = link.node.node
        node.command_timeout_s = 0.05  # the controller now "hangs": no SYNC while this test waits
        deadline = time.monotonic() + 60.0  # generous: waits for the condition, not for a time
        while not node.command_timed_out:
            assert time.monotonic() < deadline, "the node's command timeout never came into force"
            time.sleep(0.01)
        runner.run(5)
        assert loop.fault is not None and loop.fault.cause == "amplifiers_latched", loop.fault
        assert "command timeout" in loop.fault.detail
        assert not driving(system)  # the stop the cause brought: every enable low on the boards
    finally:
        system.close()
