"""A trace observes only: the same run with and without `--trace '*'` makes the same bus cycles,
at the same simulated instants, with the same numbers; the tap sees every cycle the crate counts.
A file that reaches `--trace-max-mb` stops there, still readable, and the loop runs on. The unit
controllers trace their own loop, the coordinator its plant's exchanges."""

from __future__ import annotations

import io
import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from emulators.presets import resolve_rig
from servo.motion import hold_motion
from servo.rig import load_rig
from servo.runner import LockstepRunner
from vmehil.option_groups.trace_options import TraceOptions, start_on_plant
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

mcap_reader = pytest.importorskip("mcap.reader")
pd = pytest.importorskip("pandas")

TICKS = 40


def _cycles(counters: dict[str, int]) -> int:
    return sum(v for k, v in counters.items() if k.startswith(("read.", "write.")))


def run(trace: TraceOptions | None, seed: int = 3, ticks: int = TICKS, err=None):
    system = build_emulated_rig("jpl-arm", seed=seed)
    loop = build_loop(system, motion=hold_motion(), n_ticks=ticks)
    runner = LockstepRunner(system, loop)
    started = None
    with loop.armed():
        before = _cycles(system.crate.counter_snapshot())
        if trace is not None:
            started = trace.start(system, loop, runner, rig="jpl-arm", seed=seed, err=err)
        completed = runner.run(ticks)
    if started is not None:
        started.close()
    after = _cycles(system.crate.counter_snapshot())
    system.close()
    return loop, system, started, completed, after - before


def test_a_trace_adds_no_bus_cycle_and_changes_no_number(tmp_path) -> None:
    plain, sys_a, _, _, cycles_a = run(None)
    spec = TraceOptions("*", (tmp_path / "t.csv",))
    traced, sys_b, trace, _, cycles_b = run(spec)
    assert sys_a.crate.counter_snapshot() == sys_b.crate.counter_snapshot()
    assert sys_a.crate.clock.now_ns == sys_b.crate.clock.now_ns
    a, b = plain.recorder.trimmed(), traced.recorder.trimmed()
    for key in ("theta", "theta_true", "torque", "current_cmd", "omega"):
        assert np.array_equal(a[key], b[key], equal_nan=True), key
    # the tap saw every cycle the crate counted from the trace's start to its end
    assert trace.summary()["files"][0]["bus_cycles"] == cycles_b == cycles_a


def test_a_file_at_its_size_bound_stops_readable_and_the_loop_runs_on(tmp_path) -> None:
    err = io.StringIO()
    spec = TraceOptions("*", (tmp_path / "t.mcap", tmp_path / "t.parquet"), max_mb=0.05)
    loop, _system, trace, completed, _ = run(spec, ticks=60, err=err)
    assert completed == 60 and loop.fault is None  # the loop ran to its end
    mcap, parquet = trace.summary()["files"]
    assert mcap["stopped_at_tick"] is not None and mcap["stopped_at_tick"] < 59
    assert f"trace: {tmp_path / 't.mcap'} reached --trace-max-mb 0.05 at tick {mcap['stopped_at_tick']}" \
        in err.getvalue()
    with (tmp_path / "t.mcap").open("rb") as f:  # closed where it stopped: a valid file
        reader = mcap_reader.make_reader(f)
        assert reader.get_summary() is not None
        ticks = {json.loads(m.data)["tick"] for _s, ch, m in reader.iter_messages(topics=["/j1"])}
    assert ticks == set(range(mcap["stopped_at_tick"] + 1))
    assert Path(tmp_path / "t.mcap").stat().st_size < 0.05e6 + (1 << 20)  # at most one chunk past the bound
    if parquet["stopped_at_tick"] is None:
        assert len(pd.read_parquet(tmp_path / "t.parquet")) == 60


_channels = itertools.count()


@pytest.mark.slow  # five unit controllers and a coordinator (threads): over 1.5 s
def test_a_unit_traces_its_loop_and_the_coordinator_its_plant_steps(tmp_path) -> None:
    from tests.vmehil.test_units_remote import UNITS, start_units
    from vmehil.unit_controllers.coordinator import plant_link_for
    from vmehil.unit_controllers.processes import run_coordinator
    from vmehil.unit_controllers.remote import unit_bus

    rig = load_rig(resolve_rig("melmalec-16"))
    traces: list = []
    leg1 = TraceOptions("leg1_knee.*,drv.leg1_knee.*,net.leg1_knee.*", (tmp_path / "leg1.parquet",))

    def before_run(r) -> None:
        traces.append(leg1.start(r.system, r.loop, r.runner, rig="melmalec-16:leg1", seed=r.seed))

    channel = f"unit-trace-{next(_channels)}"
    results, threads = start_units(rig, channel, per_unit={"leg1": {"before_run": before_run}})
    link = plant_link_for(rig, 4)
    plant = start_on_plant(TraceOptions("truth.leg1_knee.*,net.leg1_knee.*", (tmp_path / "plant.csv",)), link, rig,
                           seed=4)
    bus = unit_bus("virtual", channel)
    try:
        run_coordinator(rig, bus, seed=4, n_ticks=50, timeout_s=5.0, start_timeout_s=20.0, plant_link=link)
    finally:
        bus.close()
        plant.close()
    for t in threads:
        t.join(timeout=60)
    for trace in traces:
        trace.close()
    assert all(not isinstance(results[n], BaseException) for n in UNITS), results
    unit = pd.read_parquet(tmp_path / "leg1.parquet")
    loop = results["leg1"].loop
    assert len(unit) == loop.tick_count
    knee = loop.names.index("leg1_knee")
    rec = loop.recorder.trimmed()
    assert np.array_equal(unit["leg1_knee.position_rad"].to_numpy(float)[:len(rec["theta"])], rec["theta"][:, knee],
                          equal_nan=True)
    steps = pd.read_csv(tmp_path / "plant.csv", comment="#")
    assert list(steps["tick"]) == list(range(len(steps))) and len(steps) >= 50
    # the plant's truth as the coordinator served it is what the unit's loop saw: its tick k sensed
    # the answer to plant step k (step 0: the power-up exchange), which the trace's row k + 1 holds
    served = steps["truth.leg1_knee.theta_rad"].to_numpy(float)[1:50]
    assert np.allclose(served, rec["theta_true"][:49, knee], rtol=0, atol=1e-6)
    assert steps["net.leg1_knee.amp_enable"].astype(bool).iloc[5]


def test_on_a_rig_without_an_emulated_crate_a_trace_has_the_controller_and_the_drivers(tmp_path) -> None:
    """A real bus (`vmehil run --bus vme_user --trace '*'`): no nets, no bus cycles, no truth to
    observe; '*' is the controller's and the drivers' signals."""
    from types import SimpleNamespace

    system = build_emulated_rig("jpl-arm", seed=1)
    loop = build_loop(system, motion=hold_motion(), n_ticks=10)
    runner = LockstepRunner(system, loop)
    real = SimpleNamespace(rig=system.rig)  # what the trace sees of a real rig: no crate, no plant
    with loop.armed():
        trace = TraceOptions("*", (tmp_path / "real.csv",)).start(real, loop, runner, rig="jpl-arm")
        runner.run(10)
    trace.close()
    system.close()
    rows = pd.read_csv(tmp_path / "real.csv", comment="#")
    assert len(rows) == 10
    groups = {c.rpartition(".")[0] for c in rows.columns if "." in c}
    assert groups == {*loop.names, *(f"drv.{n}" for n in loop.names)}
    assert rows["drv.j1.pot_v"].notna().all() and rows["j1.position_rad"].notna().all()


@pytest.mark.slow  # five unit controllers and a coordinator: over 1.5 s
def test_vmehil_unit_and_vmehil_coordinate_take_trace_and_say_so_in_their_json(tmp_path) -> None:
    """The commands themselves (threads on the `virtual` unit bus stand in for the processes):
    `vmehil unit --trace` beside its faults' hook, `vmehil coordinate --trace` on the plant it
    makes; each JSON names its file and the ticks in it."""
    import threading

    from tests.vmehil.test_units_remote import start_units
    from vmehil.cli import main

    rig = load_rig(resolve_rig("melmalec-16"))
    channel = f"unit-trace-cli-{next(_channels)}"
    status: dict[str, int] = {}
    leg1 = threading.Thread(target=lambda: status.__setitem__("leg1", main([
        "unit", "--rig", "melmalec-16", "--unit", "leg1", "--interface", "virtual", "--channel", channel,
        "--trace", "leg1_knee.*", "--trace-out", str(tmp_path / "leg1.csv"), "--json", str(tmp_path / "leg1.json")])),
        daemon=True)
    leg1.start()
    _results, threads = start_units(rig, channel, names=("leg2", "leg3", "leg4", "arm"))
    status["coordinate"] = main(["coordinate", "--rig", "melmalec-16", "--duration", "0.4", "--interface", "virtual",
                                 "--channel", channel, "--trace", "truth.leg1_knee.*",
                                 "--trace-out", str(tmp_path / "plant.parquet"),
                                 "--json", str(tmp_path / "coordinate.json")])
    for t in (leg1, *threads):
        t.join(timeout=60)
    assert status == {"leg1": 0, "coordinate": 0}
    unit = json.loads((tmp_path / "leg1.json").read_text())
    # every tick is traced: the 0.4 s run (50 ticks), its category-1 stop and the 2 s watched after
    # it (250 ticks at 125 Hz: a unit ends as the single run does, docs/safe-stop.md)
    ticks = unit["trace"]["files"][0]["ticks"]
    assert ticks == len(pd.read_csv(tmp_path / "leg1.csv", comment="#")) and 50 + 250 <= ticks <= 50 + 250 + 125
    coordinate = json.loads((tmp_path / "coordinate.json").read_text())
    steps = pd.read_parquet(tmp_path / "plant.parquet")
    assert coordinate["trace"]["files"][0]["ticks"] == len(steps) >= 50 + 250
    assert list(steps.columns) == ["tick", "t_s", *[f"truth.leg1_knee.{leaf}" for leaf in (
        "theta_rad", "omega_rad_s", "theta_motor_rad", "omega_motor_rad_s", "current_a", "motor_torque_nm",
        "friction_torque_nm", "encoder_x4", "stuck", "at_stop", "amp_enabled", "brake_engaged")]]
