"""`vmehil run --live`: the loop's channels over the Foxglove WebSocket protocol (docs/scope.md,
"Live view").

The client here is written from the protocol's published spec (the spec document of the
foxglove/ws-protocol repository), with the `websockets` library, not with foxglove-sdk: it offers the subprotocol
(``foxglove.websocket.v1``, and its current name ``foxglove.sdk.v1``, which foxglove-sdk ≥ 0.x
servers require — the same protocol renamed), reads the server's ``serverInfo`` and ``advertise``
(JSON text), sends ``subscribe`` and decodes the binary *message data* frames (opcode 0x01,
uint32 subscription id, uint64 log time in ns, little-endian, then the message). No wall-clock
race: it waits for the server's address, then for messages, and only then ends the run (SIGINT).
Loopback only; the port is the one the server chose (``--live 127.0.0.1:0``)."""

from __future__ import annotations

import asyncio
import itertools
import json
import re
import signal
import struct
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from vmehil import cli

pytest.importorskip("foxglove")
websockets = pytest.importorskip("websockets")

PERIOD_NS = 8_000_000  # jpl-arm: 125 Hz
EVERY = 5  # 25 Hz of loop time: every 5th tick
BOUND_S = 120.0  # a bound on a hang only, never a condition of the test


def _read_address(proc: subprocess.Popen, seen: list[str]) -> int:
    """The port the run's live view announced on stderr (its ``live: ws://127.0.0.1:PORT`` line)."""
    assert proc.stderr is not None
    for line in proc.stderr:
        seen.append(line)
        m = re.match(r"live: ws://127\.0\.0\.1:(\d+) ", line)
        if m:
            return int(m.group(1))
    raise AssertionError("the run never announced its live view:\n" + "".join(seen))


async def _client(port: int, on_enough, enough: int) -> tuple[dict, list[tuple[str, int, dict]]]:
    """Subscribe to /j1 and /drv/j1; after ``enough`` messages of /j1 call ``on_enough()``; read
    until the server closes. Returns the advertised channels by topic and (topic, log time, msg)."""
    got: list[tuple[str, int, dict]] = []
    channels: dict[str, dict] = {}
    subs: dict[int, str] = {}
    async with websockets.connect(f"ws://127.0.0.1:{port}", compression=None, open_timeout=BOUND_S,
                                  subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"]) as ws:
        assert ws.subprotocol in ("foxglove.websocket.v1", "foxglove.sdk.v1")
        called = False
        try:
            async for frame in ws:
                if isinstance(frame, str):
                    op = json.loads(frame)
                    if op["op"] == "serverInfo":
                        assert op["name"] == "vmehil"
                    elif op["op"] == "advertise":
                        for ch in op["channels"]:
                            channels[ch["topic"]] = ch
                        subs = {1: "/j1", 2: "/drv/j1"}
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": sid, "channelId": channels[topic]["id"]} for sid, topic in subs.items()]}))
                    continue
                assert frame[0] == 0x01  # message data
                sid, log_time = struct.unpack_from("<IQ", frame, 1)
                got.append((subs[sid], log_time, json.loads(frame[13:])))
                if not called and sum(t == "/j1" for t, _, _ in got) >= enough:
                    called = True
                    on_enough()
        except websockets.ConnectionClosed:
            pass  # the run ended: the server stopped
    return channels, got


@pytest.mark.slow  # over 1.5 s at rest (a run of seconds of loop time)
def test_a_client_speaking_the_foxglove_protocol_receives_the_loops_channels_matching_the_runs_json(tmp_path):
    out = tmp_path / "run.json"
    cmd = [sys.executable, "-m", "vmehil", "run", "--motion", "none", "--duration", "600", "--overrun", "warn",
           "--live", "127.0.0.1:0", "--json", str(out), "--blackbox", str(tmp_path / "box"), "--quiet"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=str(tmp_path))
    seen: list[str] = []
    try:
        port = _read_address(proc, seen)
        rest = threading.Thread(target=lambda: seen.extend(proc.stderr or []), daemon=True)
        rest.start()  # keep reading stderr: a full pipe would block the run
        channels, got = asyncio.run(asyncio.wait_for(
            _client(port, lambda: proc.send_signal(signal.SIGINT), enough=10), BOUND_S))
        proc.wait(timeout=BOUND_S)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, "".join(seen)
    summary = json.loads(out.read_text())
    # the advertised channels: the box's groups per joint, JSON with a JSON Schema
    joints = ("j1", "j2", "j3", "j4", "j5", "j6", "hand")
    assert set(channels) == {f"/{j}" for j in joints} | {f"/drv/{j}" for j in joints}
    assert channels["/j1"]["encoding"] == "json" and channels["/j1"]["schemaEncoding"] == "jsonschema"
    schema = json.loads(channels["/j1"]["schema"])
    j1 = [(ns, m) for topic, ns, m in got if topic == "/j1"]
    drv = [(ns, m) for topic, ns, m in got if topic == "/drv/j1"]
    # the same rows on both channels (the very last one may be cut off by the server's stop)
    assert len(j1) >= 10 and [m["tick"] for _, m in j1][:-1] == [m["tick"] for _, m in drv][:len(j1) - 1]
    for ns, m in j1:
        assert set(m) == set(schema["properties"]) and ns == m["tick"] * PERIOD_NS
    # decimated: every 5th tick while servoing, and every tick whose stop state changed
    running = [m["tick"] for _, m in j1 if m["stop_state"] == 0]
    assert all(k % EVERY == 0 for k in running) and all(b - a == EVERY for a, b in itertools.pairwise(running))
    # the stop: SIGINT at the tick the JSON names, a category-1 stop (1), then the power off (3)
    interrupt = summary["final_stop"]["interruptions"][0]
    assert interrupt["signal"] == "SIGINT" and interrupt["during"] == "run"
    first_stopping = next(m for _, m in j1 if m["stop_state"] == 1)
    assert first_stopping["tick"] == interrupt["tick"]
    assert summary["final_stop"]["cause"] == "interrupted" and summary["final_stop"]["category"] == 1
    off = [m["tick"] for _, m in j1 if m["stop_state"] == 3]
    assert off and all(m["stop_state"] == 3 for _, m in j1 if m["tick"] >= off[0])
    # up to the run's last tick (the final stop's: sent when the view closes), powered off and braked
    assert off[-1] <= summary["final_stop"]["tick"] - 1
    assert drv[-1][1]["amp_enable"] is False
    assert drv[-1][1]["brake_released"] is False
    # the values: those of the black box the JSON names, tick for tick
    from mcap.reader import make_reader

    box: dict[tuple[str, int], dict] = {}
    with Path(summary["final_stop"]["blackbox"]).open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages(topics=["/j1", "/drv/j1"]):
            body = json.loads(message.data)
            box[(channel.topic, body["tick"])] = body
    compared = 0
    for topic, _, m in got:
        if (topic, m["tick"]) in box:
            assert m == box[(topic, m["tick"])]
            compared += 1
    assert compared >= 20  # the stop and the 2 s after it are in both


@pytest.mark.parametrize("command", ["run", "console"])
def test_a_non_loopback_live_address_is_refused_in_one_line(capsys, command):
    assert cli.main([command, "--live", "0.0.0.0:8765", "--duration", "1"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "not a loopback address" in err[0] and "--live-allow-remote" in err[0], err
    assert captured.out == ""  # refused before anything was built: no run, no table


def test_a_live_port_in_use_is_refused_in_one_line_before_anything_runs(capsys):
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert cli.main(["run", "--live", f"127.0.0.1:{port}", "--duration", "1"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "in use" in err[0], err
    assert err[0].startswith(f"vmehil run: error: --live 127.0.0.1:{port}: ")
    assert captured.out == ""
