"""Holding brakes over CAN (issue #29): the brake lines travel in the CMD frames
(``HoldingBrake``), and the plant node engages every brake when it loses its controller (its
command timeout). The node is driven frame by frame with a fake clock; the assertions read the
node's plant (its brakes' armatures and the true joint angles), not a flag of the node.
"""

from __future__ import annotations

import numpy as np
import pytest

from emulators.can.codec import CanCodec
from tests.emulators.can.test_node_watchdog import SPEC, Controller

CODEC = CanCodec()


@pytest.fixture
def ctl():
    c = Controller()
    yield c
    c.close()


def _braked() -> np.ndarray:
    return np.array([j in ("j2", "j3", "j4", "j6") for j in SPEC.names])


def test_the_holding_brake_line_is_a_bit_of_the_cmd_frame() -> None:
    from emulators.plant import PlantCommand

    cmd = PlantCommand.idle(SPEC.n_joints)
    cmd.holding_brake[[1, 3]] = True
    frames = CODEC.command_frames(CODEC.command_raw(cmd), 5, 7)
    bits = [CODEC.decode(m).raw["HoldingBrake"] for m in frames]
    assert bits == [0, 1, 0, 1, 0, 0, 0]
    assert all(len(m.data) == 12 and m.is_fd for m in frames)
    back = CODEC.command_from_raw(CODEC.command_raw(cmd), PlantCommand)
    assert np.array_equal(back.holding_brake, cmd.holding_brake)


def test_the_node_releases_the_brakes_its_controller_raises_and_engages_them_on_the_command_timeout(ctl) -> None:
    plant = ctl.node.plant
    braked = _braked()
    assert np.array_equal(plant.brakes_engaged(), braked)  # at rest, no power: held
    ctl.cmd.holding_brake[:] = True  # lines energised, amplifiers enabled (0.2 V)
    for _ in range(10):  # 80 ms > the 60 ms release delay
        ctl.send()
    assert not plant.brakes_engaged().any()
    ctl.clock.t += 0.21  # the controller falls silent beyond the node's 0.2 s command timeout
    assert ctl.node.check_command_timeout()
    assert np.array_equal(plant.brakes_engaged(), braked)
    theta = plant.joint_angle().copy()
    for _ in range(25):  # the controller back with its lines still high: the latched joints stay held
        ctl.send()
    assert np.array_equal(plant.brakes_engaged(), braked)
    moved = np.degrees(np.abs(plant.joint_angle() - theta))
    assert np.all(moved[braked] < 0.05), moved  # they were moving (0.2 V): the brake stops them at once
