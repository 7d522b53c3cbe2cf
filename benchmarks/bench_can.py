"""Lockstep ticks per second of the CAN plant node, against python-can's raw request/response rate.

    python benchmarks/bench_can.py [--rigs jpl-arm,melmalec-16] [--ticks 500] [--transports virtual,udp_multicast]

For each transport it measures, in the same run:

* **raw**: one classic frame out, one frame back from an echo peer (same arrangement as the plant
  node: a thread on ``virtual``, a second process on ``udp_multicast``) — the transport's
  request/response ceiling;
* **in-process**: the plant stepped through the same quantization without any bus;
* **lockstep**: :class:`~emulators.can.can_plant_link.CanPlantLink` ↔ :class:`~emulators.can.node.PlantNode`
  (``vmehil plant-node`` in a second process for ``udp_multicast``), per rig;

and prints ``lockstep / raw`` (what the message set and the plant cost relative to one bare
round trip) and ``lockstep / in-process``. ``udp_multicast`` runs only inside a private
loopback-only network namespace; when started as root outside one, the script re-executes
itself under ``unshare -n`` (no traffic leaves the host).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import can  # noqa: E402

from emulators.can.bus import Endpoint, open_bus, private_multicast_namespace  # noqa: E402

GROUP = "239.74.163.2"
ECHO_PORT = 43120


def echo(interface: str, channel: str, stop: threading.Event | None = None, **kw) -> None:
    """Answer every frame 0x001 with a frame 0x002 (the raw request/response peer)."""
    bus = open_bus(interface, channel, **{k: v for k, v in kw.items() if v is not None})
    reply = can.Message(arbitration_id=0x002, data=bytes(8), is_extended_id=False)
    try:
        while stop is None or not stop.is_set():
            m = bus.recv(0.1)
            if m is not None and m.arbitration_id == 0x001:
                bus.send(reply)
    finally:
        bus.shutdown()


def raw_rate(interface: str, channel: str, n: int, **kw) -> float:
    bus = open_bus(interface, channel, **kw)
    req = can.Message(arbitration_id=0x001, data=bytes(8), is_extended_id=False)

    def round_trip() -> bool:
        bus.send(req)
        t_end = time.monotonic() + 0.5
        while time.monotonic() < t_end:
            m = bus.recv(0.5)
            if m is not None and m.arbitration_id == 0x002:
                return True
        return False

    try:
        t_end = time.monotonic() + 20.0
        while not round_trip():  # wait for the peer (a frame sent before it listens is lost)
            if time.monotonic() > t_end:
                raise RuntimeError(f"no echo peer on {interface} {channel}")
        for _ in range(20):
            round_trip()
        t0 = time.perf_counter()
        for _ in range(n):
            round_trip()
        return n / (time.perf_counter() - t0)
    finally:
        bus.shutdown()


def _spawn(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, *args], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)


def lockstep_rate(rig: str, interface: str, channel: str, n: int) -> tuple[float, float, int]:
    """(lockstep ticks/s, in-process ticks/s, joints)."""
    from emulators.can.can_plant_link import CONTROLLER_IDS, CanPlantLink
    from emulators.can.codec import DbcExchangeCodec
    from emulators.can.node import PLANT_IDS, PlantNode, node_spec
    from emulators.harness import InProcessLink
    from emulators.plant import Plant

    spec = node_spec(rig)
    period, delay = spec.period_s, spec.delay_s
    plant = Plant.from_config(spec.table, seed=0)
    cmd = plant.idle_command()
    cmd.amp_enable[:] = True
    cmd.amp_command_v[:] = 0.2

    local = InProcessLink(plant, DbcExchangeCodec())
    t0 = time.perf_counter()
    for _ in range(n):
        local.exchange(cmd, period, delay)
    inproc = n / (time.perf_counter() - t0)

    proc = thread = stop = None
    if interface == "udp_multicast":
        proc = _spawn(["-m", "vmehil", "plant-node", "--rig", rig, "--interface", interface, "--channel", channel])
    else:
        node = PlantNode(Endpoint(open_bus(interface, channel), PLANT_IDS),
                         lambda s: Plant.from_config(spec.table, seed=s), spec.n_joints)
        thread, stop = node.start_thread()
    link = CanPlantLink(Endpoint(open_bus(interface, channel), CONTROLLER_IDS), spec.names,
                        connect_timeout_s=30.0)
    try:
        for _ in range(20):
            link.exchange(cmd, period, delay)
        t0 = time.perf_counter()
        for _ in range(n):
            link.exchange(cmd, period, delay)
        rate = n / (time.perf_counter() - t0)
    finally:
        link.close()
        if proc is not None:
            proc.terminate()
            proc.wait(10)
        if thread is not None:
            stop.set()
            thread.join(10)
            node.close()
    return rate, inproc, spec.n_joints


HEADER = (f"{'transport':<14} {'rig':<12} {'joints':>6} {'raw rt/s':>10} {'in-proc/s':>10} {'lockstep/s':>11} "
          f"{'/raw':>6} {'/in-proc':>9}")


def main(argv: list[str] | None = None, *, quick: bool = False) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rigs", default="jpl-arm,melmalec-16")
    p.add_argument("--transports", default="virtual,udp_multicast")
    p.add_argument("--ticks", type=int, default=200 if quick else 1000)
    p.add_argument("--no-header", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--echo", default=None, help=argparse.SUPPRESS)  # internal: run the echo peer
    args = p.parse_args([] if argv is None and quick else argv)
    if args.echo:
        echo(args.echo, GROUP, port=ECHO_PORT)
        return 0
    transports = [t for t in args.transports.split(",") if t]
    if not args.no_header:
        print(HEADER, flush=True)
    netns = None
    if "udp_multicast" in transports and not private_multicast_namespace():
        transports.remove("udp_multicast")
        if os.geteuid() == 0 and shutil.which("unshare") and shutil.which("ip"):
            # run the udp_multicast part in a private loopback-only network namespace
            inner = "ip link set lo up && ip route add 224.0.0.0/4 dev lo && exec \"$0\" \"$@\""
            netns = ["unshare", "-n", "sh", "-c", inner, sys.executable, __file__, "--transports", "udp_multicast",
                     "--rigs", args.rigs, "--ticks", str(args.ticks), "--no-header"]
        else:
            print("udp_multicast: skipped (needs a private network namespace: run as root)")
    _run(transports, args)
    if netns is not None:
        sys.stdout.flush()
        subprocess.run(netns, check=False, cwd=ROOT)
    return 0


def _run(transports: list[str], args: argparse.Namespace) -> None:
    for transport in transports:
        if transport == "udp_multicast":
            peer = _spawn([__file__, "--echo", transport])
            try:
                raw = raw_rate(transport, GROUP, args.ticks, port=ECHO_PORT)
            finally:
                peer.terminate()
                peer.wait(10)
            channel = GROUP
        else:
            stop = threading.Event()
            t = threading.Thread(target=echo, args=(transport, "bench", stop), kwargs={"port": None}, daemon=True)
            t.start()
            try:
                raw = raw_rate(transport, "bench", args.ticks)
            finally:
                stop.set()
                t.join(5)
            channel = "bench-plant"
        print(f"{transport:<14} {'(raw)':<12} {'':>6} {raw:>10.0f}", flush=True)
        for rig in [r for r in args.rigs.split(",") if r]:
            try:
                rate, inproc, nj = lockstep_rate(rig, transport, channel, args.ticks)
            except (FileNotFoundError, ValueError) as e:
                print(f"{transport:<14} {rig:<12} skipped: {e}")
                continue
            print(f"{transport:<14} {rig:<12} {nj:>6} {raw:>10.0f} {inproc:>10.0f} {rate:>11.0f} "
                  f"{rate / raw:>6.3f} {rate / inproc:>9.3f}", flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
