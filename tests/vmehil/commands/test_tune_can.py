"""`vmehil tune` with the plant as a CAN node (`--plant can`): every simulated run gets a fresh
link whose plant is RESET with the run's seed, and in lockstep the results equal the in-process
run's exactly (same seed). Short moves and holds keep each simulation near one second."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from emulators.can.bus import Endpoint, open_bus, private_multicast_namespace, replay
from emulators.can.node import PLANT_IDS, PlantNode, node_spec
from emulators.plant import Plant
from vmehil.analysis.rigparams import load_joint
from vmehil.analysis.simulate import SimSettings, simulate
from vmehil.cli import main
from vmehil.option_groups.can_options import CanLinkFactory, CanPlantOptions

SHORT = SimSettings(seed=4, move_deg=2.0, hold_s=0.5, allow_short=True)
FAST = ["--move-deg", "2", "--hold", "1"]
# The link's wall-clock answer and heartbeat bound (1 s by default) finds a dead node; these tests
# check equality, so the bound is far above any pause a loaded machine gives the node's thread.
PATIENT = ["--can-timeout", "60"]


def _node_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "vmehil-plant-node" and t.is_alive()]


def test_simulate_over_virtual_can_equals_the_in_process_run_and_stops_its_node(tmp_path: Path) -> None:
    jp = load_joint(None, 1, gains="kp=120")
    before = len(_node_threads())
    ref = simulate(jp, switch_off=False, settings=SHORT)
    got = simulate(jp, switch_off=False, settings=SHORT,
                   link_factory=CanLinkFactory(CanPlantOptions("virtual", "tune-sim", can_log=str(tmp_path / "b.log"),
                                                               can_timeout_s=60.0)))
    assert ref["fault"] is None and max(ref["theta_deg"]) - min(ref["theta_deg"]) > 1.0  # it moved
    assert got == ref  # every figure and every trace sample, bit for bit
    assert len(_node_threads()) == before  # the run's own plant node was stopped with its link
    assert sum(f.arbitration_id == 0x200 for f in replay(tmp_path / "b.log")) >= len(ref["t_s"])  # via the bus


@pytest.mark.slow
def test_one_external_node_serves_successive_runs_each_reset_with_its_seed() -> None:
    """The socketcan/udp_multicast case: no node per run, the link's RESET rebuilds the plant."""
    jp = load_joint(None, 1)
    spec = node_spec(None)
    node = PlantNode(Endpoint(open_bus("virtual", "tune-shared"), PLANT_IDS),
                     lambda s: Plant.from_config(spec.table, seed=s), spec.n_joints)
    thread, stop = node.start_thread()
    factory = CanLinkFactory(CanPlantOptions("virtual", "tune-shared", own_node=False, can_timeout_s=60.0))
    try:
        runs = [(seed, simulate(jp, settings=SimSettings(seed=seed, move_deg=2.0, hold_s=0.5, allow_short=True),
                                link_factory=factory)) for seed in (1, 2, 1)]
    finally:
        stop.set()
        thread.join(10)
        node.close()
    assert node.counters.resets == 3
    for seed, got in runs:
        ref = simulate(jp, settings=SimSettings(seed=seed, move_deg=2.0, hold_s=0.5, allow_short=True))
        assert got == ref, seed
    assert runs[0][1] != runs[1][1]  # the seed reaches the remote plant (its noise differs)


@pytest.mark.slow
def test_tune_step_json_over_can_equals_in_process_and_logs_each_run(tmp_path: Path) -> None:
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["tune", "step", *FAST, "--seed", "2", "--json", str(a)]) == 0
    assert main(["tune", "step", *FAST, "--seed", "2", "--json", str(b), "--plant", "can", "--interface", "virtual",
                 *PATIENT, "--can-log", str(tmp_path / "bus.log")]) == 0
    assert json.loads(a.read_text()) == json.loads(b.read_text())
    for tag in ("step", "move"):
        frames = list(replay(tmp_path / f"bus-{tag}.log"))
        assert any(f.arbitration_id == 0x081 for f in frames)  # the run's RESET
        assert sum(f.arbitration_id == 0x080 for f in frames) > 100  # a SYNC per tick


@pytest.mark.slow
def test_tune_limit_cycle_json_over_can_equals_in_process(tmp_path: Path, monkeypatch) -> None:
    from vmehil.commands import tune

    real = tune._sim_settings
    monkeypatch.setattr(tune, "_sim_settings", lambda opts, jp, allow_short=False: real(opts, jp, True))  # 1 s hold
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["tune", "limit-cycle", *FAST, "--json", str(a)]) in (0, 1)
    assert main(["tune", "limit-cycle", *FAST, "--json", str(b), "--plant", "can", "--interface", "virtual",
                 *PATIENT]) in (0, 1)
    da, db = json.loads(a.read_text()), json.loads(b.read_text())
    assert da["simulated"] is not None and da["switch_off"]["simulated"] is not None
    assert da == db


@pytest.mark.slow
def test_tune_sweep_in_two_workers_over_virtual_can_equals_in_process(tmp_path: Path) -> None:
    common = ["tune", "sweep", *FAST, "--grid", "kp=80:120:2", "--jobs", "2", "--quiet"]
    assert main([*common, "--out", str(tmp_path / "a")]) == 0
    assert main([*common, "--out", str(tmp_path / "b"), "--plant", "can", "--interface", "virtual", *PATIENT,
                 "--can-log", str(tmp_path / "bus.log")]) == 0
    assert all(any(True for _ in replay(tmp_path / f"bus-p{i}.log")) for i in (0, 1))  # each point on the bus
    rows = []
    for d in ("a", "b"):
        r = json.loads((tmp_path / d / "sweep.json").read_text())["rows"]
        rows.append([{k: v for k, v in row.items() if k != "wall_s"} for row in r])
    assert len(rows[0]) == 2 and all(r["status"] == "ok" for r in rows[0])
    assert rows[0] == rows[1]


@pytest.mark.parametrize("iface", ["socketcan", "udp_multicast"])
def test_tune_sweep_refuses_parallel_workers_on_a_shared_external_node(tmp_path: Path, iface: str, capsys) -> None:
    assert main(["tune", "sweep", *FAST, "--grid", "kp=80:120:2", "--jobs", "2", "--quiet", "--out",
                 str(tmp_path), "--plant", "can", "--interface", iface]) == 2
    err = capsys.readouterr().err
    assert "--jobs 1" in err and "--interface virtual" in err


def test_can_options_validate_and_tag_logs() -> None:
    with pytest.raises(ValueError, match="stale-ticks"):
        CanPlantOptions("virtual", stale_ticks=0)
    with pytest.raises(ValueError, match="plant mode"):
        CanPlantOptions("virtual", plant_mode="sometimes")
    o = CanPlantOptions("virtual", can_log="out/bus.log")
    assert o.log_path("p3") == str(Path("out/bus-p3.log")) and o.log_path(None) == "out/bus.log"
    assert o.starts_node and not CanPlantOptions("socketcan").starts_node
    assert CanLinkFactory(o).shareable and not CanLinkFactory(CanPlantOptions("socketcan")).shareable


@pytest.mark.slow
@pytest.mark.skipif(not private_multicast_namespace(), reason="udp_multicast only inside a private namespace")
def test_tune_step_against_a_plant_node_process_equals_in_process(tmp_path: Path) -> None:
    node = subprocess.Popen([sys.executable, "-m", "vmehil", "plant-node", "--interface", "udp_multicast",
                             "--duration", "300", "--command-timeout", "0"], stderr=subprocess.PIPE, text=True)
    try:
        assert "plant node" in node.stderr.readline()
        a, b = tmp_path / "a.json", tmp_path / "b.json"
        assert main(["tune", "step", *FAST, "--json", str(a)]) == 0
        assert main(["tune", "step", *FAST, "--json", str(b), "--plant", "can", "--interface", "udp_multicast",
                     *PATIENT]) == 0
    finally:
        node.terminate()
        node.wait(10)
    assert "2 resets" in node.stderr.read()  # one node, reset by each of the two runs
    assert json.loads(a.read_text()) == json.loads(b.read_text())
