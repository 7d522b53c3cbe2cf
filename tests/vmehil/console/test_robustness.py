"""The console under abuse: floods, over-long lines, binary garbage, clients that disconnect or never
read — and a real terminal program (socat) on the pty. Loop health is measured in ticks executed
and commands handled per tick (lockstep: the test drives the ticks), never in wall-clock time."""

from __future__ import annotations

import os
import queue
import shutil
import socket
import subprocess
import threading
import time

import pytest
import serial

from tests.support.console import Driver, LineReader, tap_poll
from tests.support.fakes import make_loop, tick
from vmehil.console.server import Console, ConsoleSetupError, ListenTransport, open_transport


def _pty_console(tmp_path, **kw):
    loop = make_loop(2)
    link = tmp_path / "console"
    console = Console(loop, open_transport(f"pty:{link}"), **kw).start()
    return loop, console, str(link)


def test_flood_never_stalls_the_loop_and_handling_is_bounded_per_tick(tmp_path):
    loop, console, link = _pty_console(tmp_path, queue_size=16, per_tick=4)
    client = serial.Serial(link, timeout=0.05, write_timeout=5)
    stop = threading.Event()
    sent = [0]

    def flood() -> None:  # a client that floods and never reads its replies
        chunk = b"status\r\n" * 64 + b"\x00\xff\xfe garbage\r\n" + b"x" * 2000 + b"\r\n"
        while not stop.is_set():
            try:
                client.write(chunk)
                sent[0] += 64
            except serial.SerialTimeoutException:
                pass

    t = threading.Thread(target=flood, daemon=True)
    t.start()
    try:
        # let the flood reach the queue: its first chunk fills it (busy) and carries a binary and a
        # long line. Waited for, not timed: under load the reader thread may take seconds to run.
        deadline = time.monotonic() + 60.0
        while not (console.stats.busy and console.stats.binary and console.stats.long):
            assert time.monotonic() < deadline, "the flood never reached the console's reader"
            time.sleep(0.01)
        ticks = 600
        k0 = loop.tick_count
        for _ in range(ticks):
            tick(loop, console)
            assert console.pending() <= 16
        assert loop.tick_count - k0 == ticks  # every tick ran (the test thread is the loop thread)
    finally:
        stop.set()
        t.join(timeout=10)
    st = console.stats
    assert st.busy > 0 and st.binary > 0 and st.long > 0
    assert st.max_per_pump <= 4
    assert st.pumps <= loop.tick_count and st.handled <= 4 * st.pumps
    assert loop.fault is None and loop.enabled
    # the flood is over (the reader still drains what the pty holds): the console answers again
    quiet, last = 0, -1
    for _ in range(2000):
        tick(loop, console)
        seen = console.stats.lines + console.stats.long + console.stats.binary
        quiet = quiet + 1 if (seen == last and console.pending() == 0) else 0
        last = seen
        if quiet >= 20:
            break
        time.sleep(0.001)
    assert quiet >= 20
    while not console._outbox.empty():  # forget the flood's replies still on their way
        console._outbox.get_nowait()
    client.write(b"echo flood-is-over\r\n")
    reader = LineReader(client.read)
    got: list[str] = []
    for _ in range(3000):
        tick(loop, console)
        got += reader.lines()
        if "OK echo" in got[got.index("INFO flood-is-over"):] if "INFO flood-is-over" in got else False:
            break
    i = got.index("INFO flood-is-over")
    assert got[i: i + 2] == ["INFO flood-is-over", "OK echo"]
    client.close()
    console.close()


def test_long_lines_and_binary_garbage_get_typed_errors(tmp_path):
    loop, console, link = _pty_console(tmp_path)
    client = serial.Serial(link, timeout=0.02)
    drv = Driver(loop, console, client.write, LineReader(client.read).lines)
    assert drv.ask("x" * 5000)[0].startswith("ERR LONG line longer than 512 bytes")
    assert drv.ask("\x01\x02\x1b[A status")[0].startswith("ERR BINARY")
    client.write(b"\xff\xfe\xfd\n")
    assert drv.reply()[0].startswith("ERR BINARY")
    assert drv.ask("status")[-1].startswith("OK status")
    client.close()
    console.close()


def test_client_disconnect_eio_then_reconnect(tmp_path):
    loop, console, link = _pty_console(tmp_path)
    for _ in range(3):  # connect, talk, hang up (EIO on the master), again
        client = serial.Serial(link, timeout=0.02)
        drv = Driver(loop, console, client.write, LineReader(client.read).lines)
        assert drv.ask("status")[-1].startswith("OK status")
        client.write(b"status\r\n")  # a request whose reply nobody reads
        client.close()
        tick(loop, console, 20)
        for _ in range(100):
            if not console.transport.connected:
                break
            time.sleep(0.01)
        assert not console.transport.connected
    assert all(t.is_alive() for t in console._threads)
    console.close()
    assert not os.path.lexists(link)  # the link is removed on close


def test_output_to_a_client_that_never_reads_is_dropped_not_blocking(tmp_path):
    loop, console, link = _pty_console(tmp_path, outbox_size=8)
    client = serial.Serial(link, timeout=0.02)
    drv = Driver(loop, console, client.write, LineReader(client.read).lines)
    drv.ask("status")
    for _ in range(300):  # many replies that are never read: the pty fills, the outbox overflows
        console._send(["DATA filler " + "y" * 400])
    tick(loop, console, 50)
    assert console.stats.dropped_out > 0
    assert loop.tick_count >= 50
    client.close()
    console.close()


SOCAT = shutil.which("socat")  # a system tool: `make venv` installs it where it can (apt-get as root)


@pytest.mark.skipif(SOCAT is None, reason="socat not installed")
def test_socat_terminal_exchanges_lines_with_the_console(tmp_path):
    loop, console, link = _pty_console(tmp_path)
    proc = subprocess.Popen([SOCAT, "-", f"{link},raw,echo=0"], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    lines: queue.Queue[str] = queue.Queue()

    def pump() -> None:
        assert proc.stdout is not None
        for raw in iter(proc.stdout.readline, b""):
            lines.put(raw.decode().strip("\r\n"))

    threading.Thread(target=pump, daemon=True).start()

    def send(data: bytes) -> None:
        assert proc.stdin is not None
        proc.stdin.write(data)
        proc.stdin.flush()

    def poll() -> list[str]:
        out = []
        while True:
            try:
                out.append(lines.get_nowait())
            except queue.Empty:
                return [x for x in out if x]

    try:
        drv = Driver(loop, console, send, poll)
        r = drv.ask("status")
        assert r[-1] == "OK status joints=2 state=running" and sum(x.startswith("DATA joint") for x in r) == 2
        assert drv.ask("move_joint 1 5")[-1].startswith("OK move_joint")
        assert drv.ask("gains j1")[0].startswith("DATA gains joint=j1 kp=100")
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        console.close()


def test_listen_url_serves_one_loopback_client(tmp_path):
    loop = make_loop(2)
    console = Console(loop, open_transport("listen://127.0.0.1:0")).start()
    assert isinstance(console.transport, ListenTransport)
    host, port = console.transport.address
    assert host == "127.0.0.1"
    client = serial.serial_for_url(f"socket://127.0.0.1:{port}", timeout=0.02)
    drv = Driver(loop, console, client.write, LineReader(client.read).lines)
    assert drv.ask("status")[-1].startswith("OK status")
    second = socket.create_connection(("127.0.0.1", port), timeout=5)
    second.settimeout(5)
    assert second.recv(200).startswith(b"ERR BUSY")
    second.close()
    assert drv.ask("echo still")[0] == "INFO still"
    client.close()
    console.close()


def test_socket_url_connects_out_to_a_loopback_terminal_server():
    srv = socket.create_server(("127.0.0.1", 0))
    port = srv.getsockname()[1]
    loop = make_loop(2)
    console = Console(loop, open_transport(f"socket://127.0.0.1:{port}")).start()
    srv.settimeout(5)
    conn, _ = srv.accept()
    conn.settimeout(0.02)

    def read(n: int) -> bytes:
        try:
            return conn.recv(n)
        except TimeoutError:
            return b""

    drv = Driver(loop, console, conn.sendall, LineReader(read).lines)
    assert drv.ask("status")[-1].startswith("OK status")
    conn.close()
    srv.close()
    console.close()


def test_loop_url_ignores_its_own_replies():
    loop = make_loop(2)
    console = Console(loop, open_transport("loop://")).start()
    drv = Driver(loop, console, console.transport.write, tap_poll(console))
    assert drv.ask("bogus")[0].startswith("ERR UNKNOWN")
    tick(loop, console, 20)
    assert console.stats.ignored >= 1 and console.stats.lines == 1
    console.close()


def test_echoed_replies_take_no_room_in_the_input_queue():
    # A link that echoes hands each reply back (loop://: a help reply's ~40 lines). The preparer
    # is held still here (the queue the reader fills, no threads), as a loaded machine starves it:
    # 40 echoed lines and one command must leave the command queued, not answered ERR BUSY.
    loop = make_loop(2)
    console = Console(loop, None)
    console._lines = queue.Queue(maxsize=32)
    sent: list[str] = []
    console.taps.append(sent.append)
    console.feed(b"".join(b"DATA help command=c%d usage=c%d\r\n" % (i, i) for i in range(40)) + b"help move\r\n")
    assert console.stats.ignored == 40 and console.stats.busy == 0 and sent == []
    assert console._lines.get_nowait() == "help move" and console.preparing() == 0


@pytest.mark.parametrize("port", ["socket://10.0.0.1:5000", "socket://example.com:23", "rfc2217://192.168.1.2:2217",
                                  "spy://socket://8.8.8.8:53", "listen://0.0.0.0:5555", "socket://127.0.0.1"])
def test_nothing_beyond_loopback(port):
    with pytest.raises(ConsoleSetupError):
        open_transport(port)


def test_pty_link_never_replaces_a_regular_file(tmp_path):
    f = tmp_path / "precious"
    f.write_text("keep")
    with pytest.raises(ConsoleSetupError, match="not a symlink"):
        open_transport(f"pty:{f}")
    assert f.read_text() == "keep"
    stale = tmp_path / "stale"
    os.symlink("/dev/pts/does-not-exist", stale)
    t = open_transport(f"pty:{stale}")
    assert os.readlink(stale) == t.slave_path
    t.close()


def test_run_and_load_refuse_devices_fifos_and_huge_files_and_stop_still_works(tmp_path):
    """`run /dev/zero` used to end in MemoryError and `run FIFO` blocked the reader thread so
    that `stop` was no longer heard."""
    loop, console, link = _pty_console(tmp_path)
    client = serial.Serial(link, timeout=0.02)
    drv = Driver(loop, console, client.write, LineReader(client.read).lines)
    fifo = tmp_path / "motion.fifo"
    os.mkfifo(fifo)
    huge = tmp_path / "huge.toml"
    huge.write_bytes(b"#" * (2 << 20))
    assert drv.ask("run /dev/zero")[-1].startswith("ERR FILE") and "not a regular file" in drv.ask("run /dev/zero")[-1]
    assert "not a regular file" in drv.ask(f"run {fifo}")[-1]
    assert "not a regular file" in drv.ask(f"load {fifo}")[-1]
    assert "the limit is" in drv.ask(f"run {huge}")[-1]
    assert drv.ask("stop")[-1].startswith("OK stop")
    client.close()
    console.close()


def test_stop_is_heard_while_a_motion_file_is_still_being_read(tmp_path, monkeypatch):
    """The reader thread never opens a file: a `run FILE` whose read does not return (a slow or hung
    file system) leaves `stop` working, and the stop is on the emulated boards."""
    import servo.motion
    from servo.runner import LockstepRunner
    from tests.support.boards import assert_boards_safe, driving
    from vmehil.rig_setup.session import build_loop
    from vmehil.rig_setup.system import build_emulated_rig

    entered, release = threading.Event(), threading.Event()
    real_load = servo.motion.load_motion

    def hung_load(path, n_joints):
        entered.set()
        release.wait()
        return real_load(path, n_joints)

    monkeypatch.setattr(servo.motion, "load_motion", hung_load)
    motion = tmp_path / "m.toml"
    motion.write_text('name = "hold"\n[[move]]\ntype = "wait"\nduration_s = 0.1\n')
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, n_ticks=0)
    loop.start()
    runner = LockstepRunner(system, loop)
    console = Console(loop, open_transport("loop://")).start()
    runner.after_tick.append(console.on_tick)
    drv = Driver(loop, console, console.transport.write, tap_poll(console), step=runner.tick)
    try:
        runner.run(100)  # the demo move is under way
        assert driving(system)
        console.transport.write(f"run {motion}\r\n".encode())
        assert entered.wait(30.0)  # the preparer is inside the read; it will not come back by itself
        reply = drv.ask("stop")
        assert reply[-1].startswith("OK stop"), reply
        runner.finish_stop()  # a category-1 stop: decelerate, brakes, then power off (#29)
        runner.tick()  # the exchange that carries it to the plant
        assert loop.fault is not None and loop.fault.cause == "operator_stop"
        assert_boards_safe(system)
    finally:
        release.set()
        console.close()
        system.close()
