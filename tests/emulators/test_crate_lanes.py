"""A crate of lanes (batched lockstep, hal.lanes): B scalar crates stacked into one whose
registers and nets carry a value per lane; every lane reads and writes what its own crate would."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from emulators.board import RegisterBoard
from emulators.crate import Crate
from emulators.ram import RamBoard
from hal.lanes import LaneSet
from hal.vme import Access, AddressSpace, Register, RegisterMap, Width

_MAP = RegisterMap(
    "lanetoy", 0x10, AddressSpace.A16,
    (
        Register("CSR", 0x0, Width.D16, Access.RW, also=(Width.D8,)),
        Register("DATA", 0x2, Width.D16, Access.RW),
    ),
)


class LaneToy(RegisterBoard):
    """A board whose lane form is its registers stacked (what RegisterBoard gives)."""

    REGMAP = _MAP

    @classmethod
    def from_lanes(cls, boards: Sequence[Any], crate: Any) -> LaneToy:
        b = cls(boards[0].name)
        b._stack_regs(boards)
        return b


def _crates(data: Sequence[int], net_v: Sequence[float]) -> list[Crate]:
    out = []
    for d, v in zip(data, net_v, strict=True):
        c = Crate("rack")
        c.install(LaneToy("toy"), base=0x100, space="A16")
        c.install(RamBoard("ram", 0x100), base=0x1000, space="A24")
        c.write(0x102, d)  # each instance's own set-up
        c.write(0x100, 0x0101)
        c.signals.set_analog("pot", v)
        c.signals.set_digital("enable", True)
        out.append(c)
    return out


def test_stacked_crate_reads_each_lanes_value_and_common_values_stay_plain() -> None:
    lanes = LaneSet(3)
    crate = Crate.from_lanes(_crates([5, 7, 5], [0.5, -1.25, 0.5]), lanes)
    data = crate.read(0x102)
    assert isinstance(data, np.ndarray) and data.tolist() == [5, 7, 5]
    assert crate.read(0x100) == 0x0101 and type(crate.read(0x100)) is int  # alike in every lane
    assert crate.signals.analog["pot"].tolist() == [0.5, -1.25, 0.5]
    assert crate.signals.digital["enable"] is True
    assert crate.read(0x1000, space="A24") == 0  # the RAM (passive) is lane 0's own


def test_a_lane_write_reaches_each_lane_and_time_and_counters_match_one_crate() -> None:
    lanes = LaneSet(2)
    scalar = _crates([1, 2], [0.0, 0.0])
    crate = Crate.from_lanes(_crates([1, 2], [0.0, 0.0]), lanes)
    crate.write(0x102, np.array([0x10, 0xFFFF]))
    for c, v in zip(scalar, [0x10, 0xFFFF], strict=True):
        c.write(0x102, v)
    assert crate.read(0x102).tolist() == [s.read(0x102) for s in scalar]
    assert crate.clock.now_ns == scalar[0].clock.now_ns == scalar[1].clock.now_ns
    assert dict(crate.counters) == dict(scalar[0].counters)


def test_a_value_that_does_not_fit_leaves_only_its_lane() -> None:
    lanes = LaneSet(3)
    crate = Crate.from_lanes(_crates([1, 2, 3], [0.0] * 3), lanes)
    crate.write(0x102, np.array([4, 0x10000, -1]))  # lanes 1 and 2: VmeValueError in their scalar runs
    assert lanes.alive.tolist() == [True, False, False]
    assert "does not fit D16" in lanes.reasons[1] and 2 in lanes.reasons
    assert int(crate.read(0x102)[0]) == 4


def test_a_float_lane_value_is_truncated_as_int_would_and_nan_leaves_its_lane() -> None:
    lanes = LaneSet(3)
    crate = Crate.from_lanes(_crates([1, 2, 3], [0.0] * 3), lanes)
    crate.write(0x102, np.array([3.9, -0.5, np.nan]))
    assert lanes.alive.tolist() == [True, True, False]
    assert crate.read(0x102)[:2].tolist() == [int(3.9), int(-0.5)]


def test_crates_at_different_points_of_their_program_do_not_stack() -> None:
    a, b = _crates([1, 2], [0.0, 0.0])
    b.read(0x102)  # one more cycle in instance b
    with pytest.raises(NotImplementedError, match="different"):
        Crate.from_lanes([a, b], LaneSet(2))


class NoLanes(RegisterBoard):
    """A board type that declares no lane form (as a plug-in's may not)."""

    TYPE = "nolanes"
    REGMAP = _MAP


def test_a_board_type_without_a_lane_form_refuses_in_one_line() -> None:
    crates = []
    for _ in range(2):
        c = Crate()
        c.install(NoLanes("odd"), base=0x6000, space="A16")
        crates.append(c)
    with pytest.raises(NotImplementedError, match="board type 'nolanes' .* has no lane form"):
        Crate.from_lanes(crates, LaneSet(2))


def test_decide_follows_the_majority_and_leaves_the_others() -> None:
    lanes = LaneSet(5)
    crate = Crate.from_lanes(_crates([1, 1, 2, 1, 2], [0.0] * 5), lanes)
    assert crate.decide(crate.read(0x102) == 1, "data is 1") is True
    assert lanes.alive.tolist() == [True, True, False, True, False]
    assert lanes.reasons == {2: "data is 1", 4: "data is 1"}
    assert crate.decide(crate.read(0x102) == 1, "again") is True  # dead lanes no longer count
    assert Crate().decide(0, "scalar") is False
