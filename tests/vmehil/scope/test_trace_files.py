"""`vmehil run --trace '*'` into all four formats, each read back with a reader no one here wrote:
the `mcap` reader (every message against its channel's JSON Schema: jsonschema), vcdvcd for the
VCD, pandas for Parquet and CSV; the values against the run's own JSON. Then `vmehil trace show`
on each. One short run (0.5 s of loop, its end-of-run stop and the 2 s watched after it)."""

from __future__ import annotations

import itertools
import json
import math
import signal
from collections import Counter

import pytest

from vmehil.cli import main

mcap_reader = pytest.importorskip("mcap.reader")
# vcdvcd resets SIGPIPE to its default action when imported (a CLI's "handle broken pipes"): in a
# pytest process that makes a later write to a closed pipe kill the whole run (exit 243 = -SIGPIPE,
# seen in CI). Python's own setting (ignored: EPIPE raised instead) is put back at once.
_sigpipe = signal.getsignal(signal.SIGPIPE)
vcdvcd = pytest.importorskip("vcdvcd")
signal.signal(signal.SIGPIPE, _sigpipe)
pd = pytest.importorskip("pandas")

PERIOD_NS = 8_000_000  #: jpl-arm's servo_rate_hz = 125 (emulators/presets/jpl-arm.toml)
RUN_TICKS = 62  #: --duration 0.5 at 125 Hz: round(0.5 × 125)


#: the JSON Schema keywords our schemas may use: none constrains a value beyond its type, so two
#: messages with the same keys and value types validate alike (jsonschema, 0.25 ms a message, is
#: asked once per shape; every message's shape is computed)
SHAPE_ONLY = {"$schema", "title", "type", "properties", "required", "additionalProperties", "items", "description"}
_JSON = {bool: "boolean", int: "integer", float: "number", str: "string", type(None): "null"}


def _type(v) -> str:
    return "array" if isinstance(v, list) else _JSON[type(v)]


def _shape(msg: dict) -> tuple:
    return tuple((k, _type(v), frozenset(_type(x) for x in v) if isinstance(v, list) else None)
                 for k, v in msg.items())


def _allowed(prop: dict) -> set:
    t = prop["type"]
    allowed = set(t) if isinstance(t, list) else {t}
    return allowed | ({"integer"} if "number" in allowed else set())  # JSON: an integer is a number


def _keywords(doc) -> set:
    if isinstance(doc, dict):
        out = set(doc)
        for k, v in doc.items():
            if k == "properties":
                out |= set().union(*(_keywords(p) for p in v.values()))
            elif k == "items":
                out |= _keywords(v)
        return out
    return set()


@pytest.fixture(scope="module")
def traced(tmp_path_factory):
    d = tmp_path_factory.mktemp("traced")
    status = main(["run", "--motion", "none", "--duration", "0.5", "--quiet", "--trace", "*",
                   "--trace-out", str(d / "t.mcap"), "--trace-out", str(d / "t.vcd"),
                   "--trace-out", str(d / "t.parquet"), "--trace-out", str(d / "t.csv"),
                   "--json", str(d / "run.json")])
    assert status == 0
    return d, json.loads((d / "run.json").read_text())


@pytest.mark.slow  # the traced run (module fixture) or a session: over 1.5 s
def test_every_mcap_message_decodes_against_its_channels_schema_and_each_group_has_every_tick(traced) -> None:
    d, run = traced
    ticks = run["final_stop"]["tick"]  # every tick the loop ran, its end-of-run stop's included
    assert ticks > RUN_TICKS
    try:
        from jsonschema import Draft202012Validator
    except ImportError:  # pragma: no cover - the test extra brings it
        Draft202012Validator = None
    per_topic: Counter[str] = Counter()
    seen_ticks: dict[str, list[int]] = {}
    validated: set = set()
    bus_cycles = 0
    with (d / "t.mcap").open("rb") as f:
        for schema, channel, message in mcap_reader.make_reader(f).iter_messages():
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            doc = json.loads(schema.data)
            msg = json.loads(message.data)
            if Draft202012Validator is None:  # the schema read literally: every key, each of its type or null
                assert set(msg) == set(doc["properties"])
                for k, v in msg.items():
                    assert _type(v) in _allowed(doc["properties"][k]), (channel.topic, k, v)
            else:  # jsonschema: once per shape (these schemas constrain keys and types only: SHAPE_ONLY)
                key = (schema.id, _shape(msg))
                if key not in validated:
                    assert _keywords(doc) <= SHAPE_ONLY
                    Draft202012Validator(doc).validate(msg)
                    validated.add(key)
            per_topic[channel.topic] += 1
            assert message.log_time == msg["tick"] * PERIOD_NS
            seen_ticks.setdefault(channel.topic, []).append(msg["tick"])
            if channel.topic == "/bus":  # a tick's cycles, as parallel arrays, in time order
                bus_cycles += len(msg["t_ns"])
                assert {len(v) for k, v in msg.items() if k not in ("tick", "t_s")} == {len(msg["t_ns"])}
                assert msg["t_ns"] == sorted(msg["t_ns"])
    tick_topics = [t for t in per_topic if t != "/bus"]
    assert {"/j1", "/hand", "/drv/j1", "/truth/j1", "/net/j1", "/net/j1/encoder", "/irq"} <= set(tick_topics)
    for topic in tick_topics:
        assert per_topic[topic] == ticks, topic
        assert seen_ticks[topic] == list(range(ticks)), topic
    mcap_file = next(f for f in run["trace"]["files"] if f["format"] == "mcap")
    assert bus_cycles == mcap_file["bus_cycles"] > 50 * RUN_TICKS  # ~60-130 cycles a running tick
    # every tick's cycles, and those of the final stop after the last tick (tick = ticks)
    assert seen_ticks["/bus"] == list(range(ticks + 1))


@pytest.mark.slow  # the traced run (module fixture) or a session: over 1.5 s
def test_the_traced_values_agree_with_the_runs_json(traced) -> None:
    d, run = traced
    df = pd.read_parquet(d / "t.parquet")
    assert len(df) == run["final_stop"]["tick"]
    last = df[df["tick"] == RUN_TICKS - 1].iloc[0]  # the run's last tick, before its end-of-run stop
    for j in run["joints"]:
        name = j["name"]
        err_deg = math.degrees(last[f"{name}.target_rad"] - last[f"truth.{name}.theta_rad"])
        assert abs(abs(err_deg) - abs(j["final_error_deg"])) < 1e-9, name
        assert bool(last[f"{name}.integrating"]) == j["final_integrating"], name
    end = df.iloc[-1]
    assert end["j1.stop_state"] == 3  # stopped: power off
    assert not end["net.j1.amp_enable"]  # the enable net is low after the stop
    assert df["net.j1.amp_enable"].iloc[5]  # and high while the loop ran


@pytest.mark.slow  # the traced run (module fixture) or a session: over 1.5 s
def test_the_csv_holds_the_same_rows_as_the_parquet(traced) -> None:
    d, _run = traced
    a = pd.read_parquet(d / "t.parquet")
    b = pd.read_csv(d / "t.csv", comment="#")
    assert list(a.columns) == list(b.columns)
    for col in ("j2.position_rad", "truth.j2.theta_rad", "drv.j2.enc_counts", "net.j2.pot"):
        assert (a[col].astype(float) - b[col].astype(float)).abs().max() < 1e-12, col
    bus_a = pd.read_parquet(d / "t.bus.parquet")
    bus_b = pd.read_csv(d / "t.bus.csv", comment="#")
    assert len(bus_a) == len(bus_b) and (bus_a["address"] == bus_b["address"]).all()
    assert set(bus_a["space"]) <= {16, 24, 32} and set(bus_a["width"]) <= {8, 16, 32}


@pytest.mark.slow  # the traced run (module fixture) or a session: over 1.5 s
def test_the_vcd_holds_the_lines_and_every_bus_cycle(traced) -> None:
    d, run = traced
    vcd = vcdvcd.VCDVCD(str(d / "t.vcd"))
    enable = vcd["vmehil.net.j1.amp_enable"].tv
    assert [v for _t, v in enable][-1] == "0"  # low after the stop
    assert any(v == "1" for _t, v in enable)  # high while the loop ran
    vcd_file = next(f for f in run["trace"]["files"] if f["format"] == "vcd")
    cycles = vcd["vmehil.bus.cycle"].tv
    assert int(cycles[-1][1], 2) == vcd_file["bus_cycles"] - 1  # one change per cycle, numbered from 0
    assert all(t2 >= t1 for (t1, _), (t2, _) in itertools.pairwise(cycles))
    # numbers with a fraction stay out of a VCD (volts, radians): the lines and counts only
    assert "vmehil.j1.position_rad" not in vcd.references_to_ids
    assert "vmehil.j1.integrating" in vcd.references_to_ids


@pytest.mark.slow  # the traced run (module fixture) or a session: over 1.5 s
@pytest.mark.parametrize("name", ["t.mcap", "t.parquet", "t.csv"])
def test_trace_show_plots_each_format(traced, name, capsys) -> None:
    d, _run = traced
    out = d / f"{name}.png"
    assert main(["trace", "show", str(d / name), "--signals", "j1.position_rad,truth.j1.theta_rad",
                 "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "2 signals" in capsys.readouterr().err


@pytest.mark.slow  # the traced run (module fixture) or a session: over 1.5 s
def test_trace_show_refuses_a_signal_the_file_does_not_hold(traced, capsys) -> None:
    d, _run = traced
    assert main(["trace", "show", str(d / "t.mcap"), "--signals", "j1.positon_rad"]) == 2
    assert "nearest: j1.position_rad" in capsys.readouterr().err


@pytest.mark.slow  # the traced run (module fixture) or a session: over 1.5 s
def test_the_console_traces_its_session(tmp_path) -> None:
    out = tmp_path / "console.csv"
    status = main(["console", "--port", f"pty:{tmp_path / 'console'}", "--lockstep", "--duration", "0.2",
                   "--trace", "j1.*,net.j1.amp_enable", "--trace-out", str(out), "--json", str(tmp_path / "c.json")])
    assert status == 0
    session = json.loads((tmp_path / "c.json").read_text())
    rows = pd.read_csv(out, comment="#")
    assert len(rows) == session["ticks"] == session["trace"]["files"][0]["ticks"]
    assert list(rows.columns) == ["tick", "t_s", *[f"j1.{leaf}" for leaf in (
        "target_rad", "target_rad_s", "position_rad", "velocity_rad_s", "error_rad", "torque_nm", "current_cmd_a",
        "current_a", "integral_e", "integral_edot_rad", "kp_eff", "integrating", "stop_state")], "net.j1.amp_enable"]
    assert rows["j1.stop_state"].iloc[-1] == 3


@pytest.mark.slow  # the traced run (module fixture) or a session: over 1.5 s
@pytest.mark.parametrize("name", ["t.mcap", "t.vcd", "t.parquet", "t.csv", "t.bus.parquet"])
def test_a_trace_file_of_ours_may_be_written_again(traced, name) -> None:
    from vmehil.writers.output_paths import check_output_file

    d, _run = traced
    assert check_output_file(d / name, "--trace-out") == d / name  # no refusal: vmehil wrote it


def test_a_file_vmehil_did_not_write_is_not_overwritten_by_a_trace(tmp_path, capsys) -> None:
    theirs = tmp_path / "theirs.mcap"
    theirs.write_bytes(b"\x89MCAP0\r\nsomeone else's recording")
    status = main(["run", "--motion", "none", "--duration", "0.1", "--trace", "j1.*", "--trace-out", str(theirs)])
    assert status == 2
    assert "was not written by vmehil" in capsys.readouterr().err
    assert theirs.read_bytes() == b"\x89MCAP0\r\nsomeone else's recording"


def test_a_trace_out_with_an_unknown_suffix_is_refused_before_the_run(tmp_path, capsys) -> None:
    status = main(["run", "--motion", "none", "--duration", "0.1", "--trace", "j1.*",
                   "--trace-out", str(tmp_path / "t.json")])
    assert status == 2
    assert "--trace-out" in capsys.readouterr().err and not list(tmp_path.iterdir())


@pytest.mark.slow  # builds the rig (its plant kernel): over 1.5 s
def test_trace_list_prints_every_name_of_the_rig(capsys) -> None:
    assert main(["run", "--trace", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = [line.split()[0] for line in lines]
    # jpl-arm: 7 joints × (13 controller + 7 driver + 12 truth), its nets, 7 IRQ levels, 8 bus fields
    assert names[:2] == ["j1.target_rad", "j1.target_rad_s"]
    assert {"drv.hand.enc_counts", "net.j2.holding_brake", "net.rig.watchdog", "net.j1.encoder.index",
            "truth.j6.brake_engaged", "irq.IRQ7", "bus.berr"} <= set(names)
    assert len(names) == len(set(names)) == 7 * (13 + 7 + 12) + 7 + 8 + len([n for n in names if n.startswith("net.")])


def test_a_spec_the_rig_cannot_meet_is_refused_before_the_loop_is_armed(capsys) -> None:
    assert main(["run", "--motion", "none", "--duration", "0.1", "--trace", "j9.*"]) == 2
    err = capsys.readouterr().err
    assert "'j9.*' matches no signal; nearest:" in err
    assert "amplifiers enabled" not in err  # refused before the run began


def test_trace_out_without_trace_is_refused(capsys) -> None:
    assert main(["run", "--trace-out", "t.mcap"]) == 2
    assert "--trace-out: give --trace SPEC too" in capsys.readouterr().err


@pytest.mark.slow  # builds the rig (its plant kernel): over 1.5 s
def test_console_trace_list_prints_the_same_names_as_run(capsys) -> None:
    # jpl-arm's controller names of its first joint and its last (the hand), as run's listing above
    assert main(["console", "--trace", "list"]) == 0
    names = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    assert names[:2] == ["j1.target_rad", "j1.target_rad_s"]
    assert {"drv.hand.enc_counts", "net.rig.watchdog", "irq.IRQ7", "bus.berr"} <= set(names)


@pytest.mark.parametrize(("name", "content"), [
    ("t.mcap", b"garbage\n"),  # no MCAP magic
    ("t.parquet", b"garbage\n"),  # no Parquet footer
    ("t.csv", b"garbage\n1\n"),  # a CSV, but no t_s column: not a trace
])
def test_trace_show_refuses_a_file_that_is_not_a_trace_in_one_line(tmp_path, capsys, name, content) -> None:
    path = tmp_path / name
    path.write_bytes(content)
    assert main(["trace", "show", str(path), "--out", str(tmp_path / "t.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"vmehil trace: error: vmehil trace show {path}: not a") and err.count("\n") == 1
    assert not (tmp_path / "t.png").exists()


def test_trace_show_signals_list_prints_the_files_signal_names(tmp_path, capsys) -> None:
    # the hint every --signals refusal gives ("--signals list prints them all") must work
    path = tmp_path / "t.csv"
    path.write_text("# vmehil trace\ntick,t_s,j1.position_rad,truth.j1.theta_rad\n0,0,0.5,0.25\n")
    assert main(["trace", "show", str(path), "--signals", "list"]) == 0
    assert capsys.readouterr().out.splitlines() == ["j1.position_rad", "truth.j1.theta_rad"]
    assert not (tmp_path / "t.png").exists()
