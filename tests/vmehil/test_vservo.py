"""Visual servoing through the whole stack: vision emulator ↔ BIT3 card ↔ driver ↔ servo loop."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hal.config import ConfigError
from servo.motion import load_motion
from vmehil.cli import main


@pytest.mark.slow
def test_inprocess_visual_servo_run_reaches_the_target(tmp_path: Path, capsys) -> None:
    out = tmp_path / "vs.json"
    assert main(["run", "--vision", "inprocess", "--quiet", "--json", str(out)]) == 0
    v = json.loads(out.read_text())["vision"]
    assert v["end_reason"] == "PEER_ENDED"  # the vision system ended the task: target reached
    assert v["robot_state"] == "IDLE" and v["commands"] > 10
    assert v["final_distance_mm"] < 8.0  # the vision tolerance (5 mm) plus settling and pot noise (≈1.7 mm/LSB)
    assert "vision: " in capsys.readouterr().out


def test_vservo_move_parses_and_needs_the_link(tmp_path: Path) -> None:
    p = tmp_path / "m.toml"
    p.write_text('[[move]]\ntype = "vservo"\ntimeout_s = 5\n[[move]]\ntype = "wait"\nduration_s = 1\n')
    motion = load_motion(p, 7)
    assert motion.moves[0].kind == "vservo" and motion.moves[0].timeout_s == 5.0
    p.write_text('[[move]]\ntype = "vservo"\ntimeout = 5\n')
    with pytest.raises(ConfigError, match="move\\[0\\].timeout"):
        load_motion(p, 7)


def test_vservo_without_vision_is_a_clear_error(tmp_path: Path, capsys) -> None:
    p = tmp_path / "m.toml"
    p.write_text('[[move]]\ntype = "vservo"\n')
    assert main(["run", "--motion", str(p), "--quiet"]) == 2
    assert "--vision" in capsys.readouterr().err


def test_vision_process_mode_requires_realtime(capsys) -> None:
    assert main(["run", "--vision", "process", "--quiet"]) == 2
    assert "--realtime" in capsys.readouterr().err


def test_the_vision_process_command_line_is_one_vmehil_accepts():
    """`--vision process` starts its vision system as `python -m vmehil vision …`; it once named
    `python -m servo vision`, a module with no __main__, and every process-mode run failed."""
    import subprocess
    import sys

    import numpy as np

    from vmehil.option_groups.vision_options import VisionOptions, vision_process_argv

    argv = vision_process_argv("vmehil-test-none", np.array([0.8, 0.2, 0.5]), VisionOptions(mode="process"))
    assert argv[:4] == [sys.executable, "-m", "vmehil", "vision"]
    # every option it passes is one `vmehil vision` parses (--help after them: parse, print, exit 0)
    done = subprocess.run([*argv, "--help"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "--shm" in done.stdout
