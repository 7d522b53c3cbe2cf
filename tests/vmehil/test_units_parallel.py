"""MELMALEC's five unit controllers in parallel (threads, one plant in lockstep): the key check
is bit-identity with the single controller of all sixteen joints for the same seed."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from servo.runner import LockstepRunner
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig
from vmehil.unit_controllers.coordinator import run_units
from vmehil.unit_controllers.options import MergedUnits

N_TICKS = 250


def single_run(seed: int, n_ticks: int) -> dict[str, np.ndarray]:
    system = build_emulated_rig("melmalec-16", seed=seed)
    loop = build_loop(system, n_ticks=n_ticks)
    with loop.armed():
        LockstepRunner(system, loop).run(n_ticks)
    assert loop.fault is None
    system.close()
    return loop.recorder.trimmed()


@pytest.mark.slow
def test_parallel_units_in_lockstep_equal_the_single_controller_bit_for_bit() -> None:
    ref = single_run(3, N_TICKS)
    run = run_units("melmalec-16", seed=3, n_ticks=N_TICKS)
    try:
        assert all(u.error is None and u.completed == N_TICKS for u in run.units)
        assert all(u.loop.fault is None for u in run.units)
        got = run.recorded()
        for key in ref:
            if key == "compute_s":
                continue
            assert np.array_equal(ref[key], got[key], equal_nan=True), key
        moved = np.degrees(np.abs(got["theta_true"][-1] - got["theta_true"][0]))
        assert np.all(moved > 1.0)  # every joint really moved: the check compares motion, not rest
        assert all(u.loop.run_ticks == N_TICKS for u in run.units)
        # power-up + one per tick, each with every unit in; then each unit's end (its category-1
        # stop and the 2 s after it) while the longest still ticks
        assert run.hub.exchanges == 1 + max(u.loop.tick_count for u in run.units)
    finally:
        run.close()


@pytest.mark.slow
def test_parallel_units_with_the_plant_node_over_can_equal_the_single_controller() -> None:
    """The plant of all 16 joints as the CAN plant node (python-can `virtual`, a node thread),
    stepped by the hub once every unit's commands are in: still bit-identical."""
    from vmehil.option_groups.can_options import CanPlantOptions

    n = 120
    ref = single_run(4, n)
    link = CanPlantOptions(interface="virtual", channel="melmalec-units", own_node=True).open_link("melmalec-16", 4)
    run = run_units("melmalec-16", seed=4, n_ticks=n, link=link)
    try:
        assert all(u.error is None and u.completed == n and u.loop.fault is None for u in run.units)
        got = run.recorded()
        for key in ref:
            if key != "compute_s":
                assert np.array_equal(ref[key], got[key], equal_nan=True), key
    finally:
        run.close()


# --- faults: every unit stops; the checks read the boards' outputs and the plant's amplifiers --
class BoardProbe:
    """After every tick of every unit: are all the unit's amplifier enables low (PIO lines), its
    DAC outputs at 0 V once settled (the board's output at now + its settling time, a few µs)
    and its PWM duty 0, on its own boards?"""

    def __init__(self) -> None:
        self.off: dict[str, dict[int, bool]] = {}

    def __call__(self, name: str, system, loop) -> None:
        s = system.crate.signals
        off = True
        for j in system.rig.joints:
            if "amp_enable" in j.wiring and s.get_digital(j.net("amp_enable")):
                off = False
            if "pwm" in j.wiring and s.get_analog(j.net("pwm")) != 0.0:
                off = False
            if "amp_command" in j.wiring:
                pin = j.wiring["amp_command"]
                dac = system.crate.boards[pin.board]
                if dac.output_volts(pin.index, dac.now_ns + dac.settling_time_ns) != 0.0:
                    off = False
        self.off.setdefault(name, {})[loop.tick_count - 1] = off

    def first_off(self, name: str) -> int:
        """The first tick from which the unit's boards stayed off to the end."""
        seen = self.off[name]
        return min(k for k, off in seen.items() if off and all(seen[i] for i in seen if i >= k))


@contextmanager
def hub_captured(holder: dict) -> Iterator[dict]:
    """While in the block, the PlantHub run_units makes is also put in ``holder["hub"]``."""
    import vmehil.unit_controllers.coordinator as coordinator

    original = coordinator.PlantHub

    def capture(*a, **kw):
        holder["hub"] = original(*a, **kw)
        return holder["hub"]

    coordinator.PlantHub = capture  # type: ignore[misc]
    try:
        yield holder
    finally:
        coordinator.PlantHub = original  # type: ignore[misc]


def chain(*hooks):
    def run_all(name, system, loop):
        for h in hooks:
            h(name, system, loop)
    return run_all


def test_a_fault_in_one_unit_stops_every_unit_in_the_same_tick() -> None:
    """leg2's loop safe-stops in tick 100: every other unit safe-stops in tick 100 too (its own
    boards: enables low, 0 V), the plant has leg2's amplifiers off from exchange 101 (tick 100)
    and every amplifier off from the next."""
    probe = BoardProbe()

    def inject(name, system, loop):
        if name == "leg2" and loop.tick_count == 100:
            loop.submit(lambda lp: lp.safe_stop("injected", "test: a fault in unit leg2"))

    run = run_units("melmalec-16", seed=1, n_ticks=140, after_tick=chain(inject, probe))
    try:
        for u in run.units:
            assert probe.off[u.unit.name][99] is False  # moving, amplifiers on, before the fault
            assert probe.first_off(u.unit.name) == 100, u.unit.name
            # a stop at the boundary (after tick 100's exchange) is recorded with the loop's
            # counter already at 101, as any plant-boundary stop is (servo.runner)
            assert u.loop.fault.tick == (100 if u.unit.name == "leg2" else 101)
            assert u.loop.fault.cause == ("injected" if u.unit.name == "leg2" else "unit_stop")
        on = run.hub.amps_on  # index = exchange: 0 power-up, k + 1 after tick k
        assert on[100] == 16 and on[101] == 13 and all(x == 0 for x in on[102:])
        assert run.hub.stop.unit == "leg2" and run.hub.stop.exchange == 101
    finally:
        run.close()


def test_a_unit_that_dies_with_an_exception_stops_every_unit_within_one_tick() -> None:
    probe = BoardProbe()

    def die(name, system, loop):
        if name == "leg4" and loop.tick_count == 81:
            raise RuntimeError("test: unit leg4 dies")

    run = run_units("melmalec-16", seed=1, n_ticks=120, after_tick=chain(probe, die))
    try:
        leg4 = next(u for u in run.units if u.unit.name == "leg4")
        assert leg4.loop.fault.cause == "exception" and leg4.completed == 80
        probe("leg4", leg4.system, leg4.loop)  # its runner ended: read its boards as they were left
        assert probe.off["leg4"][leg4.loop.tick_count - 1] is True
        for u in run.units:
            assert probe.off[u.unit.name][79] is False
            if u is not leg4:  # the others stop in the tick the dead unit's stop reached the plant
                assert probe.first_off(u.unit.name) == 81, u.unit.name
                assert u.loop.fault.cause == "unit_stop"
        assert all(x == 0 for x in run.hub.amps_on[83:])  # the plant: all off within 2 exchanges
        # as the single run after an exception: the dead unit's loop still reads its joints for
        # 2 s after its stop (its excursion), its amplifiers off
        assert leg4.loop.tick_count >= 81 + 250 and leg4.loop.final_stop["category"] == 0
        assert set(leg4.loop.final_stop["excursion_deg"]) == set(leg4.unit.joints)
    finally:
        run.close()


@pytest.mark.slow
def test_a_silent_unit_is_declared_lost_its_amplifiers_cut_and_every_unit_stops() -> None:
    """leg3 hangs after tick 50 (it waits until the hub has declared it lost — no sleep). The
    others wait timeout_s for its tick-51 commands, the plant steps with leg3's amplifiers off,
    and every other unit safe-stops in tick 51; leg3, when it comes back, refuses to go on."""
    probe = BoardProbe()
    holder: dict = {}

    def hang(name, system, loop):
        if name == "leg3" and loop.tick_count == 51:
            assert holder["hub"].lost.wait(timeout=60.0)

    with hub_captured(holder):
        # 3 s: far above any pause a loaded machine gives a healthy unit; leg3 waits for the verdict
        run = run_units("melmalec-16", seed=1, n_ticks=90, timeout_s=3.0, after_tick=chain(probe, hang))
    try:
        for u in run.units:
            assert probe.off[u.unit.name][50] is False
            assert probe.first_off(u.unit.name) == 51, u.unit.name
            assert u.loop.fault.cause == "unit_lost"
        on = run.hub.amps_on
        assert on[51] == 16 and on[52] == 13 and all(x == 0 for x in on[53:])
        assert run.hub.stop.unit == "leg3" and run.hub.stop.what.startswith("lost")
    finally:
        run.close()


def test_a_rig_without_units_is_refused_for_parallel_runs() -> None:
    from vmehil.unit_controllers.coordinator import UnitsRefused

    with pytest.raises(UnitsRefused, match="no \\[\\[rig.unit\\]\\] tables"):
        run_units("jpl-arm", n_ticks=10)


def test_an_abort_stops_every_unit_from_its_next_tick_by_category_1() -> None:
    """What Ctrl-C / SIGTERM to the coordinator does (it sets the abort event): every unit
    begins a category-1 stop at its next tick boundary (as the single run does for a signal),
    its brakes hold and its boards read off; then it watches its joints for 2 s."""
    import threading

    probe = BoardProbe()
    abort = threading.Event()

    def hook(name, system, loop):
        if name == "leg1" and loop.tick_count == 60:
            abort.set()

    run = run_units("melmalec-16", seed=1, n_ticks=1500, after_tick=chain(probe, hook), abort=abort)
    try:
        for u in run.units:
            name, loop = u.unit.name, u.loop
            assert loop.fault is not None and loop.fault.cause == "interrupted", name
            stop = loop.final_stop
            assert stop["verified"] and stop["category"] == 1 and stop["fell_to_0"] is None, name
            probe(name, u.system, loop)  # the boards as the unit left them
            assert probe.off[name][loop.tick_count - 1] is True, name
            assert 60 <= loop.run_ticks <= 62  # its stop began within a tick or two of the abort
            assert probe.off[name][loop.run_ticks] is False  # decelerating: powered
            off = probe.first_off(name)
            assert loop.tick_count - off >= 250  # then 2 s watched (the run's 1500 ticks are not run)
            assert loop.tick_count < 1500
        # each unit's own end: no unit told the others to stop, none cut another's window short
        assert run.hub.stop is None
    finally:
        run.close()


def test_ctrl_c_to_the_coordinator_leaves_every_unit_safe_stopped_and_goes_on() -> None:
    """A real KeyboardInterrupt in the main thread (interrupt_main, with Python's own SIGINT
    handler): run_units sets the abort, joins every unit and re-raises; every unit's boards
    read off."""
    import _thread
    import signal

    seen: dict = {}
    probe = BoardProbe()

    def hook(name, system, loop):
        seen[name] = (system, loop)
        if name == "leg1" and loop.tick_count == 60:
            _thread.interrupt_main()

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            run_units("melmalec-16", seed=1, n_ticks=1500, after_tick=hook)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert sorted(seen) == sorted(("leg1", "leg2", "leg3", "leg4", "arm"))
    for name, (system, loop) in seen.items():
        assert loop.final_stop is not None and loop.final_stop["verified"], name
        probe(name, system, loop)
        assert probe.off[name][loop.tick_count - 1] is True, name
    for system, _ in seen.values():
        system.close()


class EndProbe:
    """After every tick of every unit, from its own boards and the plant's truth: whether any
    amplifier enable is high, whether any holding-brake line is high, the true joint angles."""

    def __init__(self) -> None:
        self.enabled: dict[str, list[bool]] = {}
        self.released: dict[str, list[bool]] = {}
        self.theta: dict[str, list[np.ndarray]] = {}

    def __call__(self, name: str, system, loop) -> None:
        s = system.crate.signals
        joints = system.rig.joints
        self.enabled.setdefault(name, []).append(any(s.get_digital(j.net("amp_enable")) for j in joints
                                                     if "amp_enable" in j.wiring))
        self.released.setdefault(name, []).append(any(s.get_digital(j.net("holding_brake")) for j in joints
                                                      if "holding_brake" in j.wiring))
        self.theta.setdefault(name, []).append(system.truth()["theta_joint"].copy())


@pytest.mark.slow
def test_every_unit_ends_the_run_as_the_single_run_does_category_1_then_2_s_watched() -> None:
    """The run's end (issue #29): each unit decelerates, drops its brake lines with its
    amplifiers still on, powers off one engage delay (40 ms) later, then keeps reading for 2 s;
    the merged final stop reports category 1 and every joint's excursion, as the single
    controller's end does (its figures: an independent run of the same seed)."""
    from tests.support.boards import assert_boards_safe

    n, period = 250, 1 / 125
    probe = EndProbe()
    run = run_units("melmalec-16", seed=3, n_ticks=n, after_tick=probe)
    try:
        for u in run.units:
            name, loop = u.unit.name, u.loop
            assert u.error is None and loop.fault is None and loop.run_ticks == n, name
            stop = loop.final_stop
            assert stop["category"] == 1 and stop["cause"] == "end" and stop["verified"], name
            on = probe.enabled[name]  # index k: after tick k
            off = next(k for k in range(n, len(on)) if not on[k])
            assert all(on[:off]), name  # powered until then: decelerating, at rest, brakes engaging
            assert (len(on) - 1 - off) * period >= 2.0 - 1e-9, name  # then 2 s watched
            if name.startswith("leg"):  # the legs' lifts and knees have holding brakes
                rel = probe.released[name]
                brakes = next(k for k in range(n, len(rel)) if not rel[k])
                assert (brakes - n) * period >= 0.1  # after decelerating and 0.1 s at rest
                assert (off - brakes) * period >= 0.04 - 1e-9  # amplifiers on through the engage delay
                assert u.system.truth()["brake_engaged"][[1, 2]].all()
            assert_boards_safe(u.system)
            # the excursion reported is the truth's movement from the stop's beginning
            th = np.asarray(probe.theta[name])
            moved = np.degrees(np.abs(th[n - 1:] - th[n - 1]).max(axis=0))
            got = [stop["excursion_deg"][j] for j in u.unit.joints]
            np.testing.assert_allclose(got, moved, atol=0.05)
        merged = MergedUnits(run)
        final = merged.final_stop
        assert final["category"] == 1 and final["cause"] == "end" and merged.run_ticks == n
        assert list(final["excursion_deg"]) == [j.name for j in run.rig.joints]
        assert list(final["excursion_sensor_deg"]) == [j.name for j in run.rig.joints]
    finally:
        run.close()
    # the single controller of every joint, the same seed, the same end
    system = build_emulated_rig("melmalec-16", seed=3)
    try:
        loop = build_loop(system, n_ticks=n)
        runner = LockstepRunner(system, loop)
        with loop.armed():
            runner.run(n)
            runner.end_run()
        single = loop.final_stop["excursion_deg"]
    finally:
        system.close()
    # the legs' stops are timed alike; the arm's unit brings its own joints to rest sooner
    for j in run.rig.joints:
        assert final["excursion_deg"][j.name] == pytest.approx(single[j.name], abs=0.05), j.name


def test_a_second_interrupt_during_the_units_end_makes_their_stops_category_0_and_ends_the_window() -> None:
    """Ctrl-C twice at the coordinator (with Python's own SIGINT handler): the first begins every
    unit's category-1 stop, the second — while they decelerate — removes power at once (category
    0, as the single run's second signal) and ends the 2 s window; run_units re-raises. (leg1's
    hook waits until the main thread has taken each interrupt: lockstep holds every unit there.)"""
    import _thread
    import signal
    import threading

    seen: dict = {}
    probe = BoardProbe()
    abort, cut = threading.Event(), threading.Event()
    sent: list[int] = []

    def hook(name, system, loop):
        seen[name] = (system, loop)
        if name != "leg1":
            return
        if loop.tick_count == 60:
            sent.append(loop.tick_count)
            _thread.interrupt_main()
            assert abort.wait(10.0)
        elif loop.stopping is not None and not cut.is_set() and len(sent) == 1:
            sent.append(loop.tick_count)  # decelerating, powered: the second interrupt
            assert system.crate.signals.get_digital(system.rig.joints[1].net("amp_enable"))
            _thread.interrupt_main()
            assert cut.wait(10.0)

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            run_units("melmalec-16", seed=1, n_ticks=1500, after_tick=chain(probe, hook), abort=abort,
                      cut_short=cut)
    finally:
        signal.signal(signal.SIGINT, previous)
    try:
        assert sent[0] == 60 and len(sent) == 2
        for name, (system, loop) in seen.items():
            stop = loop.final_stop
            assert stop is not None and stop["verified"] and stop["category"] == 0, name
            assert stop["fell_to_0"] is not None, name
            probe(name, system, loop)
            assert probe.off[name][loop.tick_count - 1] is True, name
            assert loop.tick_count <= sent[1] + 3  # no 2 s window (250 ticks) after the second interrupt
    finally:
        for system, _ in seen.values():
            system.close()
