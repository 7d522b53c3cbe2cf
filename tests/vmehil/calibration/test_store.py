"""The calibration store: TOML round trip, identity checks, atomic writes, and the I/O layer loading it."""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import pytest

from hal.adc_dac.calibration import Calibration
from servo.io import JointIO
from servo.rig import load_rig
from tests.support.calib_bench import RIG_TOML, build_bench, write_rig
from tests.vmehil.test_files import kill_mid_write
from vmehil.calibration.store import (
    BoardCal,
    CalibrationFileError,
    CalibrationMissingWarning,
    CalibrationStore,
    JointCal,
    default_store_path,
    load_store,
    load_store_or_nominal,
    rig_boards,
    utc_now,
)
from vmehil.writers.files import is_temp_file


def sample_store(rig, offset=0.012) -> CalibrationStore:
    s = CalibrationStore.empty(rig)
    ident = rig_boards(rig)["adc1"]
    s.set_board(BoardCal(ident, Calibration((offset,) * 16, (1.004,) * 16), "adc", 1, utc_now(), (12, 13)))
    s.set_joint("j1", JointCal("pot", 1, utc_now(), {"volts": [-9.0, 0.0, 9.0], "angles_rad": [-2.7, 0.0, 2.7]}))
    return s


def test_round_trip_keeps_coefficients_and_provenance(tmp_path):
    rig = write_rig(tmp_path)
    path = sample_store(rig).save(tmp_path / "cal.toml")
    text = path.read_text()
    assert 'format = "vmehil-calibration"' in text and 'rig = "bench"' in text and "board_id = 44310" in text
    back = load_store(path, rig)
    assert back.board_calibration("adc1").offset_v == (0.012,) * 16
    assert back.boards["adc1"].measured == (12, 13)
    assert back.boards["adc1"].procedure == "adc" and back.boards["adc1"].procedure_version == 1
    assert back.joint_entry("j1", "pot").values["angles_rad"] == [-2.7, 0.0, 2.7]


def test_save_keeps_the_previous_file(tmp_path):
    rig = write_rig(tmp_path)
    p = tmp_path / "cal.toml"
    first = sample_store(rig, 0.001)
    first.save(p)
    assert first.previous is None and not p.with_name("cal.toml.prev").exists()  # nothing to keep yet
    second = sample_store(rig, 0.002)
    second.save(p)
    assert second.previous == p.with_name("cal.toml.prev")
    assert load_store(p, rig).board_calibration("adc1").offset_v[0] == 0.002
    assert load_store(second.previous, rig).board_calibration("adc1").offset_v[0] == 0.001


def test_malformed_file_message_names_a_prev_only_when_there_is_one(tmp_path):
    rig = write_rig(tmp_path)
    p = tmp_path / "cal.toml"
    p.write_text("[calibration\n")
    with pytest.raises(CalibrationFileError) as e:
        load_store(p, rig)
    assert ".prev" not in str(e.value) and "re-run the calibration" in str(e.value)
    p.with_name("cal.toml.prev").write_text("")
    with pytest.raises(CalibrationFileError, match=r"restore cal\.toml\.prev"):
        load_store(p, rig)


def test_merge_replaces_only_the_procedures_results(tmp_path):
    rig = write_rig(tmp_path)
    base = sample_store(rig)
    upd = CalibrationStore.empty(rig)
    upd.set_joint("j1", JointCal("encoder", 1, utc_now(), {"counts_per_joint_rev": 2e5}))
    m = base.merged(upd)
    assert m.joint_entry("j1", "pot") is not None and m.joint_entry("j1", "encoder") is not None
    assert base.joint_entry("j1", "encoder") is None


def test_non_finite_coefficients_are_not_written(tmp_path):
    rig = write_rig(tmp_path)
    s = CalibrationStore.empty(rig)
    s.set_joint("j1", JointCal("pot", 1, utc_now(), {"volts": [float("nan"), 1.0]}))
    with pytest.raises(ValueError, match="non-finite"):
        s.save(tmp_path / "cal.toml")
    assert not (tmp_path / "cal.toml").exists()


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t.replace('rig = "bench"', 'rig = "other-arm"'), "written for rig 'other-arm'"),
        (lambda t: t.replace('crate = "bench-rack"', 'crate = "lab"'), "written for crate 'lab'"),
        (lambda t: t.replace("base = 24832", "base = 24576"), "base = 0x6000 but the rig's adc1 has base 0x6100"),
        (lambda t: t.replace('type = "adc"', 'type = "dac"'), "type = 'dac'"),
        (lambda t: t.replace("[board.adc1]", "[board.adc9]"), "no board 'adc9'"),
        (lambda t: t.replace("[joint.j1.pot]", "[joint.j7.pot]"), "no joint 'j7'"),
        (lambda t: t.replace("board_id = 44310", "board_id = 1"), "board_id = 1"),
        (lambda t: t.replace('format = "vmehil-calibration"', 'format = "x"'), "not a vmehil calibration file"),
        (lambda t: t.replace("format_version = 1", "format_version = 7"), "format_version 7 is not supported"),
        (lambda t: t.replace("offset_v = [", "offset_v = [1.0,"), "expected 16 values"),
        (lambda t: t.replace("gain = [", "gain = [-1.0,", 1), "gain"),
        (lambda t: t[: len(t) // 2] + "\n[[[", "not valid TOML"),
        (lambda t: t.replace('procedure = "pot"', 'procedure = "adc"'), "says procedure = 'adc'"),
    ],
)
def test_foreign_or_malformed_files_are_refused_with_the_reason(tmp_path, edit, message):
    rig = write_rig(tmp_path)
    path = sample_store(rig).save(tmp_path / "cal.toml")
    path.write_text(edit(path.read_text()))
    with pytest.raises(CalibrationFileError) as err:
        load_store(path, rig)
    assert message in str(err.value)
    assert str(path) in str(err.value)


def test_a_board_that_answers_another_id_is_refused(tmp_path):
    b = build_bench(tmp_path)
    path = sample_store(b.rig).save(tmp_path / "cal.toml")
    # the same file for a rig whose adc1 sits where the DAC answers (0x7000): the bus check catches it
    swap = {"base = 0x6100": "base = 0x7000", "base = 0x7000": "base = 0x6100"}
    moved = "\n".join(swap.get(line, line) for line in RIG_TOML.splitlines())
    rig2 = write_rig(tmp_path, moved, "moved.toml")
    text = path.read_text().replace("base = 24832", "base = 28672")
    path.write_text(text)
    with pytest.raises(CalibrationFileError, match="answers ID 0xDA08"):
        load_store(path, rig2, bus=b.crate)


def test_jointio_applies_a_loaded_file_and_warns_when_missing(tmp_path):
    b = build_bench(tmp_path)
    path = sample_store(b.rig).save(tmp_path / "cal.toml")
    io = JointIO(b.crate, b.rig, b.io.scaling, calibration=load_store_or_nominal(path, b.rig, bus=b.crate))
    assert io.adc["adc1"].calibration.offset_v[0] == 0.012
    assert io.pot_angle(0, 4.5) == pytest.approx(1.35)
    with pytest.warns(CalibrationMissingWarning, match="nominal"):
        missing = load_store_or_nominal(tmp_path / "missing.toml", b.rig, bus=b.crate)
    assert missing is None
    io2 = JointIO(b.crate, b.rig, b.io.scaling, calibration=missing)
    assert io2.adc["adc1"].calibration == Calibration.identity(16)
    other = load_rig(tmp_path / "bench.toml")
    other.name = "elsewhere"
    with pytest.raises(CalibrationFileError, match="written for rig 'bench'"):
        load_store_or_nominal(path, other, bus=b.crate)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        JointIO(b.crate, b.rig, b.io.scaling)  # no calibration asked for: no warning


def test_default_path_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("VMEHIL_CALIBRATION_DIR", str(tmp_path))
    assert default_store_path("jpl-arm") == tmp_path / "jpl-arm.toml"
    monkeypatch.delenv("VMEHIL_CALIBRATION_DIR")
    assert default_store_path("jpl-arm") == Path("calibration") / "jpl-arm.toml"


def test_killed_mid_write_leaves_the_previous_file_intact_and_no_orphan_after_the_next_save(tmp_path):
    """A real process is SIGKILLed after writing and fsyncing the temporary file, before the rename."""
    rig = write_rig(tmp_path)
    path = tmp_path / "cal.toml"
    sample_store(rig, 0.001).save(path)
    old = path.read_bytes()
    tmp_file = kill_mid_write(path, f"""
        from pathlib import Path
        from tests.support.calib_bench import write_rig
        from tests.vmehil.calibration.test_store import sample_store
        sample_store(write_rig(Path({str(tmp_path)!r})), 0.999).save({str(path)!r})
    """)
    assert b"0.999" in tmp_file.read_bytes()  # the new data was on disk
    assert path.read_bytes() == old
    assert load_store(path, rig).board_calibration("adc1").offset_v[0] == 0.001
    # the killed process could not remove its temporary file; the next save does
    assert is_temp_file(tmp_file.name)
    sample_store(rig, 0.002).save(path)
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".tmp")]
