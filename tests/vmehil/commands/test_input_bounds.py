"""Every number a command takes is finite and bounded, and every output path is checked before
the command does any work; nothing that vmehil did not write is overwritten without --force."""

from __future__ import annotations

import json

import pytest

from vmehil import cli
from vmehil.exit_status import EXIT_USAGE
from vmehil.writers.output_paths import MARKER


@pytest.mark.parametrize("argv", [
    ["run", "--duration", "inf"], ["run", "--duration", "1e12"], ["run", "--duration", "nan"],
    ["run", "--duration", "0"], ["plant-node", "--duration", "nan"], ["console", "--duration", "-1"],
    ["calibrate", "pot", "--points", "100000"], ["run", "--seed", "-1"], ["tune", "step", "--step-deg", "inf"],
    ["run", "--realtime", "--max-lateness", "inf"],
])
def test_an_unbounded_or_non_finite_number_is_refused_by_the_parser(argv, capsys) -> None:
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    assert e.value.code == 2
    assert "expected" in capsys.readouterr().err or "must be" in capsys.readouterr().err


def test_a_sweep_grid_of_1e8_points_is_refused_before_anything_is_built(tmp_path, capsys) -> None:
    code = cli.main(["tune", "sweep", "--grid", "kp=80:140:10000,kv=30:70:10000", "--out", str(tmp_path / "s")])
    assert code == EXIT_USAGE
    assert "100,000,000 points" in capsys.readouterr().err


def test_report_naming_an_existing_file_is_refused_before_the_run(tmp_path, capsys) -> None:
    f = tmp_path / "notes.txt"
    f.write_text("mine")
    assert cli.main(["run", "--duration", "1", "--quiet", "--report", str(f)]) == EXIT_USAGE
    assert "exists and is not a directory" in capsys.readouterr().err
    assert f.read_text() == "mine"


def test_a_foreign_json_file_is_kept_unless_forced_and_our_own_is_replaced(tmp_path, capsys) -> None:
    f = tmp_path / "out.json"
    f.write_text('{"someone": "else"}')
    assert cli.main(["run", "--duration", "0.5", "--quiet", "--json", str(f)]) == EXIT_USAGE
    assert "not written by vmehil" in capsys.readouterr().err and json.loads(f.read_text()) == {"someone": "else"}
    assert cli.main(["run", "--duration", "0.5", "--quiet", "--json", str(f), "--force"]) == 0
    assert json.loads(f.read_text())["written_by"] == "vmehil"
    assert cli.main(["run", "--duration", "0.5", "--quiet", "--json", str(f)]) == 0  # ours now


def test_a_report_directory_that_is_not_ours_is_not_written_into(tmp_path, capsys) -> None:
    d = tmp_path / "photos"
    d.mkdir()
    (d / "holiday.png").write_bytes(b"x")
    assert cli.main(["run", "--duration", "0.5", "--quiet", "--report", str(d)]) == EXIT_USAGE
    assert sorted(p.name for p in d.iterdir()) == ["holiday.png"]


MAKE_RUN = ["run", "--duration", "0.2", "--quiet", "--report", "reports/run", "--json", "reports/run/run.json"]


@pytest.fixture(scope="module")
def made_by_make_run(tmp_path_factory):
    """`make run` on a fresh clone, once for the tests below (a run that writes every figure of the
    report takes seconds): `--report reports/run --json reports/run/run.json`, no reports/ yet."""
    where = tmp_path_factory.mktemp("clone")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(where)
        code = cli.main(MAKE_RUN)
    return where, code


@pytest.mark.slow  # a second run that writes every figure of the report (≈ 3 s on the 2-core machine)
def test_a_report_directory_the_run_made_is_marked_ours_and_rewritten(made_by_make_run, monkeypatch) -> None:
    where, code = made_by_make_run
    assert code == 0 and (where / "reports/run" / MARKER).exists()
    monkeypatch.chdir(where)
    assert cli.main(MAKE_RUN) == 0  # ours: rewritten, not refused
    assert (where / "reports/run" / MARKER).exists()
    assert json.loads((where / "reports/run/run.json").read_text())["written_by"] == "vmehil"


@pytest.mark.slow  # the shared run writes every figure of the report (≈ 3 s on the 2-core machine)
def test_make_runs_json_inside_the_report_directory_it_creates_is_accepted(made_by_make_run) -> None:
    """The JSON's folder is the report directory the run creates."""
    where, code = made_by_make_run
    assert code == 0
    assert json.loads((where / "reports/run/run.json").read_text())["written_by"] == "vmehil"
    assert (where / "reports/run" / MARKER).exists()


def test_a_json_in_a_folder_nothing_creates_is_refused_and_nothing_is_made(tmp_path, capsys) -> None:
    out = tmp_path / "missing" / "run.json"
    assert cli.main(["run", "--duration", "0.2", "--quiet", "--report", str(tmp_path / "rep"),
                     "--json", str(out)]) == EXIT_USAGE
    assert "does not exist" in capsys.readouterr().err
    assert not (tmp_path / "missing").exists() and not (tmp_path / "rep").exists()


def test_a_sweep_whose_grid_times_samples_exceeds_the_limit_is_refused_before_anything_runs(tmp_path, capsys) -> None:
    """Each factor is within its own limit (10⁵ values, 10⁵ samples); their product is not (10¹⁰ tasks
    grew to 3.8 GB): here 10³ × 10³."""
    code = cli.main(["tune", "sweep", "--grid", "kp=80:140:1000", "--vary", "coulomb=10%", "--samples", "1000",
                     "--out", str(tmp_path / "s")])
    assert code == EXIT_USAGE
    err = capsys.readouterr().err
    assert "1,000 gain sets × 1,000 samples = 1,000,000 points" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "s").exists()


def test_the_sweep_size_bound_counts_switch_off_modes_and_samples() -> None:
    from vmehil.analysis.sweep import SweepError, check_sweep_size

    assert check_sweep_size(50_000, 2, 1) == 100_000
    assert check_sweep_size(1, 1, 100_000) == 100_000
    with pytest.raises(SweepError, match="= 100,002 points"):
        check_sweep_size(50_001, 2, 1)
