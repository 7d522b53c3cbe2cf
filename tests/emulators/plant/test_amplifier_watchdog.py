"""The amplifiers' enable watchdog (charge pump) in the plant, on simulated time.

A line the controller toggles every servo period keeps the enable chain closed; when the edges
stop for ``timeout_s`` every enabled amplifier is latched off until its enable rises again while
the line toggles. The plant node's command timeout latches through the same path.
"""

from __future__ import annotations

import numpy as np
import pytest

from emulators.plant import Plant, PlantParams, load_plant_params, plant_params_from_config
from emulators.plant.amplifier import WATCHDOG_COMMAND_TIMEOUT, WATCHDOG_EXPIRED, EnableWatchdog
from hal.config import ConfigError, ConfigTable

T = 0.008  # servo period (s)
DELAY = 0.001  # computation delay: the command, and the line's edge, take effect here
TIMEOUT = 0.05


def _plant(timeout_s: float | None = TIMEOUT) -> Plant:
    j1 = load_plant_params("jpl-arm").joints[0]
    hand = load_plant_params("jpl-arm").joints[6]
    return Plant(PlantParams(joints=[j1, hand], watchdog_timeout_s=timeout_s), seed=5)


class Driver:
    """Commands a plant period by period: 0.5 V on the linear amplifier, 30 % duty on the H-bridge."""

    def __init__(self, plant: Plant) -> None:
        self.plant = plant
        self.cmd = plant.idle_command()
        self.cmd.amp_command_v[0] = 0.5
        self.cmd.pwm_duty[1] = 0.3
        self.k = 0

    def step(self, *, enable: bool = True, toggle: bool = True):
        self.cmd.amp_enable[:] = enable
        if toggle:
            self.cmd.watchdog_line = not self.cmd.watchdog_line
        s = self.plant.step_period(self.cmd, T, DELAY)
        self.k += 1
        return s

    def edge_time_s(self) -> float:
        """When the command of the period just stepped took effect."""
        return (self.k - 1) * T + DELAY


def test_a_line_toggled_every_period_changes_nothing():
    with_wd, without = Driver(_plant()), Driver(_plant(None))
    for _ in range(250):
        a, b = with_wd.step(), without.step()
        assert np.array_equal(a.truth["current_a"], b.truth["current_a"])
        assert np.array_equal(a.pot_v, b.pot_v) and a.encoder == b.encoder
        assert a.truth["amp_enabled"].all() and not a.truth["amp_watchdog_tripped"].any()
    assert with_wd.plant.watchdog.trips == 0


def test_enables_drop_timeout_s_after_the_last_edge_and_the_current_decays():
    d = Driver(_plant())
    for _ in range(10):
        s = d.step()
    last_edge = d.edge_time_s()
    assert s.truth["current_a"][0] == pytest.approx(1.5, rel=1e-3)
    ends, enabled = [], []
    while d.k < 40:
        s = d.step(toggle=False)
        ends.append(d.k * T)
        enabled.append(bool(s.truth["amp_enabled"][0]))
        if not enabled[-1]:
            break
    # on through every period that ends before the pump runs out, off in the period it runs out
    assert all(enabled[:-1]) and not enabled[-1]
    assert last_edge + TIMEOUT <= ends[-1] < last_edge + TIMEOUT + T
    assert ends[-2] < last_edge + TIMEOUT
    assert s.truth["current_a"].tolist() == [0.0, 0.0]  # both output stages open
    assert s.truth["amp_watchdog_cause"].tolist() == [WATCHDOG_EXPIRED, WATCHDOG_EXPIRED]
    assert not s.amp_fault.any()  # a watchdog trip is not an amplifier fault


def test_the_trip_happens_at_the_substep_the_pump_runs_out():
    wd = EnableWatchdog(1, TIMEOUT)
    wd.command(True, np.ones(1, bool), np.zeros(1, bool), 0.001)
    h = T / 32
    # 0.001 + 0.05 = 0.051 s lies 12 substeps into the period starting at 0.048 s
    assert wd.expiry_substep(0.048, h, 32) == 12
    assert wd.expiry_substep(0.040, h, 32) == -1
    assert wd.expiry_substep(0.056, h, 32) == 0  # already out


def test_a_tripped_amplifier_stays_off_until_its_enable_rises_while_the_line_toggles():
    d = Driver(_plant())
    d.step()
    for _ in range(10):
        s = d.step(toggle=False)
    assert not s.truth["amp_enabled"].any()
    for _ in range(5):  # the controller comes back and toggles, enables still high: no re-arm
        s = d.step()
    assert not s.truth["amp_enabled"].any() and s.truth["current_a"][0] == 0.0
    s = d.step(enable=False, toggle=False)  # enable low, then high without toggling: no re-arm
    for _ in range(10):
        s = d.step(toggle=False)
    assert not s.truth["amp_enabled"].any()
    s = d.step(enable=False)  # low → high after the line toggles again: re-armed
    s = d.step()
    assert s.truth["amp_enabled"].all() and not s.truth["amp_watchdog_tripped"].any()
    assert s.truth["current_a"][0] == pytest.approx(1.5, rel=1e-3)


def test_fault_reset_does_not_clear_a_watchdog_trip():
    d = Driver(_plant())
    d.step()
    for _ in range(10):
        d.step(toggle=False)
    d.cmd.fault_reset[:] = True
    s = d.step()
    assert s.truth["amp_watchdog_tripped"].all() and not s.amp_fault.any()


def test_disabling_before_the_pump_stops_trips_nothing():
    """A safe stop: enables low in the same tick the drivers stop toggling."""
    d = Driver(_plant())
    for _ in range(20):
        d.step()
    for _ in range(40):
        s = d.step(enable=False, toggle=False)
    assert not s.truth["amp_watchdog_tripped"].any() and d.plant.watchdog.trips == 0
    s = d.step(enable=True)  # the drivers re-enable together with the first toggle
    assert s.truth["amp_enabled"].all()


def test_an_enable_raised_into_a_dead_pump_is_latched_off():
    d = Driver(_plant())
    d.step(enable=False)  # the pump ran once, then stopped
    for _ in range(10):
        d.step(enable=False, toggle=False)
    s = d.step(toggle=False)
    assert s.truth["amp_watchdog_cause"].tolist() == [WATCHDOG_EXPIRED, WATCHDOG_EXPIRED]
    assert s.truth["current_a"].tolist() == [0.0, 0.0]


def test_a_pump_that_never_ran_holds_nothing_off():
    """The watchdog arms at its line's first edge: a plant driven without a controller (tests,
    benchmarks) behaves as before."""
    d = Driver(_plant())
    for _ in range(50):
        s = d.step(toggle=False)
    assert s.truth["amp_enabled"].all()


def test_without_a_watchdog_the_line_is_ignored():
    d = Driver(_plant(None))
    d.step()
    for _ in range(50):
        s = d.step(toggle=False)
    assert s.truth["amp_enabled"].all() and d.plant.watchdog.trips == 0


def test_holding_the_amplifiers_off_latches_the_enabled_ones_with_its_cause():
    d = Driver(_plant(None))  # the plant node's command timeout works with or without a pump
    d.cmd.amp_enable[:] = [True, False]
    d.plant.step_period(d.cmd, T, DELAY)
    latched = d.plant.hold_amplifiers_off(WATCHDOG_COMMAND_TIMEOUT)
    assert latched.tolist() == [True, False]
    assert d.plant.amplifier_enabled().tolist() == [False, False]
    assert d.plant.amplifier_watchdog_cause().tolist() == [WATCHDOG_COMMAND_TIMEOUT, 0]
    s = d.plant.step_period(d.cmd, T, DELAY)  # the first period after the hold is already off
    assert s.truth["current_a"][0] == 0.0
    d.step(enable=False)
    s = d.step()
    assert s.truth["amp_enabled"].all()


def _rig_table(watchdog: dict) -> ConfigTable:
    return ConfigTable({"rig": {"watchdog": watchdog}, "joint": [{"name": "j1"}]}, "test.toml")


def test_rig_watchdog_table_sets_the_timeout_and_its_absence_none():
    assert plant_params_from_config(_rig_table({"line": "pio0:PB7", "timeout_s": 0.05})).watchdog_timeout_s == 0.05
    assert plant_params_from_config(ConfigTable({"joint": [{"name": "j1"}]}, "t.toml")).watchdog_timeout_s is None
    with pytest.raises(ConfigError, match="timeout"):
        plant_params_from_config(_rig_table({"line": "pio0:PB7", "timeout_s": 0.0}))
    with pytest.raises(ConfigError, match="timeout_ms"):
        plant_params_from_config(_rig_table({"line": "pio0:PB7", "timeout_ms": 50}))


def test_the_presets_have_a_watchdog():
    for rig in ("jpl-arm", "melmalec-16"):
        p = load_plant_params(rig)
        assert p.watchdog_timeout_s is not None and p.watchdog_timeout_s > 1 / 125.0, rig
