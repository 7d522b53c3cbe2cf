"""The first words a new user types: bare `vmehil` and `vmehil --version`."""

from __future__ import annotations

import pytest

from vmehil.cli import main


def test_bare_vmehil_lists_the_commands_and_exits_with_the_usage_status(capsys) -> None:
    # it printed "error: the following arguments are required: COMMAND" and no command
    assert main([]) == 2
    out = capsys.readouterr().out
    for command in ("run", "tune", "calibrate", "reproduce", "console", "crate"):
        assert f"\n    {command} " in out or f"\n    {command}\n" in out


def test_version_prints_the_installed_version(capsys) -> None:
    # `vmehil --version` was "unrecognized arguments"
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    words = capsys.readouterr().out.split()
    assert words[0] == "vmehil" and words[1][0].isdigit()


def test_make_run_ends_with_next_steps_that_name_real_commands() -> None:
    # after `make run` a new user was told nothing of calibrate, reproduce or tune
    import re
    import shlex
    from pathlib import Path

    from vmehil.cli import build_parser

    recipe = (Path(__file__).resolve().parents[2] / "Makefile").read_text().split("\nrun:", 1)[1].split("\n\n", 1)[0]
    assert '@echo "Next:"' in recipe
    hints = re.findall(r"\$\(VENV\)/bin/vmehil ([^\"]*?)\s{2,}", recipe)
    assert {h.split()[0] for h in hints} >= {"calibrate", "reproduce", "tune"}
    for hint in hints:
        if hint.strip() == "--help":
            continue
        build_parser().parse_args(shlex.split(hint))  # an unknown command or flag exits 2 here
