"""The signal catalog and its SPEC grammar (docs/scope.md, "Names" and "SPEC"): the names are the
doc's, written out here; a SPEC item that matches nothing is refused in one line naming the
nearest names."""

from __future__ import annotations

import pytest

from vmehil.scope.catalog import TraceSpecError, build_catalog

CATALOG = build_catalog(["j1", "j2"], analog_nets=["j1.pot", "j2.pot", "loop.dac0.6"],
                        digital_nets=["j1.amp_enable", "j2.amp_enable", "rig.watchdog"],
                        quadrature_nets=["j1.encoder"], truth=True, irq=True, bus=True)

#: docs/scope.md: the controller's signals of one joint, in order
J1 = ["j1.target_rad", "j1.target_rad_s", "j1.position_rad", "j1.velocity_rad_s", "j1.error_rad", "j1.torque_nm",
      "j1.current_cmd_a", "j1.current_a", "j1.integral_e", "j1.integral_edot_rad", "j1.kp_eff", "j1.integrating",
      "j1.stop_state"]


def names(spec: str) -> list[str]:
    return [s.name for s in CATALOG.select(spec)]


def test_a_joint_pattern_chooses_the_controllers_signals_of_that_joint() -> None:
    assert names("j1.*") == J1


def test_a_group_name_alone_chooses_the_whole_group() -> None:
    assert names("j1") == J1
    assert names("net.j1.encoder") == ["net.j1.encoder.counts", "net.j1.encoder.illegal", "net.j1.encoder.index",
                                       "net.j1.encoder.phase"]


def test_items_add_up_in_catalog_order_and_a_minus_item_removes() -> None:
    assert names("net.j2.*,net.j1.pot") == ["net.j1.pot", "net.j2.amp_enable", "net.j2.pot"]
    everything = names("*")
    assert len(everything) == len(CATALOG)
    assert "bus.address" in everything and "irq.IRQ7" in everything
    assert [n for n in names("*,-bus.*,-net.*,-truth.*,-irq.*,-drv.*,-j2.*")] == J1


def test_the_bus_group_is_an_event_stream_with_the_cycle_fields() -> None:
    bus = CATALOG.select("bus.*")
    assert [s.leaf for s in bus] == ["space", "address", "width", "write", "value", "block", "berr", "cycle"]
    assert not any(s.per_tick for s in bus)


def test_a_misspelt_name_is_refused_in_one_line_naming_the_nearest() -> None:
    with pytest.raises(TraceSpecError) as e:
        CATALOG.select("j1.*,j1.posiion_rad")
    text = str(e.value)
    assert "\n" not in text
    assert "'j1.posiion_rad' matches no signal" in text
    assert "nearest: j1.position_rad" in text


def test_a_joint_the_rig_does_not_have_is_refused_naming_the_joints_it_has() -> None:
    with pytest.raises(TraceSpecError, match=r"'j9\.\*' matches no signal; nearest: .*j1\.\*"):
        CATALOG.select("j9.*")


@pytest.mark.parametrize("spec", ["", " , ", "j1.*,-j1.*"])
def test_a_spec_that_chooses_nothing_is_refused(spec: str) -> None:
    with pytest.raises(TraceSpecError):
        CATALOG.select(spec)


def test_a_rig_without_an_emulated_crate_has_the_controller_and_the_drivers_only() -> None:
    real = build_catalog(["j1"])
    assert {s.group for s in real.signals} == {"j1", "drv.j1"}
    with pytest.raises(TraceSpecError):
        real.select("bus.*")
