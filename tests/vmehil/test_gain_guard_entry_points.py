"""One stability guard: every way of giving the servo gains — the console's ``gains``, a MAVLink
PARAM_SET, ``vmehil run --gains``, ``vmehil tune`` — refuses the same unstable set with the same
reason (servo.gain_guard's), and a sweep classifies it (``stable = false``) instead of refusing.

Each entry point runs as shipped on the default rig (jpl-arm: 125 Hz, 1 ms computation delay,
switch-off enabled), through the extension that attaches it to a running loop."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from servo.control.gains import Gains
from servo.gain_guard import judge
from servo.runner import LockstepRunner
from tests.support.console import Driver, tap_poll
from vmehil.cli import build_parser, main
from vmehil.mavlink.client import Client
from vmehil.mavlink.endpoint import free_udp_port
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

T, DELAY = 0.008, 0.001 / 0.008  # jpl-arm

# (change, MAVLink parameter, value): one gain set too stiff for 125 Hz, and the marginal Kpi = 0
# with KvI > 0 that the two old guards disagreed on (one refused it, the other decided by rounding)
UNSTABLE = [("kp", "J1_KP", 5e4), ("kpi", "J1_KPI", 0.0)]


def _expected_reason(name: str, value: float) -> str:
    g = Gains.paper().replace(**{name: value})
    v = judge(g, T, DELAY, kp_off=g.kp + g.kvi)
    assert not v.ok and v.kind == "unstable"
    return v.reason


@pytest.fixture
def live_rig():
    """A running jpl-arm loop with the console (loop://) and the MAVLink endpoint attached as
    ``vmehil run --console … --mavlink …`` attaches them."""
    from vmehil.console.extension import start_console
    from vmehil.mavlink.extension import attach

    system = build_emulated_rig("jpl-arm")
    loop = build_loop(system)
    loop.start()
    runner = LockstepRunner(system, loop)
    port = free_udp_port()
    args = build_parser().parse_args(["run", "--mavlink", f"udpin:127.0.0.1:{port}", "--mavlink-rate", "0"])
    endpoint = attach(args.options(args), system, loop, runner)
    console = start_console("loop://", loop, runner=runner, announce=lambda _text: None)
    client = Client(port)
    client.hello()
    yield loop, runner, console, client
    client.close()
    console.close()
    endpoint.close()
    system.close()


@pytest.mark.parametrize(("name", "param", "value"), UNSTABLE)
def test_console_and_mavlink_refuse_with_the_guards_reason(live_rig, name, param, value):
    loop, runner, console, client = live_rig
    reason = _expected_reason(name, value)
    before = loop.law.gains
    drv = Driver(loop, console, console.transport.write, tap_poll(console), step=runner.tick)
    reply = drv.ask(f"gains all {name}={value:g}")
    assert reply[0].startswith("ERR GAIN") and reason in reply[0]

    client.set(param, value)
    client.wait(lambda: client.of("PARAM_ERROR"), runner.tick)
    refusals = [text for _, source, text in loop.log if source == "mavlink" and text.startswith("refused")]
    assert len(refusals) == 1 and f": {reason}" in refusals[0]
    runner.run(2)
    assert loop.law.gains == before  # nothing was changed


@pytest.mark.parametrize(("name", "param", "value"), UNSTABLE)
def test_run_and_tune_refuse_with_the_guards_reason(name, param, value, capsys):
    reason = _expected_reason(name, value)
    gains = f"{name}={value:g}"
    assert main(["run", "--gains", gains, "--duration", "0.1", "--quiet"]) == 2
    assert reason in capsys.readouterr().err
    for cmd in ("step", "limit-cycle"):  # refused before simulating
        assert main(["tune", cmd, "--gains", gains]) == 1
        assert reason in capsys.readouterr().err
    assert main(["tune", "bode", "--gains", gains]) == 1  # analysed and reported, not hidden
    cap = capsys.readouterr()
    assert reason in cap.err and reason in cap.out


@pytest.mark.parametrize(("name", "param", "value"), UNSTABLE)
def test_a_sweep_classifies_the_set_instead_of_refusing(name, param, value, tmp_path: Path, capsys):
    reason = _expected_reason(name, value)  # the sweep's loop keeps its integrators: the same reason
    out = tmp_path / "out"
    assert main(["tune", "sweep", "--grid", f"{name}={value:g};{Gains.paper().as_dict()[name]:g}", "--margins-only",
                 "--jobs", "1", "--out", str(out), "--quiet"]) == 0
    rows = json.loads((out / "sweep.json").read_text())["rows"]
    assert [(r["stable"], r["unstable_reason"]) for r in rows] == [(False, reason), (True, None)]
    assert rows[0]["status"] == "unstable (servo.gain_guard): not simulated"


@pytest.mark.parametrize(("gains", "reason"), [("kp = 1e30, kv = 50.0", "kp is limited to 100000"),
                                               ("kp = 100000, kv = 0", "unstable (pole radius 2.21")])
def test_a_rig_files_gains_go_through_the_guard_as_the_command_lines_do(gains, reason, tmp_path: Path, capsys):
    """Issue #30 item 3: the same sets the command line refuses ran from a rig file."""
    from emulators.presets import resolve_rig

    paper = "gains = { kp = 100.0, kpi = 5000.0, kv = 50.0, kvi = 1000.0 }"
    text = resolve_rig("jpl-arm").read_text(encoding="utf-8")
    assert paper in text
    rig = tmp_path / "rig.toml"
    rig.write_text(text.replace(paper, f"gains = {{ kpi = 5000.0, kvi = 1000.0, {gains} }}", 1), encoding="utf-8")
    assert main(["run", "--rig", str(rig), "--duration", "0.1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert reason in err and f"{rig}: key 'servo.gains'" in err
    assert main(["run", "--gains", gains.replace(" ", ""), "--duration", "0.1", "--quiet"]) == 2
    assert reason in capsys.readouterr().err  # the command line's refusal, for the same set
