"""`vmehil tune`: defaults on the default rig, JSON keys and nulls, reports, rig-file gains, and
clear errors for bad gains (no tracebacks)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from vmehil.cli import main
from vmehil.writers.output_paths import MARKER


def test_bode_with_no_arguments_works_on_the_default_rig(capsys) -> None:
    assert main(["tune", "bode"]) == 0
    out = capsys.readouterr().out
    assert "phase margin" in out and "jpl-arm" in out and "Kp=100 Kpi=5000 Kv=50 KvI=1000" in out


def test_bode_json_has_the_documented_keys_and_null_for_infinite_margin(tmp_path: Path, capsys) -> None:
    path = tmp_path / "bode.json"
    assert main(["tune", "bode", "--joint", "2", "--json", str(path)]) == 0  # encoder velocity: no tach filter
    text = path.read_text()
    d = json.loads(text)
    for key in ("gain_margin_db", "phase_margin_deg"):
        assert key in d["continuous"]
    for key in ("gain_margin_db", "phase_margin_deg", "crossover_hz", "bandwidth_hz"):
        assert isinstance(d["sampled"][key], float)
    assert d["continuous"]["gain_margin_db"] is None  # infinite upper margin: phase never reaches −180°
    assert '"gain_margin_db": null' in text and "Infinity" not in text and "NaN" not in text
    assert 40 < d["sampled"]["phase_margin_deg"] < d["continuous"]["phase_margin_deg"]
    assert list(tmp_path.iterdir()) == [path]  # no temp files left behind


@pytest.mark.slow
def test_bode_report_writes_png_svg_and_markdown(tmp_path: Path, capsys) -> None:
    rep = tmp_path / "rep"
    assert main(["tune", "bode", "--report", str(rep)]) == 0
    names = sorted(p.name for p in rep.iterdir() if p.name != MARKER)  # the marker: a directory of ours
    assert names == ["bode_open_loop.png", "bode_open_loop.svg", "closed_loop_and_disturbance.png",
                     "closed_loop_and_disturbance.svg", "summary.md"]
    assert (rep / "bode_open_loop.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (rep / "summary.md").read_text()
    assert "phase margin" in md and "bode_open_loop.png" in md


@pytest.mark.parametrize(("gains", "words"), [
    ("kp=-5", "negative"),
    ("kv=nan", "not finite"),
    ("kq=3", "unknown gain"),
    ("kp=1,,kv", "malformed"),
    ("kp=fast", "not a number"),
])
def test_bad_gains_are_clear_errors_without_traceback(gains: str, words: str, capsys) -> None:
    assert main(["tune", "bode", "--gains", gains]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err and err.startswith("vmehil tune: error:")


def test_unstable_gains_are_reported_clearly(tmp_path: Path, capsys) -> None:
    path = tmp_path / "b.json"
    assert main(["tune", "bode", "--gains", "kpi=200000", "--json", str(path)]) == 1
    cap = capsys.readouterr()
    assert "UNSTABLE" in cap.out and "UNSTABLE" in cap.err and "Traceback" not in cap.err
    d = json.loads(path.read_text())
    assert d["stable"] is False and d["sampled"]["stable"] is False


def test_bad_joint_number_is_an_argument_error(capsys) -> None:
    with pytest.raises(SystemExit) as e:
        main(["tune", "bode", "--joint", "0"])
    assert e.value.code == 2
    assert "numbered from 1" in capsys.readouterr().err


def _rig_variant(tmp_path: Path, **edits: str) -> Path:
    """jpl-arm with text edits: ``servo_j1`` appended to joint 1's [joint.servo]; ``servo`` replaces the
    [servo] switch-off line; ``replace`` is a list of (old, new) text substitutions."""
    from emulators.presets import resolve_rig

    text = resolve_rig("jpl-arm").read_text()
    if "servo_j1" in edits:
        anchor = 'velocity = "tach"\n'
        assert text.count(anchor) == 1
        text = text.replace(anchor, anchor + edits["servo_j1"] + "\n")
    for old, new in edits.get("replace", ()):
        assert old in text
        text = text.replace(old, new, 1)
    if "servo" in edits:
        text = text.replace('switch_off = { enabled = true }', edits["servo"], 1)
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def test_rig_file_gains_and_loop_settings_are_used(tmp_path: Path, capsys) -> None:
    rig = _rig_variant(tmp_path, servo_j1="gains = { kp = 150, kpi = 4000, kv = 60, kvi = 900 }",
                       replace=[("servo_rate_hz = 125.0", "servo_rate_hz = 250.0"),
                                ("computation_delay_s = 0.001", "computation_delay_s = 0.003")])
    path = tmp_path / "b.json"
    assert main(["tune", "bode", "--rig", str(rig), "--gains", "kp=175", "--json", str(path)]) == 0
    d = json.loads(path.read_text())
    assert d["gains"] == {"kp": 175.0, "kpi": 4000.0, "kv": 60.0, "kvi": 900.0}
    assert d["gains_source"].startswith("rig [joint.servo]")
    assert d["joint_name"] == "j1" and d["velocity_source"] == "tach"
    assert d["sample_period_s"] == pytest.approx(0.004) and d["computation_delay_s"] == pytest.approx(0.003)
    assert not any(n.startswith("gains") for n in d["notes"])


def test_encoder_velocity_joint_has_no_dead_band(tmp_path: Path, capsys) -> None:
    path = tmp_path / "lc.json"
    assert main(["tune", "limit-cycle", "--predict-only", "--joint", "2", "--json", str(path)]) == 0
    d = json.loads(path.read_text())
    assert d["velocity_source"] == "encoder" and d["tach_deadband_rad_s"] is None
    assert d["joint_name"] == "j2"


def test_joint_beyond_the_rig_is_a_clear_error(capsys) -> None:
    assert main(["tune", "bode", "--joint", "8"]) == 2
    err = capsys.readouterr().err
    assert "has 7 joints" in err and "Traceback" not in err


@pytest.mark.slow
def test_limit_cycle_predict_only_json_and_report(tmp_path: Path, capsys) -> None:
    path = tmp_path / "lc.json"
    rep = tmp_path / "lc"
    assert main(["tune", "limit-cycle", "--predict-only", "--json", str(path), "--report", str(rep)]) == 0
    d = json.loads(path.read_text())
    p = d["predicted"]
    assert 0.5 < p["amplitude_deg"] < 1.0 and 1.0 < p["frequency_hz"] < 3.0  # docs/jpl-figures.md: ±¾° at 1–3 Hz
    assert d["simulated"] is None and d["switch_off"]["simulated"] is None
    # the paper's cure: with the integrators switched off no stable cycle is predicted
    assert d["switch_off"]["predicted"]["amplitude_deg"] is None
    assert d["switch_off"]["predicted"]["frequency_hz"] is None
    assert "static_error_deg" in d["switch_off"]
    from emulators.plant import load_plant_params

    j1 = load_plant_params("jpl-arm").joints[0]  # T_F at the output = N · largest local input breakout
    tf = j1.friction.breakout_nm * (1 + j1.friction.ripple_fraction) * j1.gear.ratio
    assert d["switch_off"]["predicted"]["static_error_bound_deg"] == pytest.approx(
        tf / (j1.inertia_at_joint() * 1100) * 180 / 3.141592653589793, rel=1e-6)
    names = {x.name for x in rep.iterdir()}
    assert {"df_nyquist.png", "df_nyquist.svg", "cycle_model_check.png", "summary.md"} <= names


def test_limit_cycle_without_any_cycle_gives_null(tmp_path: Path, capsys) -> None:
    """Joint 2 senses velocity with the motor encoder (no dead band): nothing to predict."""
    path = tmp_path / "lc.json"
    assert main(["tune", "limit-cycle", "--predict-only", "--joint", "2", "--json", str(path)]) == 0
    d = json.loads(path.read_text())
    assert d["predicted"]["amplitude_deg"] is None and d["predicted"]["frequency_hz"] is None
    assert "null" in path.read_text()
