"""The console server: a transport (serial device, pty, pyserial URL, loopback listener), a reader
thread, a writer thread, and the hand-over of commands to the loop at tick boundaries.

Threads and bounds (the console never blocks the 125 Hz loop):

* the **reader** thread reads bytes and assembles lines (:class:`~vmehil.console.protocol.LineAssembler`,
  bounded to ``MAX_LINE``); it acts on ``stop`` itself and hands every other line to the
  preparer through a bounded queue (``queue_size``; full: ``ERR BUSY`` at once, line dropped).
  It never opens a file, so nothing a command names can keep it from hearing ``stop``;
* the **preparer** thread parses and type-checks the lines in order, reads the files a command
  needs (motion and compound files: regular files under a size bound), and puts the command in
  the loop's bounded queue (``queue_size``; full: ``ERR BUSY``, dropped);
* the **loop** thread runs :meth:`Console.on_tick` after every tick (a runner's ``after_tick``
  hook). When work is waiting it submits one *pump* with :meth:`servo.loop.ServoLoop.submit`;
  the pump runs at the next tick boundary, executes at most ``per_tick`` queued commands and
  advances the compound commands by a bounded number of statements. The loop thread never does
  I/O: replies go to a bounded outbox;
* the **writer** thread writes the outbox to the transport; writes time out (0.5 s), so a client
  that stops reading loses output (``EVT overflow dropped=N`` tells it) but stalls nothing.

``stop`` jumps the queue: it is submitted directly (one at a time) so a flood cannot delay it.
"""

from __future__ import annotations

import contextlib
import errno
import ipaddress
import os
import queue
import select
import socket
import termios
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import urlsplit

from servo.runner import WATCH_AFTER_STOP_S
from vmehil.console.commands import ATOMS, URGENT_STOPS, Atom, Outcome, Session, bind, bind_request, stop_event
from vmehil.console.compound import CompoundLibrary, Executor, prepare
from vmehil.console.protocol import (
    BINARY,
    BUSY,
    INTERNAL,
    LONG,
    MAX_LINE,
    STATE,
    UNKNOWN,
    ConsoleError,
    LineAssembler,
    is_reply_line,
    kv,
    one_line,
    parse_line,
)
from vmehil.console.terminal import TerminalView
from vmehil.errors import VmehilError
from vmehil.writers.ascii_text import to_ascii

DEFAULT_PTY_LINK = "/tmp/vmehil-console"
READ_TIMEOUT_S = 0.1
WRITE_TIMEOUT_S = 0.5


class ConsoleSetupError(VmehilError, ValueError):
    """The console's PORT cannot be opened (says which and what to do)."""


class Transport(Protocol):
    """A byte pipe to the operator's terminal. ``read`` returns b"" after ~0.1 s without data (or
    while no client is connected); ``write`` drops data it cannot deliver within 0.5 s."""

    description: str

    def read(self, n: int) -> bytes: ...

    def write(self, data: bytes) -> None: ...

    def close(self) -> None: ...


# ---- transports -------------------------------------------------------------------------------------------
def _check_loopback_host(host: str | None, what: str) -> None:
    if host in (None, ""):
        raise ConsoleSetupError(f"{what}: give a host (127.0.0.1)")
    if host == "localhost":
        return
    try:
        ok = ipaddress.ip_address(host).is_loopback
    except ValueError:
        raise ConsoleSetupError(f"{what}: host {host!r} must be a loopback address (127.0.0.1, ::1 or localhost); "
                                "vmehil sends nothing beyond this machine") from None
    if not ok:
        raise ConsoleSetupError(f"{what}: host {host!r} is not loopback; vmehil sends nothing beyond this machine")


class SerialTransport:
    """A pyserial port: a device path (``/dev/ttyUSB0``) or a URL (``loop://``, ``socket://127.0.0.1:N``,
    ``rfc2217://127.0.0.1:N``, ``spy://…``). A port that fails (device unplugged, server gone) is
    reopened with a back-off."""

    def __init__(self, port: str, baudrate: int = 115200) -> None:
        import serial

        self._serial = serial
        self.port = port
        self.description = port
        url = port if "://" in port else None
        if url is not None:
            check_url(url)
        try:
            if url is not None:
                self.ser = serial.serial_for_url(url, baudrate=baudrate, timeout=READ_TIMEOUT_S,
                                                 write_timeout=WRITE_TIMEOUT_S)
            else:
                self.ser = serial.Serial(port, baudrate=baudrate, timeout=READ_TIMEOUT_S,
                                         write_timeout=WRITE_TIMEOUT_S)
        except (serial.SerialException, OSError, ValueError) as e:
            raise ConsoleSetupError(f"cannot open console port {port!r}: {e}") from None
        self._closed = False
        self._lock = threading.Lock()

    def read(self, n: int) -> bytes:
        try:
            waiting = self.ser.in_waiting
            return self.ser.read(max(1, min(n, waiting)))
        except (self._serial.SerialException, OSError, AttributeError, TypeError):
            self._recover()
            return b""

    def write(self, data: bytes) -> None:
        try:
            with self._lock:
                self.ser.write(data)
        except self._serial.SerialTimeoutException:
            return
        except (self._serial.SerialException, OSError, AttributeError, TypeError):
            return

    def _recover(self) -> None:
        if self._closed:
            return
        with contextlib.suppress(Exception):
            self.ser.close()
        time.sleep(0.5)
        if self._closed:
            return
        with contextlib.suppress(Exception):
            self.ser.open()

    def close(self) -> None:
        self._closed = True
        with contextlib.suppress(Exception):
            self.ser.close()


def check_url(url: str) -> None:
    """Refuse pyserial URLs that would reach beyond loopback."""
    scheme = url.split("://", 1)[0].lower()
    if scheme == "spy" or scheme == "alt":
        inner = url.split("://", 1)[1]
        if "://" in inner:
            check_url(inner)
        return
    if scheme in ("socket", "rfc2217"):
        parts = urlsplit(url)
        _check_loopback_host(parts.hostname, url)
        if parts.port is None:
            raise ConsoleSetupError(f"{url}: give a port (socket://127.0.0.1:PORT)")


class PtyTransport:
    """A pseudo-terminal vmehil creates: terminal programs open its slave side through ``link``
    (a symlink to ``/dev/pts/N``). The pty is raw (no echo, no CR/LF mapping). A client that
    closes the pty (EIO on the master) is waited for again; output meanwhile is discarded."""

    def __init__(self, link: str | None = DEFAULT_PTY_LINK) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)
        self.slave_path = os.ttyname(slave)
        os.close(slave)
        os.set_blocking(master, False)
        self.master = master
        self.link = link
        self.connected = False
        #: called (reader thread) when a client opens the slave side: the console greets it
        self.on_connect: Callable[[], None] | None = None
        self._closed = False
        if link:
            try:
                make_link(link, self.slave_path)
            except ConsoleSetupError:
                os.close(master)
                raise
        self.description = f"{self.slave_path}" + (f" (link {link})" if link else "")

    def read(self, n: int) -> bytes:
        if self._closed:
            time.sleep(READ_TIMEOUT_S)
            return b""
        try:
            r, _, _ = select.select([self.master], [], [], READ_TIMEOUT_S)
            if not r:  # no EIO: a client has the slave side open (it has not typed yet)
                self._connect()
                return b""
            data = os.read(self.master, n)
        except BlockingIOError:
            return b""
        except OSError as e:
            if e.errno in (errno.EIO, errno.EBADF):  # no client has the slave open
                if self.connected:
                    # the hung-up client's leftovers are flushed first, then it counts as gone: a
                    # new client that sees `connected` false and types at once must not lose its
                    # first line to this flush (it did, rarely: a test's reconnect waited 400 ticks)
                    with contextlib.suppress(OSError, termios.error):
                        termios.tcflush(self.master, termios.TCIOFLUSH)
                    self.connected = False
                time.sleep(READ_TIMEOUT_S)
                return b""
            raise
        self._connect()
        return data

    def _connect(self) -> None:
        if not self.connected:
            self.connected = True
            if self.on_connect is not None:
                self.on_connect()

    def write(self, data: bytes) -> None:
        if self._closed or not self.connected:
            return
        view = memoryview(data)
        deadline = time.monotonic() + WRITE_TIMEOUT_S
        while view:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return
            try:
                _, w, _ = select.select([], [self.master], [], remaining)
                if not w:
                    return
                k = os.write(self.master, view)
            except BlockingIOError:
                continue
            except OSError:
                return
            view = view[k:]

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self.link:
            with contextlib.suppress(OSError):
                if os.path.islink(self.link) and os.readlink(self.link) == self.slave_path:
                    os.unlink(self.link)
        with contextlib.suppress(OSError):
            os.close(self.master)


def make_link(link: str, target: str) -> None:
    """Point symlink ``link`` at ``target`` atomically; refuse to replace anything but a symlink."""
    p = Path(link)
    if p.exists() or p.is_symlink():
        if not p.is_symlink():
            raise ConsoleSetupError(f"{link} exists and is not a symlink; give another path (pty:/path/to/link)")
    if not p.parent.is_dir():
        raise ConsoleSetupError(f"cannot create {link}: folder {p.parent} does not exist")
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    try:
        os.symlink(target, tmp)
        os.replace(tmp, p)
    except OSError as e:
        raise ConsoleSetupError(f"cannot create the symlink {link} -> {target}: {e}") from None


class ListenTransport:
    """A TCP listener on a loopback address (``listen://127.0.0.1:PORT``, PORT 0 picks a free one),
    serving one client at a time — reachable with ``socat - TCP:127.0.0.1:PORT`` or any pyserial
    program as ``socket://127.0.0.1:PORT``. A second client is told ``ERR BUSY`` and closed."""

    def __init__(self, host: str, port: int) -> None:
        _check_loopback_host(host, f"listen://{host}:{port}")
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        try:
            self.server = socket.create_server((host, port), family=family, reuse_port=False)
        except OSError as e:
            raise ConsoleSetupError(f"cannot listen on {host}:{port}: {e}") from None
        self.server.setblocking(False)
        self.address = self.server.getsockname()[:2]
        self.description = f"listen://{self.address[0]}:{self.address[1]}"
        self.client: socket.socket | None = None
        self._lock = threading.Lock()
        self._closed = False

    def read(self, n: int) -> bytes:
        if self._closed:
            time.sleep(READ_TIMEOUT_S)
            return b""
        watch = [self.server] + ([self.client] if self.client is not None else [])
        try:
            r, _, _ = select.select(watch, [], [], READ_TIMEOUT_S)
        except (OSError, ValueError):
            time.sleep(READ_TIMEOUT_S)
            return b""
        if self.server in r:
            try:
                conn, _ = self.server.accept()
            except OSError:
                conn = None
            if conn is not None:
                if self.client is None:
                    conn.settimeout(WRITE_TIMEOUT_S)
                    with self._lock:
                        self.client = conn
                else:
                    with contextlib.suppress(OSError):
                        conn.sendall(b"ERR BUSY another client is connected to this console\r\n")
                    conn.close()
        c = self.client
        if c is not None and c in r:
            try:
                data = c.recv(n)
            except (OSError, TimeoutError):
                data = b""
            if not data:
                self._drop_client()
            return data
        return b""

    def _drop_client(self) -> None:
        with self._lock:
            c, self.client = self.client, None
        if c is not None:
            with contextlib.suppress(OSError):
                c.close()

    def write(self, data: bytes) -> None:
        with self._lock:
            c = self.client
        if c is None:
            return
        try:
            c.sendall(data)
        except (OSError, TimeoutError):
            self._drop_client()

    def close(self) -> None:
        self._closed = True
        self._drop_client()
        with contextlib.suppress(OSError):
            self.server.close()


def open_transport(port: str, *, baudrate: int = 115200) -> Transport:
    """Open the console PORT:

    * ``pty`` → a new pty linked at /tmp/vmehil-console; ``pty:/path/link`` → linked there;
    * ``listen://127.0.0.1:PORT`` → a loopback TCP listener;
    * any other ``scheme://`` → a pyserial URL (``loop://``, ``socket://127.0.0.1:N``, …; network
      URLs must name a loopback host);
    * anything else → a serial device path.
    """
    if port == "pty" or port.startswith("pty:"):
        link = port[4:] or DEFAULT_PTY_LINK
        return PtyTransport(link)
    if port.startswith("listen://"):
        parts = urlsplit(port)
        if parts.port is None and not port.endswith(":0"):
            raise ConsoleSetupError(f"{port}: give a port (listen://127.0.0.1:PORT, 0 for any free one)")
        return ListenTransport(parts.hostname or "", parts.port or 0)
    return SerialTransport(port, baudrate)


# ---- the console -------------------------------------------------------------------------------------------
@dataclass
class ConsoleStats:
    """Counters (read them for tests and reports)."""

    lines: int = 0  # request lines received (not counting blank, comment and reply-looking lines)
    handled: int = 0  # commands executed in the loop thread
    busy: int = 0  # lines dropped because the queue was full
    long: int = 0  # over-long lines discarded
    binary: int = 0  # lines with non-text bytes
    ignored: int = 0  # lines that looked like replies (loopback / echo)
    dropped_out: int = 0  # reply lines dropped because the outbox was full
    pumps: int = 0  # pumps run (at most one per tick)
    max_per_pump: int = 0  # most commands handled in one pump (≤ per_tick)


@dataclass
class _Item:
    kind: str  # "atom", "compound", "reply"
    name: str = ""
    target: Any = None
    args: dict[str, Any] = field(default_factory=dict)
    lines: list[str] = field(default_factory=list)


def _is_stop(text: str) -> bool:
    """Whether a request line is ``stop`` or ``estop`` (which the reader acts on itself, ahead of
    the queue)."""
    try:
        req = parse_line(text)
    except ConsoleError:
        return False
    return req is not None and req.name in URGENT_STOPS


class Console:
    """An operator console serving ``transport`` for ``loop``.

    Call :meth:`start` to launch the reader and writer threads, register :meth:`on_tick` to run
    after every tick (``runner.after_tick.append(console.on_tick)``), and :meth:`close` at the end.
    ``delay`` is the computation delay in periods (gain checks); ``library`` the compound commands;
    ``shutdown`` / ``calibrate`` optional host hooks.

    Deferred jobs (``Session.defer``, e.g. a calibration) run between two ticks in the thread
    that owns the rig: from :meth:`on_tick` (``jobs_on_tick``), or when the host calls
    :meth:`run_job`. While one waits or runs no pump is scheduled, so queued commands wait for
    it; ``stop`` still reaches the loop (the job's own ticks drain it) and aborts the job.
    """

    def __init__(self, loop: Any, transport: Transport | None, *, delay: float = 0.0,
                 library: CompoundLibrary | None = None, shutdown: Callable[[], None] | None = None,
                 calibrate: Callable[..., Outcome] | None = None, queue_size: int = 32, per_tick: int = 4,
                 outbox_size: int = 1000, max_line: int = MAX_LINE, jobs_on_tick: bool = True,
                 prompt: str | None = None, echo: bool = False, ascii_only: bool = True) -> None:
        self.loop = loop
        self.transport = transport
        self.session = Session(loop, delay, library if library is not None else CompoundLibrary(), None,
                               shutdown, calibrate)
        self.executor = Executor(self.session, self._emit)
        self.session.executor = self.executor
        self.session.defer = self._defer
        #: run deferred jobs from :meth:`on_tick` (False: the host calls :meth:`run_job` between
        #: runner chunks, so a wall-clock runner keeps its deadlines — see ``vmehil console``)
        self.jobs_on_tick = jobs_on_tick
        self._job: Callable[[Callable[[list[str]], None]], None] | None = None
        self.per_tick = per_tick
        self.stats = ConsoleStats()
        # taps: called with every reply/event line sent (a transcript, tests over loop://)
        self.taps: list[Callable[[str], None]] = []
        self._queue: queue.Queue[_Item] = queue.Queue(maxsize=queue_size)
        self._outbox: queue.Queue[bytes] = queue.Queue(maxsize=outbox_size)
        #: replies in 7-bit ASCII (vmehil.writers.ascii_text): a serial terminal shows UTF-8 as mojibake
        self.ascii_only = ascii_only
        #: prompt, echo and history for a person at a terminal (None: bytes pass as they are)
        self.terminal: TerminalView | None = None
        if transport is not None and (prompt or echo):
            self.terminal = TerminalView(transport.write, prompt=prompt, echo=echo)
        self._assembler = LineAssembler(max_line, keys=self.terminal is not None)
        self._max_line = max_line
        self._scheduled = False
        self._stop_pending = threading.Event()
        self._closing = threading.Event()
        self._threads: list[threading.Thread] = []
        # lines from the reader to the preparer; None: handle_line runs in the caller (no threads)
        self._lines: queue.Queue[str] | None = None
        # input lines dealt with (queued for the loop, answered, or a stop submitted), by either
        # thread: a caller waits on it (wait_taken) rather than on a clock
        self._taken = 0
        self._taken_cv = threading.Condition()
        self._last_fault = loop.fault
        self._dropped_since = 0
        #: the stop announced last (its begin tick) and the tick the current one completed
        self._announced_stop: int | None = None
        self._stop_done_tick: int | None = None

    # ---- lifecycle ---------------------------------------------------------------------------------------
    def start(self) -> Console:
        if self.transport is None:
            raise ConsoleSetupError("no transport to serve")
        self._lines = queue.Queue(maxsize=self._queue.maxsize)
        for name, fn in (("console-reader", self._reader), ("console-preparer", self._preparer),
                         ("console-writer", self._writer)):
            t = threading.Thread(target=fn, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        if hasattr(self.transport, "on_connect"):  # a pty: greet each terminal program when it opens it
            self.transport.on_connect = self._connected
        else:
            self._hello()
        return self

    def _connected(self) -> None:
        """A terminal program opened the pty (the reader thread): forget what an earlier one had
        half typed, and greet it."""
        self._assembler.replace("")
        if self.terminal is not None:
            self.terminal.reset()
        self._hello()

    def _hello(self) -> None:
        self._emit(kv("EVT", "hello", "vmehil console", joints=self.loop.n, names=",".join(self.loop.names),
                      help="help lists the commands"))

    def close(self) -> None:
        self._closing.set()
        with contextlib.suppress(queue.Full):
            self._outbox.put_nowait(b"")  # wake the writer
        for t in self._threads:
            t.join(timeout=2.0)
        if self.transport is not None:
            self.transport.close()

    # ---- reader side (any thread but the loop's) ---------------------------------------------------------
    def _reader(self) -> None:
        assert self.transport is not None
        while not self._closing.is_set():
            try:
                data = self.transport.read(4096)
            except Exception:  # a transport bug must not end the console
                time.sleep(READ_TIMEOUT_S)
                continue
            if data:
                self.feed(data)

    def feed(self, data: bytes) -> None:
        """Process received bytes (the reader thread calls this; tests may too)."""
        events = (self.terminal.feed(data, self._assembler) if self.terminal is not None
                  else self._assembler.feed(data))
        for ev in events:
            if ev.kind == "long":
                self.stats.long += 1
                self._enqueue_reply([f"ERR {LONG} line longer than {self._max_line} bytes discarded"])
                self._took()
            elif ev.kind == "binary":
                self.stats.binary += 1
                self._enqueue_reply([f"ERR {BINARY} line with non-text bytes discarded"])
                self._took()
            elif ev.kind != "line":
                continue  # a cursor key (the terminal view used it)
            elif is_reply_line(ev.text):
                # dropped here, not by the preparer: a link that echoes (loop://, a terminal with
                # local echo) hands every reply back, and queued they filled the input queue: a help
                # reply's ~40 lines made the next command ERR BUSY while the preparer was starved
                self.stats.ignored += 1
            elif self._lines is None or _is_stop(ev.text):
                self.handle_line(ev.text)
                self._took()
            else:
                try:
                    self._lines.put_nowait(ev.text)
                except queue.Full:
                    self.stats.busy += 1
                    self._send([f"ERR {BUSY} console input queue full ({self._lines.maxsize} lines being "
                                "prepared); line dropped, wait for the replies before sending more"])
                    self._took()

    def _preparer(self) -> None:
        """Parse, check and read the files of the lines the reader hands over, in their order."""
        assert self._lines is not None
        while not self._closing.is_set():
            try:
                text = self._lines.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                self.handle_line(text)
            except Exception as e:  # a bug in one command's preparation must not end the console
                self._send([f"ERR {INTERNAL} {one_line(f'{type(e).__name__}: {e}')}"])
            self._took()

    def _took(self) -> None:
        with self._taken_cv:
            self._taken += 1
            self._taken_cv.notify_all()

    def lines_taken(self) -> int:
        """Input lines (not echoed replies) dealt with so far: queued for the loop, answered at
        once, or a stop submitted to the loop."""
        with self._taken_cv:
            return self._taken

    def wait_taken(self, n: int, timeout_s: float) -> bool:
        """Wait until :meth:`lines_taken` reaches ``n`` (False: ``timeout_s`` passed first). A
        driver that counts ticks waits on this first, so the reader and preparer threads' share
        of the machine does not change how many ticks a reply takes."""
        with self._taken_cv:
            return self._taken_cv.wait_for(lambda: self._taken >= n, timeout_s)

    def handle_line(self, text: str) -> None:
        """Parse, check and queue one request line."""
        if is_reply_line(text):
            self.stats.ignored += 1
            return
        try:
            req = parse_line(text)
        except ConsoleError as e:
            self.stats.lines += 1
            self._enqueue_reply([e.reply_line()])
            return
        if req is None:
            return
        self.stats.lines += 1
        loop = self.loop
        try:
            atom = ATOMS.get(req.name)
            if atom is not None and atom.on_line:
                bound = bind_request(atom, req.args, loop.n, list(loop.names))
                if atom.name in URGENT_STOPS:
                    self._urgent_stop(atom.name)
                    return
                bound = prepare(atom.name, bound, loop.n, list(loop.names), loop)
                self._enqueue(_Item("atom", atom.name, atom, bound))
                return
            defn = self.session.library.get(req.name) if self.session.library is not None else None
            if defn is not None:
                env = bind(defn.name, defn.params, [(a.key, a.value) for a in req.args], loop.n, list(loop.names))
                self._enqueue(_Item("compound", defn.name, defn, env))
                return
            if atom is not None:
                raise ConsoleError(UNKNOWN, f"{req.name} can only be used inside compound commands")
            raise ConsoleError(UNKNOWN, f"no command {req.name!r}; help lists the commands")
        except ConsoleError as e:
            self._enqueue_reply([e.reply_line()])

    def _enqueue_reply(self, lines: list[str]) -> None:
        self._enqueue(_Item("reply", lines=lines))

    def _enqueue(self, item: _Item) -> None:
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.stats.busy += 1
            self._send([f"ERR {BUSY} console queue full ({self._queue.maxsize} commands waiting); line dropped, "
                        "wait for the replies before sending more"])

    def _urgent_stop(self, name: str = "stop") -> None:
        # an estop is never merged into a pending stop: it is the stricter one (category 0)
        if name == "stop" and self._stop_pending.is_set():
            self._send(["INFO a stop is already pending", "OK stop pending=1"])
            return
        self._stop_pending.set()

        def do_stop(loop: Any) -> None:
            try:
                self._run_item(_Item("atom", name, ATOMS[name], {}))
            finally:
                self._stop_pending.clear()

        self.loop.submit(do_stop)

    # ---- loop side (the loop's thread, at tick boundaries) ----------------------------------------------
    def on_tick(self, loop: Any) -> None:
        """Call after every tick (the runner's ``after_tick``): report new faults, and submit a pump
        for the next tick boundary when commands wait or compound commands run."""
        f = loop.fault
        if f is not None and f is not self._last_fault:
            self._emit(kv("EVT", "fault", cause=f.cause, joint=f.joint or "-", tick=f.tick, detail=f.detail))
        self._last_fault = f
        self._watch_stop(loop)
        if self._job is not None:
            if not self.jobs_on_tick:
                return  # the host runs it between runner chunks
            self.run_job()
            return
        if not self._scheduled and (not self._queue.empty() or self.executor.active):
            self._scheduled = True
            loop.submit(self._pump)

    def _watch_stop(self, loop: Any, *, now: bool = False) -> None:
        """``EVT stop category=N cause=… excursion_deg=…`` once per stop, when the joints have been
        watched for the 2 s after it (or ``now``: the session ends before that)."""
        began = getattr(loop, "stop_tick", None)
        if began is None or began == self._announced_stop or loop.enabled or loop.stopping is not None:
            self._stop_done_tick = None
            return
        if self._stop_done_tick is None:
            self._stop_done_tick = loop.tick_count
        if not now and loop.tick_count - self._stop_done_tick < round(WATCH_AFTER_STOP_S / loop.period_s):
            return
        self._announced_stop = began
        self._emit(stop_event(loop))

    def announce_stop(self) -> None:
        """At the end of a session: the last stop's EVT, if it was not announced yet."""
        self._watch_stop(self.loop, now=True)

    def _pump(self, loop: Any) -> None:
        self._scheduled = False
        self.stats.pumps += 1
        handled = 0
        while handled < self.per_tick:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                break
            handled += 1
            self._run_item(item)
        self.stats.max_per_pump = max(self.stats.max_per_pump, handled)
        try:
            self.executor.step()
        except Exception as e:  # never into the loop
            self._emit(f"EVT error {INTERNAL} compound executor: {one_line(f'{type(e).__name__}: {e}')}")
            self.executor.cancel_all("internal error")

    # ---- deferred jobs (the loop's thread, between ticks) -----------------------------------------------
    def _defer(self, job: Callable[[Callable[[list[str]], None]], None]) -> None:
        if self._job is not None:
            raise ConsoleError(STATE, "another long command (a calibration) is waiting to run")
        self._job = job

    def job_waiting(self) -> bool:
        """True while a deferred job waits for :meth:`run_job`."""
        return self._job is not None

    def run_job(self) -> bool:
        """Run the waiting deferred job, if any (call between ticks, in the thread that ticks the
        loop); returns whether one ran. The job's errors become an ``ERR INTERNAL`` line."""
        job, self._job = self._job, None
        if job is None:
            return False
        try:
            job(self._send)
        except Exception as e:
            self._send([f"ERR {INTERNAL} {one_line(f'{type(e).__name__}: {e}')}"])
        return True

    def _run_item(self, item: _Item) -> None:
        if item.kind == "reply":
            self._send(item.lines)
            return
        self.stats.handled += 1
        try:
            if item.kind == "compound":
                inv = self.executor.start(item.target, item.args)
                self._send([kv("OK", item.name, id=inv)])
                return
            atom: Atom = item.target
            out = atom.run(self.session, item.args)
            if out.deferred:
                self._send(out.lines)  # the deferred job sends the rest and the end line
                return
            self._send([*out.lines, f"OK {item.name} {out.ok}".rstrip()])
        except ConsoleError as e:
            self._send([e.reply_line()])
        except Exception as e:
            self._send([f"ERR {INTERNAL} {item.name}: {one_line(f'{type(e).__name__}: {e}')}"])

    # ---- output --------------------------------------------------------------------------------------------
    def _emit(self, line: str) -> None:
        self._send([line])

    def _send(self, lines: list[str]) -> None:
        for tap in self.taps:
            for ln in lines:
                tap(to_ascii(ln) if self.ascii_only else ln)
        text = "".join(one_line(ln) + "\r\n" for ln in lines)
        data = to_ascii(text).encode("ascii", errors="replace") if self.ascii_only else text.encode("utf-8")
        try:
            self._outbox.put_nowait(data)
        except queue.Full:
            self.stats.dropped_out += len(lines)
            self._dropped_since += len(lines)

    def _writer(self) -> None:
        assert self.transport is not None
        while not self._closing.is_set():
            try:
                data = self._outbox.get(timeout=0.2)
            except queue.Empty:
                continue
            if not data:
                continue
            write = self.terminal.output if self.terminal is not None else self.transport.write
            try:
                write(data)
                if self._dropped_since:
                    n, self._dropped_since = self._dropped_since, 0
                    write(f"EVT overflow dropped={n}\r\n".encode())
            except Exception:
                continue

    def preparing(self) -> int:
        """Lines the reader handed over that the preparer has not taken yet."""
        return self._lines.qsize() if self._lines is not None else 0

    def pending(self) -> int:
        """Commands waiting in the queue."""
        return self._queue.qsize()
