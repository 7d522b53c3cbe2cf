"""One command language (issue 20): one spelling per concept across the subcommands, every
shipped spelling kept as an alias that parses to the same value."""

from __future__ import annotations

import json

import pytest

from vmehil.cli import build_parser, main


def _parse(*argv: str):
    return build_parser().parse_args(list(argv))


@pytest.mark.parametrize(("new", "old"), [
    (["console", "--console", "loop://"], ["console", "--port", "loop://"]),
    (["console", "--console-commands", "ops.cmd"], ["console", "--commands", "ops.cmd"]),
    (["console", "--console-baud", "9600"], ["console", "--baud", "9600"]),
    (["console", "--lockstep"], ["console", "--lockstep"]),
    (["calibrate", "adc", "--calibration", "cal.toml"], ["calibrate", "adc", "--out", "cal.toml"]),
    (["crate", "list", "--json"], ["crate", "--json", "list"]),
    (["crate", "read", "A24", "0x10", "--rig", "melmalec-16"],
     ["crate", "--rig", "melmalec-16", "read", "A24", "0x10"]),
], ids=lambda v: " ".join(v))
def test_an_old_spelling_parses_as_the_new_one(new, old):
    assert vars(_parse(*new)) == vars(_parse(*old))


def test_run_and_console_share_the_console_options():
    run = _parse("run", "--console", "pty", "--console-commands", "f", "--console-baud", "9600",
                 "--console-prompt", "off", "--console-echo", "on")
    console = _parse("console", "--console", "pty", "--console-commands", "f", "--console-baud", "9600",
                     "--console-prompt", "off", "--console-echo", "on")
    for key in ("console", "console_commands", "console_baud", "console_prompt", "console_echo"):
        assert getattr(run, key) == getattr(console, key), key
    assert _parse("console").console == "pty"  # the port defaults to a new pty


@pytest.mark.parametrize("command", ["run", "console"])
def test_pacing_is_realtime_or_lockstep_in_both_commands(command):
    from vmehil.option_groups.realtime_options import RealtimeOptions

    assert RealtimeOptions.from_args(_parse(command, "--realtime"), default=False).realtime is True
    assert RealtimeOptions.from_args(_parse(command, "--lockstep"), default=True).realtime is False
    assert _parse(command).realtime is None  # the command's own default applies
    with pytest.raises(SystemExit):
        _parse(command, "--realtime", "--lockstep")


def test_crate_options_after_the_action_win_and_print_json(capsys):
    assert main(["crate", "--rig", "jpl-arm", "types", "--json"]) == 0
    assert "adc" in json.loads(capsys.readouterr().out)


def test_run_motion_none_asks_for_a_duration(capsys):
    assert main(["run", "--motion", "none"]) == 2
    assert "--motion none holds the joints: give --duration S" in capsys.readouterr().err


def test_run_motion_none_holds_the_joints(tmp_path):
    out = tmp_path / "hold.json"
    assert main(["run", "--motion", "none", "--duration", "0.2", "--quiet", "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert summary["ticks"] == 25 and summary["faults"] == [] and summary["mode"] == "lockstep"
    assert not summary["motion_end_s"]  # no motion to end: the joints were held from the first tick


def test_vision_writes_its_summary_with_json(tmp_path, capsys):
    from emulators.bit3 import Bit3Link

    link = Bit3Link.create_shared(0x1000)
    out = tmp_path / "vision.json"
    try:
        assert main(["vision", "--shm", link.shm_name, "--duration", "0.2", "--json", str(out)]) == 0
    finally:
        link.close(unlink=True)
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    written = json.loads(out.read_text())
    assert written.pop("written_by") == "vmehil" and written == printed


def test_a_stdout_closed_by_its_reader_ends_the_command_quietly():
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "vmehil", "crate", "list"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    assert proc.stdout is not None
    proc.stdout.close()  # no reader at all: the first write fails with EPIPE (as `| head` once it has had enough)
    _out, err = proc.communicate(timeout=120)
    assert proc.returncode == 141 and b"BrokenPipeError" not in err and err.strip() == b""


@pytest.mark.parametrize(("extra", "mode"), [([], "realtime"), (["--lockstep"], "lockstep")])
def test_run_with_a_console_paces_by_the_wall_clock_unless_lockstep(tmp_path, extra, mode):
    pytest.importorskip("serial")
    out = tmp_path / "run.json"
    assert main(["run", "--console", "loop://", "--motion", "none", "--duration", "0.2", "--quiet",
                 "--overrun", "warn", "--json", str(out), *extra]) == 0
    assert json.loads(out.read_text())["mode"] == mode
