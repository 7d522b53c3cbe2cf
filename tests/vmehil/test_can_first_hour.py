"""A new user's first CAN commands: `vmehil run --plant can` on the default interface works, an
unknown interface is named with the known ones, and every connect error's advice is a command
that parses (issue 20, "CAN")."""

from __future__ import annotations

import json
import shlex
import sys

import can
import pytest

from emulators.can.bus import INTERFACES, BusConfigError, config_files, resolve
from emulators.harness import PlantLostError
from vmehil.cli import build_parser, main
from vmehil.option_groups.can_options import CanPlantOptions


@pytest.fixture
def no_can_config(monkeypatch, tmp_path):
    """No CAN_* variables and no python-can config file of this machine's user."""
    for var in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_CONFIG", "CAN_BITRATE"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr(can.util, "CONFIG_FILES", [str(tmp_path / "none.conf")])
    monkeypatch.setattr(can, "rc", {})
    monkeypatch.chdir(tmp_path)


def test_run_plant_can_on_the_default_interface_starts_the_node_in_process_and_equals_in_process(
        tmp_path, no_can_config, capsys):
    over_can, in_process = tmp_path / "can.json", tmp_path / "inproc.json"
    # --can-timeout: an equality check, so no 1 s wall-clock bound a loaded machine could trip
    assert main(["run", "--plant", "can", "--duration", "0.3", "--can-timeout", "60", "--json", str(over_can)]) == 0
    err = capsys.readouterr().err
    assert "plant node: in this process on virtual" in err
    assert main(["run", "--duration", "0.3", "--quiet", "--json", str(in_process)]) == 0
    a, b = json.loads(over_can.read_text()), json.loads(in_process.read_text())
    assert a["joints"] == b["joints"]  # lockstep over CAN is bit-identical to the in-process run
    assert a["ticks"] == b["ticks"] > 0


@pytest.mark.parametrize("how", ["option", "environment", "config file"])
def test_an_unknown_interface_is_named_with_where_it_came_from_and_the_known_ones(how, no_can_config,
                                                                                  monkeypatch, tmp_path):
    interface = None
    if how == "option":
        interface, where = "bogus", "--interface"
    elif how == "environment":
        monkeypatch.setenv("CAN_INTERFACE", "bogus")
        where = "CAN_INTERFACE"
    else:
        conf = tmp_path / "can.conf"
        conf.write_text("[default]\ninterface = bogus\n")
        monkeypatch.setattr(can.util, "CONFIG_FILES", [str(conf)])
        where = str(conf)
    with pytest.raises(BusConfigError) as e:
        resolve(interface, None)
    text = str(e.value)
    assert "unknown CAN interface 'bogus'" in text and where in text
    assert ", ".join(INTERFACES) in text and "pcan" in text  # ours, then python-can's others
    assert "needs a channel" not in text


def test_plant_node_with_an_unknown_interface_exits_2_naming_it(no_can_config, capsys):
    assert main(["plant-node", "--interface", "bogus", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "unknown CAN interface 'bogus' (from --interface)" in err and "udp_multicast" in err


@pytest.mark.skipif(sys.platform == "win32", reason="python-can reads can.ini on Windows")
def test_can_ini_in_the_working_directory_is_not_read_off_windows(no_can_config, tmp_path):
    # docs/can.md: python-can reads ./can.ini on Windows only; here the default stays virtual
    (tmp_path / "can.ini").write_text("[default]\ninterface = udp_multicast\n")
    assert "can.ini" not in " ".join(config_files())
    assert resolve() == ("virtual", "vmehil")


def test_the_environment_channel_is_used_with_the_default_interface(no_can_config, monkeypatch):
    monkeypatch.setenv("CAN_CHANNEL", "bench-7")
    assert resolve() == ("virtual", "bench-7")


@pytest.mark.parametrize(("interface", "mode"), [("socketcan", "lockstep"), ("udp_multicast", "free-running")])
def test_no_node_advice_is_a_plant_node_command_that_parses(interface, mode):
    from emulators.presets import resolve_rig
    from servo.rig import load_rig

    opts = CanPlantOptions(interface, None, mode)
    advice = opts._advice(PlantLostError("no plant node answered RESET within 5 s"),
                          load_rig(resolve_rig("melmalec-16")), interface, "ch0", own_node=False)
    argv = shlex.split(advice[advice.index("vmehil plant-node"):])
    assert argv[:2] == ["vmehil", "plant-node"]
    args = build_parser().parse_args(argv[1:])
    assert (args.rig, args.interface, args.channel) == ("melmalec-16", interface, "ch0")
    assert args.free_running == (mode == "free-running")


def test_no_node_advice_on_virtual_says_it_does_not_cross_processes():
    opts = CanPlantOptions("virtual", None)
    advice = opts._advice(PlantLostError("x"), None, "virtual", "vmehil", own_node=False)
    assert "reaches this process only" in advice and "plant-node" not in advice


def test_a_plant_node_on_the_default_virtual_interface_is_refused_with_what_works(no_can_config, capsys):
    assert main(["plant-node", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "virtual does not cross processes" in err and "--interface udp_multicast" in err
    assert "`vmehil run --plant can` alone starts its node itself" in err
