"""MAVProxy as a real ground station: it fetches, shows and sets parameters of a running loop,
signed and unsigned, driven through its stdin; we read its printed output (its exit code is
always 1). MAVProxy is a test dependency (the test extra; ``make venv`` installs it)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time

import MAVProxy  # noqa: F401  (the ground station the tests run: missing, they fail here, not in a subprocess)
import pytest

from tests.support.fakes import fake_loop
from vmehil.mavlink.endpoint import MavlinkEndpoint, free_udp_port
from vmehil.mavlink.signing import key_from_passphrase

TIMEOUT_S = 25.0


class MavProxy:
    """MAVProxy in its own process group, loopback only, param + signing modules only."""

    def __init__(self, port: int, home, modules: str = "param,signing") -> None:
        env = {**os.environ, "MAVLINK20": "1", "HOME": str(home)}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "MAVProxy.mavproxy", f"--master=udpout:127.0.0.1:{port}",
             f"--default-modules={modules}", "--no-state", "--nowait", "--mav20"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
            cwd=str(home), start_new_session=True)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def send(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def text(self) -> str:
        return "\n".join(self.lines)

    def close(self) -> None:
        # MAVProxy does not end on SIGTERM (every close waited the full 5 s, then killed it):
        # its process group is killed at once; nothing of it needs a clean exit (HOME is tmp)
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait(30)


@pytest.fixture
def served(tmp_path):
    """A loop with an endpoint, ticked at about real time by ``until`` while MAVProxy talks to it."""
    made = []

    def make(**kw):
        loop, _, runner = fake_loop(2)
        port = free_udp_port()
        ep = MavlinkEndpoint(loop, f"udpin:127.0.0.1:{port}", rate_hz=2.0, **kw)
        runner.after_tick.append(ep.after_tick)
        mp = MavProxy(port, tmp_path)
        made.append((ep, mp))
        t_end = time.monotonic() + TIMEOUT_S

        def until(cond, what: str):
            while time.monotonic() < t_end:
                runner.tick()
                if cond():
                    return
                time.sleep(0.004)
            raise AssertionError(f"MAVProxy: timed out waiting for {what}; its output:\n{mp.text()}")

        return loop, ep, mp, until

    yield make
    for ep, mp in made:
        mp.close()
        ep.close()


@pytest.mark.slow
def test_mavproxy_fetches_shows_and_sets_gains_unsigned(served):
    loop, ep, mp, until = served()
    until(lambda: "online system 1" in mp.text() or "Detected vehicle 1:1" in mp.text(), "the vehicle")
    mp.send("param fetch")
    until(lambda: f"Received {len(ep.table)} parameters" in mp.text(), "the parameter list")
    mp.send("param show J1_KP")
    until(lambda: re.search(r"^.*J1_KP\s+100(\.0)?\s*$", mp.text(), re.M), "J1_KP 100")
    mp.send("param set J1_KP 120")
    until(lambda: float(loop.law.gains.kp[0]) == 120.0, "the new gain in the loop")
    mp.send("param show J1_KP")
    until(lambda: re.search(r"J1_KP\s+120(\.0)?\s*$", mp.text(), re.M), "J1_KP 120")
    mp.send("param set J1_KP 90000")
    until(lambda: "unstable" in mp.text(), "the refusal of an unstable gain")
    mp.send("param set J1_VEL_MAX 3")
    until(lambda: "read-only" in mp.text(), "the refusal of a read-only parameter")
    assert float(loop.law.gains.kp[0]) == 120.0 and float(loop.law.gains.kp[1]) == 100.0
    notes = [text for _, source, text in loop.log if source == "mavlink"]
    assert any("J1_KP 100 -> 120" in t for t in notes)
    assert any("refused J1_KP = 90000" in t for t in notes)


@pytest.mark.slow
def test_mavproxy_signed_set_accepted_unsigned_refused(served):
    key = key_from_passphrase("vmehil-test-passphrase")  # MAVProxy takes one word
    # unsigned reads allowed, so that MAVProxy learns the parameters before it has the key
    loop, ep, mp, until = served(key=key, allow_unsigned_read=True)
    until(lambda: "online system 1" in mp.text() or "Detected vehicle 1:1" in mp.text(), "the vehicle")
    mp.send("param fetch")
    until(lambda: f"Received {len(ep.table)} parameters" in mp.text(), "the parameter list")
    mp.send("param set J1_KV 45")  # without the key: unsigned, refused
    until(lambda: "PARAM_SET refused: signing required" in mp.text(), "the refusal of an unsigned PARAM_SET")
    assert float(loop.law.gains.kv[0]) == 50.0
    mp.send("signing key vmehil-test-passphrase")
    mp.send("param set J1_KV 45")
    until(lambda: float(loop.law.gains.kv[0]) == 45.0, "the signed set to take effect")
    assert ep.stats.unsigned_refused >= 1
    assert any("J1_KV 50 -> 45" in t and ", signed)" in t for _, _, t in loop.log)


@pytest.mark.slow
def test_mavproxy_sets_a_gain_before_tick_zero_and_arms_the_run(tmp_path):
    """The lockstep flow (``--mavlink-wait``): set while waiting, ``arm throttle`` starts the run."""
    loop, _, runner = fake_loop(1)
    port = free_udp_port()
    ep = MavlinkEndpoint(loop, f"udpin:127.0.0.1:{port}")
    mp = MavProxy(port, tmp_path, modules="param,signing,arm")
    feeder = threading.Thread(target=lambda: _feed(mp, ep), daemon=True)
    feeder.start()
    try:
        assert ep.wait_for_start(TIMEOUT_S), mp.text()
        runner.run(1)
        assert float(loop.law.gains.kp[0]) == 120.0
        notes = [text for _, _, text in loop.log]
        assert notes[0].startswith("J1_KP 100 -> 120") and notes[1].startswith("armed")
    finally:
        mp.close()
        ep.close()


def _feed(mp: MavProxy, ep: MavlinkEndpoint) -> None:
    """Type into MAVProxy: the set once it has the parameters, the arm once the set was applied."""
    t_end = time.monotonic() + TIMEOUT_S
    steps = (("param set J1_KP 120", lambda: "Received" in mp.text()),
             ("arm throttle", lambda: ep.stats.sets_applied >= 1))
    for command, ready in steps:
        while time.monotonic() < t_end and not ready():
            time.sleep(0.05)
        mp.send(command)


@pytest.mark.slow
def test_mavproxy_tunes_a_real_vmehil_run(tmp_path):
    """The issue's 'done when': MAVProxy reads and sets a gain of a running `vmehil run`
    (lockstep, jpl-arm, waiting for the arm), and the run then uses it."""
    import json

    port = free_udp_port()
    out = tmp_path / "run.json"
    run = subprocess.Popen(
        [sys.executable, "-m", "vmehil", "run", "--duration", "3", "--quiet", "--json", str(out),
         "--mavlink", f"udpin:127.0.0.1:{port}", "--mavlink-wait", "90"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=str(tmp_path))
    mp = MavProxy(port, tmp_path, modules="param,signing,arm")
    try:
        t_end = time.monotonic() + 90

        def wait_for(pattern: str, resend: str | None = None) -> None:
            """Wait for MAVProxy to print ``pattern``; ``resend`` is typed again every 2 s (a
            request over UDP that may have gone out before the vehicle was known)."""
            next_send = time.monotonic()
            while time.monotonic() < t_end:
                if re.search(pattern, mp.text(), re.M):
                    return
                assert run.poll() is None, run.stderr.read() if run.stderr else ""
                if resend is not None and time.monotonic() >= next_send:
                    mp.send(resend)
                    next_send = time.monotonic() + 2.0
                time.sleep(0.1)
            raise AssertionError(f"MAVProxy never printed {pattern!r}:\n{mp.text()}")

        # MAVProxy may fetch the list before it has detected the vehicle, and then shows nothing
        # for it: wait for the detection, fetch again, and ask until the value is shown.
        wait_for(r"Detected vehicle 1:1|online system 1")
        mp.send("param fetch")
        wait_for(r"Received \d+ parameters")
        wait_for(r"J1_KP\s+100(\.0)?\s*$", resend="param show J1_KP")
        mp.send("param set J1_KP 250")  # staged: it takes effect at the first tick boundary
        # the vehicle's PARAM_VALUE answer updates MAVProxy's table: the set was received
        wait_for(r"J1_KP\s+250(\.0)?\s*$", resend="param show J1_KP")
        mp.send("arm throttle")
        _, err = run.communicate(timeout=120)
        assert run.returncode == 0, err
    finally:
        mp.close()
        if run.poll() is None:
            run.kill()
            run.wait()
    summary = json.loads(out.read_text())
    assert summary["ticks"] == 375 and not summary["faults"]
    changes = [c for c in summary["changes"] if c["source"] == "mavlink"]
    assert changes[0]["change"].startswith("J1_KP 100 -> 250") and changes[0]["time_s"] == 0.0
