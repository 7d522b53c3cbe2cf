"""python-can bus creation, the network-namespace guard for ``udp_multicast``, and bus logging.

Configuration follows python-can's own conventions: explicit ``interface``/``channel`` win;
otherwise ``CAN_INTERFACE`` / ``CAN_CHANNEL`` (and ``CAN_CONFIG``) from the environment or
python-can's config file (:func:`config_files`: on Linux ``~/can.conf``, ``/etc/can.conf``,
``~/.can``, ``~/.canrc``; ``can.ini`` is read on Windows only; section ``[default]``) are used;
with nothing configured the in-process ``virtual`` bus on channel ``vmehil``. An interface name
python-can does not know is an error naming it and the known ones.

All buses are opened for CAN FD (the SENS, SYNC, STATUS and TRUTH frames are FD frames).

**udp_multicast** sends to an IP multicast group. On a shared machine that traffic must not
leave the host, so :func:`open_bus` refuses it outside a private network namespace that has
only loopback (see :func:`private_multicast_namespace`) unless ``VMEHIL_ALLOW_MULTICAST=1``
says the network is yours. The IPv4 group 239.74.163.2 (python-can's IPv4 default) is used by
default; inside the namespace it needs ``ip route add 224.0.0.0/4 dev lo``.

An :class:`Endpoint` has named faults (:class:`emulators.faults.FaultInjectable`): ``frame_loss``
(a percentage of frames lost, seeded) and ``frame_delay`` (frames held back before delivery).
"""

from __future__ import annotations

import heapq
import itertools
import os
import socket
import subprocess
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import can

from emulators.errors import EmulatorError
from emulators.faults import FaultInjectable
from emulators.rng import rng_for

DEFAULT_CHANNEL = {"virtual": "vmehil", "socketcan": "vcan0", "udp_multicast": "239.74.163.2"}
INTERFACES = ("virtual", "socketcan", "udp_multicast")


class BusConfigError(EmulatorError, ValueError):
    """The bus cannot be opened as configured (message says what to change)."""


def config_files() -> list[str]:
    """The configuration files python-can reads on this platform (``can.util.CONFIG_FILES``; on
    Linux and macOS ``~/can.conf``, ``/etc/can.conf``, ``~/.can``, ``~/.canrc`` — ``can.ini`` only on
    Windows), section ``[default]``."""
    return list(can.util.CONFIG_FILES)


def _configured_interface(interface: str | None) -> tuple[str | None, str]:
    """The interface name python-can's configuration gives, and where it came from."""
    if interface:
        return interface, "--interface"
    sources: list[tuple[str, Any]] = [
        ("can.rc", lambda: dict(can.rc)),
        ("CAN_INTERFACE / CAN_CONFIG", can.util.load_environment_config),
        (f"python-can's config file ({', '.join(config_files())}, section [default])", can.util.load_file_config),
    ]
    for where, load in sources:
        cfg = load()
        name = cfg.get("interface") or cfg.get("bustype")
        if name:
            return str(name), where
    return None, ""


def unknown_interface_message(name: str, where: str) -> str:
    """What to say about an interface name python-can does not know."""
    others = sorted(set(can.VALID_INTERFACES) - set(INTERFACES))
    return (f"unknown CAN interface {name!r} (from {where}): vmehil runs on {', '.join(INTERFACES)} "
            f"(virtual: in this process, the default; socketcan: vcan0; udp_multicast: between processes); "
            f"python-can also knows {', '.join(others)}")


def resolve(interface: str | None = None, channel: str | None = None) -> tuple[str, str]:
    """Interface and channel after python-can's config resolution (arguments, environment,
    config file), defaulting to ``virtual``/``vmehil``.

    Raises :class:`BusConfigError` naming an interface python-can does not know (and where it
    was configured) with the known ones — never a silent fall-back to ``virtual``."""
    name, where = _configured_interface(interface)
    if name is not None and name not in can.VALID_INTERFACES:
        raise BusConfigError(unknown_interface_message(name, where))
    given: dict[str, Any] = {"interface": name or "virtual"}
    if channel:
        given["channel"] = channel
    cfg: Mapping[str, Any] = can.util.load_config(config=given)
    iface = str(cfg["interface"])
    chan = cfg.get("channel") or DEFAULT_CHANNEL.get(iface)
    if chan is None:
        raise BusConfigError(f"interface {iface!r} needs a channel: pass --channel or set CAN_CHANNEL")
    return iface, str(chan)


def socketcan_available() -> bool:
    """True when this kernel lets us open a raw CAN socket (``AF_CAN``)."""
    af = getattr(socket, "AF_CAN", None)
    if af is None:
        return False
    try:
        s = socket.socket(af, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError:
        return False
    s.close()
    return True


def vcan_exists(name: str = "vcan0") -> bool:
    return Path(f"/sys/class/net/{name}").exists()


def private_multicast_namespace() -> bool:
    """True inside a network namespace whose only interface is ``lo`` and that routes the IPv4
    multicast range (224.0.0.0/4) over ``lo``: multicast there cannot leave the host."""
    try:
        names = [n for _, n in socket.if_nameindex()]
    except OSError:
        return False
    if names != ["lo"]:
        return False
    try:
        out = subprocess.run(["ip", "route", "show", "table", "all"], capture_output=True, text=True,
                             timeout=5, check=False).stdout
    except (OSError, subprocess.SubprocessError):
        return False
    return any(line.split()[:1] == ["224.0.0.0/4"] and "dev lo" in line
               for line in out.splitlines() if line.strip())


def multicast_allowed() -> bool:
    return os.environ.get("VMEHIL_ALLOW_MULTICAST") == "1" or private_multicast_namespace()


def open_bus(interface: str | None = None, channel: str | None = None, **kwargs: Any) -> can.BusABC:
    """Open a CAN FD bus with python-can (see the module docstring for the resolution rules).

    Raises :class:`BusConfigError` with what to do when the transport is unusable here.
    """
    iface, chan = resolve(interface, channel)
    if iface == "udp_multicast" and not multicast_allowed():
        raise BusConfigError(
            "udp_multicast would send multicast beyond this host: run node and controller inside one private "
            "network namespace, e.g. unshare -rn sh -c 'ip link set lo up; ip route add 224.0.0.0/4 dev lo; "
            "vmehil plant-node --interface udp_multicast & vmehil run --plant can --interface udp_multicast; "
            "kill $!' (unshare -n as root), or set VMEHIL_ALLOW_MULTICAST=1 on a network that is yours; "
            "for one process, leave --interface out (virtual)")
    if iface == "socketcan" and not socketcan_available():
        raise BusConfigError("socketcan: this kernel has no usable AF_CAN sockets; leave --interface out "
                             "(virtual, the node in this process) or use udp_multicast between processes")
    opts: dict[str, Any] = {"fd": True}
    if iface == "udp_multicast":
        opts["receive_own_messages"] = False
    opts.update(kwargs)
    try:
        return can.Bus(interface=iface, channel=chan, **opts)
    except (OSError, can.CanError) as e:
        hint = (f" (create it with: sudo ip link add dev {chan} type vcan && sudo ip link set {chan} mtu 72 up;"
                " or sudo ./vcan_setup.sh in a vmehil checkout)" if iface == "socketcan" else "")
        raise BusConfigError(f"cannot open {iface} channel {chan!r}: {e}{hint}") from e


class Endpoint(FaultInjectable):
    """One node's view of a bus: sends and receives frames, logging both directions.

    Frames whose identifier this node sends itself (``own_ids``) are ignored on receive:
    ``udp_multicast`` loops a node's own frames back to it.
    """

    FAULTS = {  # noqa: RUF012 - the FaultInjectable catalogue
        "frame_loss": "percent=P[, direction=both|rx|tx, seed=S]: each frame sent (tx) or received (rx) "
                      "here is lost with probability P %",
        "frame_delay": "ms=D[, percent=P, seed=S]: P % (default 100) of the frames received here arrive D ms "
                       "(wall clock) late, so later frames may overtake them",
    }

    def __init__(self, bus: can.BusABC, own_ids: set[int], *, log_path: str | Path | None = None,
                 owns_bus: bool = True) -> None:
        self.bus = bus
        self.own_ids = set(own_ids)
        self.owns_bus = owns_bus
        self.logger: can.Listener | None = can.Logger(str(log_path)) if log_path else None
        self.sent = 0
        self.received = 0
        self.lost = 0  #: frames dropped by an injected ``frame_loss``
        self._held: list[tuple[float, int, can.Message]] = []  # frame_delay: (release time, order, frame)
        self._order = itertools.count()

    def _fault_changed(self, name: str) -> None:
        f = self.fault(name)
        if f is None:
            return
        for key in ("percent", "ms"):
            if key in f and not 0.0 <= float(f[key]) <= (100.0 if key == "percent" else 60_000.0):
                self.clear_fault(name)
                raise ValueError(f"CAN fault {name}: {key} = {f[key]} is out of range")
        if name == "frame_loss" and f.get("direction", "both") not in ("both", "rx", "tx"):
            self.clear_fault(name)
            raise ValueError(f"CAN fault frame_loss: direction {f['direction']!r} is not both, rx or tx")
        f["_rng"] = rng_for(int(f.get("seed", 0)), "can", name)

    def _hit(self, name: str, direction: str) -> bool:
        """True when fault ``name`` takes this frame (seeded draw per frame)."""
        f = self.fault(name)
        if f is None or f.get("direction", "both") not in ("both", direction):
            return False
        return bool(f["_rng"].random() * 100.0 < float(f.get("percent", 100.0)))

    def send(self, msg: can.Message) -> None:
        if self._hit("frame_loss", "tx"):
            self.lost += 1
            return
        msg.timestamp = time.time()
        msg.channel = msg.channel or "vmehil"
        msg.is_rx = False
        self.bus.send(msg)
        self.sent += 1
        if self.logger is not None:
            self.logger(msg)

    def recv(self, timeout: float | None) -> can.Message | None:
        """The next frame from the other node(s), or ``None`` after ``timeout`` seconds."""
        deadline = None if timeout is None else time.monotonic() + max(0.0, timeout)
        m: can.Message | None
        while True:
            now = time.monotonic()
            if self._held and self._held[0][0] <= now:  # a delayed frame is due
                m = heapq.heappop(self._held)[2]
                break
            left = None if deadline is None else max(0.0, deadline - now)
            if self._held:
                left = self._held[0][0] - now if left is None else min(left, self._held[0][0] - now)
            m = self.bus.recv(left)
            if m is None:
                now = time.monotonic()
                if deadline is not None and now >= deadline and not (self._held and self._held[0][0] <= now):
                    return None
                continue  # woken for a delayed frame (or early): look again
            if not m.is_extended_id and m.arbitration_id in self.own_ids and not m.is_error_frame:
                # our own frame looped back: skip it and look again. A poll (timeout 0) must still
                # see what is queued behind it, so the deadline is checked only when the bus
                # itself has nothing (above), never here.
                continue
            if self._hit("frame_loss", "rx"):
                self.lost += 1
                continue
            if self._hit("frame_delay", "rx"):
                delay = self.fault("frame_delay")
                assert delay is not None  # _hit is only True while the fault is on
                due = time.monotonic() + float(delay.get("ms", 0.0)) * 1e-3
                heapq.heappush(self._held, (due, next(self._order), m))
                continue
            break
        self.received += 1
        if self.logger is not None:
            m.channel = m.channel or "vmehil"
            self.logger(m)
        return m

    def close(self) -> None:
        if self.logger is not None:
            self.logger.stop()
            self.logger = None
        if self.owns_bus:
            self.bus.shutdown()


def replay(path: str | Path):
    """Iterate the frames of a recorded log (any format python-can reads: ``.log`` candump, ``.asc``,
    ``.blf``, ``.csv``)."""
    yield from can.LogReader(str(path))
