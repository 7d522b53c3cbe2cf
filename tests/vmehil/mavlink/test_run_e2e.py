"""MAVLink end to end: a ground station sets a gain of a real `vmehil run` (lockstep, jpl-arm)
before arming it, and the run's behaviour changes accordingly."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vmehil.mavlink.client import Client
from vmehil.mavlink.endpoint import free_udp_port

ARGS = ["--duration", "2", "--quiet", "--no-integrator-switch-off", "--seed", "2"]


def _run(tmp_path: Path, name: str, extra: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "vmehil", "run", *ARGS, "--json", str(tmp_path / name), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
def test_gain_set_over_mavlink_changes_a_real_run(tmp_path: Path) -> None:
    ref = _run(tmp_path, "ref.json", [])
    port = free_udp_port()
    proc = _run(tmp_path, "tuned.json", ["--mavlink", f"udpin:127.0.0.1:{port}", "--mavlink-wait", "60"])
    client = Client(port)
    try:
        def step() -> None:
            client.hello()
            time.sleep(0.05)

        client.wait(lambda: client.of("HEARTBEAT"), step, timeout_s=60)  # the run is up and waiting
        client.set("J1_KP", 250.0)
        value = client.wait(lambda: [m for m in client.of("PARAM_VALUE") if m.param_id == "J1_KP"], step, 10)
        assert value[-1].param_value == pytest.approx(250.0)
        client.arm(True)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
    finally:
        client.close()
        if proc.poll() is None:
            proc.kill()
    _, ref_err = ref.communicate(timeout=120)
    assert ref.returncode == 0, ref_err
    tuned = json.loads((tmp_path / "tuned.json").read_text())["joints"][0]
    plain = json.loads((tmp_path / "ref.json").read_text())["joints"][0]
    # Kp 100 → 250 on joint 1 only: the joint moves differently (tracking error changes)
    assert tuned["max_tracking_error_deg"] != pytest.approx(plain["max_tracking_error_deg"], rel=1e-6)
    other_t = json.loads((tmp_path / "tuned.json").read_text())["joints"][3]
    other_p = json.loads((tmp_path / "ref.json").read_text())["joints"][3]
    assert other_t["max_tracking_error_deg"] == pytest.approx(other_p["max_tracking_error_deg"], rel=1e-9)
