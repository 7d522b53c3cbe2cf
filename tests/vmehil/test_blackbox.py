"""`vmehil run` writes the servo loop's black box on every stop (docs/scope.md, "Black box").

Read back with readers this project did not write: the `mcap` library's reader (every message
decoded as JSON and checked against its channel's JSON Schema's keys), numpy for the `.npz`.
The values compared come from the run's JSON (the fault's tick and joint, the stop, the
excursion), not from the black box's own code; the box's spans are the spec's (5 s kept before
the stop by default, 2 s after the power went off)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vmehil import cli

pytest.importorskip("mcap")

PERIOD_S = 0.008  # jpl-arm: 125 Hz
AFTER_TICKS = 250  # 2 s kept after the power went off


def _read_mcap(path: Path) -> tuple[dict[str, list[dict]], dict[str, dict], dict[str, str]]:
    """topic → messages (decoded JSON, in log-time order), topic → schema, the metadata ``vmehil``."""
    from mcap.reader import make_reader

    msgs: dict[str, list[dict]] = {}
    schemas: dict[str, dict] = {}
    with path.open("rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            assert schema is not None and schema.encoding == "jsonschema" and channel.message_encoding == "json"
            schemas[channel.topic] = json.loads(schema.data)
            body = json.loads(message.data)
            assert set(body) == set(schemas[channel.topic]["properties"]), channel.topic
            assert message.log_time == round(body["tick"] * PERIOD_S * 1e9)
            assert body["t_s"] == pytest.approx(body["tick"] * PERIOD_S)
            msgs.setdefault(channel.topic, []).append(body)
        f.seek(0)
        meta = {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
    return msgs, schemas, meta["vmehil"]


@pytest.mark.slow  # over 1.5 s at rest (a run of seconds of loop time)
def test_a_fault_runs_black_box_holds_the_seconds_before_the_stop_and_its_lines_match_the_json(tmp_path):
    out = tmp_path / "run.json"
    box_dir = tmp_path / "box"
    status = cli.main(["run", "--duration", "1.6", "--fault", "amp_fault@1.5:joint=j2", "--quiet",
                       "--json", str(out), "--blackbox", str(box_dir)])
    assert status == 1
    summary = json.loads(out.read_text())
    fault = summary["faults"][0]
    assert fault["cause"] == "amplifier_fault" and fault["joint"] == "j2"
    path = Path(summary["final_stop"]["blackbox"])
    assert path.parent.parent == box_dir and path.parent.name.startswith("jpl-arm-") and path.suffix == ".mcap"
    assert (path.parent / "blackbox.png").stat().st_size > 10_000
    msgs, _, meta = _read_mcap(path)
    joints = ("j1", "j2", "j3", "j4", "j5", "j6", "hand")
    assert set(msgs) == {f"/{j}" for j in joints} | {f"/drv/{j}" for j in joints}
    assert int(meta["stop_tick"]) == fault["tick"] and meta["stop_cause"] == "amplifier_fault"
    ticks = [m["tick"] for m in msgs["/j1"]]
    assert ticks == list(range(ticks[0], ticks[-1] + 1))  # every tick, none twice
    assert all([m["tick"] for m in msgs[j]] == ticks for j in msgs)
    # at least 1 s before the stop (the run was 1.5 s long then: all of it, from tick 0)
    assert ticks[0] == 0 and (fault["tick"] - ticks[0]) * PERIOD_S >= 1.0
    # and 2 s after the power went off, then frozen (the run ticked on to 1.6 s + 2 s)
    assert ticks[-1] == fault["tick"] + AFTER_TICKS
    by_tick = {topic: {m["tick"]: m for m in msgs[topic]} for topic in msgs}
    f = fault["tick"]
    assert by_tick["/drv/j2"][f]["amp_fault"] is True and by_tick["/drv/j2"][f - 1]["amp_fault"] is False
    assert all(by_tick[f"/drv/{j}"][f]["amp_fault"] is False for j in joints if j != "j2")
    for j in joints:  # the enables fell in the fault's tick, the brake lines with them, 0 N·m commanded
        assert by_tick[f"/drv/{j}"][f - 1]["amp_enable"] is True and by_tick[f"/drv/{j}"][f]["amp_enable"] is False
        assert by_tick[f"/drv/{j}"][f]["brake_released"] is False and by_tick[f"/{j}"][f]["torque_nm"] == 0.0
        assert by_tick[f"/{j}"][f - 1]["stop_state"] == 0 and by_tick[f"/{j}"][f]["stop_state"] == 3  # stopped
    assert by_tick["/j2"][f]["t_s"] == pytest.approx(fault["time_s"])
    row = by_tick["/j1"][f - 1]
    assert row["error_rad"] == pytest.approx(row["target_rad"] - row["position_rad"])
    assert row["kp_eff"] > 0 and row["integral_e"] is not None and row["integrating"] in (True, False)


def test_a_normal_end_writes_the_box_and_its_angles_give_the_jsons_excursion(tmp_path):
    out = tmp_path / "run.json"
    status = cli.main(["run", "--motion", "none", "--duration", "1", "--quiet", "--json", str(out),
                       "--blackbox", str(tmp_path)])
    assert status == 0
    summary = json.loads(out.read_text())
    stop = summary["final_stop"]
    msgs, _, meta = _read_mcap(Path(stop["blackbox"]))
    rows = msgs["/j1"]
    # the end's category-1 stop (1: decelerating) begins after the run's own ticks; the last tick
    # is the final stop's, powered off (3)
    stopping = [m["tick"] for m in rows if m["stop_state"] == 1]
    assert stopping[0] == summary["ticks"] and int(meta["stop_tick"]) == summary["ticks"]
    assert rows[-1]["tick"] == stop["tick"] - 1 and rows[-1]["stop_state"] == 3
    # the JSON's excursion (sensors): the largest move from the angle before the stop, to the end
    for j, deg in stop["excursion_sensor_deg"].items():
        pos = {m["tick"]: m["position_rad"] for m in msgs[f"/{j}"]}
        origin = pos[summary["ticks"] - 1]
        moved = max(abs(pos[k] - origin) for k in pos if k >= summary["ticks"])
        assert np.degrees(moved) == pytest.approx(deg, abs=1e-4), j


def test_without_the_trace_extra_the_box_is_an_npz_said_in_one_line(tmp_path, monkeypatch, capsys):
    import vmehil.reports.blackbox as writer

    have = writer._have
    monkeypatch.setattr(writer, "_have", lambda module: False if module == "mcap" else have(module))
    out = tmp_path / "run.json"
    assert cli.main(["run", "--motion", "none", "--duration", "0.5", "--quiet", "--json", str(out),
                     "--blackbox", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    path = Path(json.loads(out.read_text())["final_stop"]["blackbox"])
    assert path.suffix == ".npz"
    notes = [line for line in err.splitlines() if ".npz" in line]
    assert len(notes) == 1 and "'trace' extra" in notes[0]
    data = np.load(path)
    signals = data["signals"].tolist()
    assert data["names"].tolist() == ["j1", "j2", "j3", "j4", "j5", "j6", "hand"]
    assert data["joints"].shape == (data["t"].size, len(signals), 7)
    assert data["tick"][0] == 0 and np.all(np.diff(data["tick"]) == 1)
    assert data["joints"][0, signals.index("amp_enable")].tolist() == [1.0] * 7


def test_the_box_goes_to_the_report_else_a_stamped_folder_else_where_asked(monkeypatch):
    from datetime import UTC, datetime

    from vmehil.reports.blackbox import blackbox_folder

    now = datetime(2026, 12, 3, 12, 5, 19, tzinfo=UTC)
    monkeypatch.delenv("VMEHIL_BLACKBOX", raising=False)
    assert blackbox_folder(None, "rep", "jpl-arm", now) == Path("rep")
    assert blackbox_folder(None, None, "jpl-arm", now) == Path("vmehil-blackbox/jpl-arm-20261203T120519Z")
    assert blackbox_folder("boxes", "rep", "jpl-arm", now) == Path("boxes/jpl-arm-20261203T120519Z")
    assert blackbox_folder("off", "rep", "jpl-arm", now) is None
    monkeypatch.setenv("VMEHIL_BLACKBOX", "/var/boxes")
    assert blackbox_folder(None, "rep", "melmalec-16", now) == Path("/var/boxes/melmalec-16-20261203T120519Z")
    monkeypatch.setenv("VMEHIL_BLACKBOX", "off")
    assert blackbox_folder(None, "rep", "jpl-arm", now) is None


def test_off_writes_no_box_and_names_none(tmp_path):
    out = tmp_path / "run.json"
    assert cli.main(["run", "--motion", "none", "--duration", "0.2", "--quiet", "--json", str(out),
                     "--blackbox", "off"], ) == 0
    assert "blackbox" not in json.loads(out.read_text())["final_stop"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.json"]


def test_the_black_box_adds_no_bus_cycle():
    """Two lockstep runs of the same rig and seed, one without its black box: the same cycles."""
    from servo.runner import LockstepRunner
    from vmehil.rig_setup.session import build_loop
    from vmehil.rig_setup.system import build_emulated_rig

    counts = []
    for keep in (True, False):
        system = build_emulated_rig("jpl-arm", seed=0)
        loop = build_loop(system, n_ticks=200)
        if not keep:
            loop.blackbox = None
        runner = LockstepRunner(system, loop)
        with loop.armed():
            runner.run(200)
        counts.append((system.crate.counter_snapshot(), loop.recorder.trimmed()["theta"].tobytes()))
        system.close()
    assert counts[0] == counts[1]


@pytest.mark.slow  # over 1.5 s at rest (a run of seconds of loop time)
def test_a_console_session_writes_its_box_when_it_ends(tmp_path):
    out = tmp_path / "console.json"
    assert cli.main(["console", "--console", f"pty:{tmp_path / 'con'}", "--lockstep", "--duration", "0.5",
                     "--json", str(out), "--blackbox", str(tmp_path / "box")]) == 0
    stop = json.loads(out.read_text())["final_stop"]
    assert stop["cause"] == "session_end"
    msgs, _, meta = _read_mcap(Path(stop["blackbox"]))
    assert meta["stop_cause"] == "session_end"
    rows = msgs["/hand"]
    # held, then the session's category-1 stop (1), then power off (3) and the 2 s after it
    assert [rows[0]["stop_state"], rows[-1]["stop_state"]] == [0, 3] and any(r["stop_state"] == 1 for r in rows)
    # the power went off at the end of the stop's last tick; the 2 s watched after it, every tick kept
    assert sum(r["stop_state"] == 3 for r in rows) == AFTER_TICKS


@pytest.mark.slow  # over 1.5 s at rest (a run of seconds of loop time)
def test_parallel_units_each_write_their_box_and_the_run_names_the_stopped_units(tmp_path, monkeypatch):
    import vmehil.reports.blackbox as writer

    have = writer._have  # no PNGs here (five of them): the MCAP is what is checked
    monkeypatch.setattr(writer, "_have", lambda module: False if module == "matplotlib" else have(module))
    out = tmp_path / "run.json"
    status = cli.main(["run", "--rig", "melmalec-16", "--units", "parallel", "--duration", "1.2", "--quiet",
                       "--fault", "amp_fault@1:joint=leg2_knee", "--json", str(out), "--blackbox", str(tmp_path)])
    assert status == 1
    summary = json.loads(out.read_text())
    leg2 = summary["units"]["leg2"]
    fault = leg2["faults"][0]
    assert fault["cause"] == "amplifier_fault" and fault["joint"] == "leg2_knee"
    assert summary["final_stop"]["unit"] == "leg2"
    assert summary["final_stop"]["blackbox"] == leg2["final_stop"]["blackbox"]
    path = Path(leg2["final_stop"]["blackbox"])
    assert path.parent.name == "leg2" and path.name == "blackbox.mcap"
    assert {Path(u["final_stop"]["blackbox"]).parent.name for u in summary["units"].values()} == set(summary["units"])
    msgs, _, meta = _read_mcap(path)
    assert {t for t in msgs if not t.startswith("/drv/")} == {f"/{j['name']}" for j in leg2["joints"]}
    assert int(meta["stop_tick"]) == fault["tick"]
    knee = {m["tick"]: m for m in msgs["/drv/leg2_knee"]}
    assert knee[fault["tick"]]["amp_fault"] is True and knee[fault["tick"] - 1]["amp_fault"] is False
    assert (fault["tick"] - min(knee)) * PERIOD_S >= 1.0


def test_an_error_outside_the_ticks_still_leaves_the_box(tmp_path, monkeypatch, capsys):
    from servo.runner import LockstepRunner

    def broken(self, *args, **kwargs):
        raise RuntimeError("the end of the run failed")

    monkeypatch.setattr(LockstepRunner, "end_run", broken)
    assert cli.main(["run", "--motion", "none", "--duration", "0.4", "--quiet", "--blackbox", str(tmp_path)]) == 3
    err = capsys.readouterr().err
    line = next(line for line in err.splitlines() if line.startswith("black box: "))
    msgs, _, meta = _read_mcap(Path(line.removeprefix("black box: ")))
    assert meta["stop_reason"] == "exception" and "failed" not in meta["stop_cause"]
    # stopped between ticks, after the last one the box holds (still servoing then)
    assert int(meta["stop_tick"]) == msgs["/j1"][-1]["tick"] + 1 == 50  # 0.4 s at 125 Hz: ticks 0..49
    assert msgs["/j1"][-1]["stop_state"] == 0 and msgs["/drv/j1"][-1]["amp_enable"] is True
