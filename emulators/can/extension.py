"""CAN options for the command line: ``vmehil run --plant can …`` (a ``RUN_EXTENSIONS`` module of
:mod:`servo.commands.run`) and the shared option set of ``vmehil plant-node``.

    --plant inprocess|can        where the plant runs (default inprocess)
    --interface NAME             python-can interface: virtual | socketcan | udp_multicast
                                 (default: CAN_INTERFACE / python-can config / virtual)
    --channel NAME               python-can channel (default: CAN_CHANNEL / config / per interface)
    --plant-mode lockstep|free-running   must match the node (default lockstep)
    --can-log PATH               record the bus (.log = candump format; .asc/.blf/.csv also work)
    --can-timeout S              lockstep answer timeout and heartbeat timeout (default 1.0 s)
    --stale-ticks N              exchanges without fresh data before the safe stop
"""

from __future__ import annotations

import argparse
from typing import Any


def add_bus_arguments(p: argparse.ArgumentParser) -> None:
    """``--interface``, ``--channel``, ``--can-log`` (python-can conventions)."""
    p.add_argument("--interface", default=None,
                   help="python-can interface: virtual, socketcan or udp_multicast (default: CAN_INTERFACE, "
                        "python-can's config file, else virtual)")
    p.add_argument("--channel", default=None,
                   help="python-can channel (default: CAN_CHANNEL, config file, else vmehil / vcan0 / 239.74.163.2)")
    p.add_argument("--can-log", default=None, metavar="PATH",
                   help="record the bus from this side (.log = candump format, decodable with cantools decode)")


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("plant node over CAN")
    g.add_argument("--plant", choices=("inprocess", "can"), default="inprocess",
                   help="run the plant in this process (default) or talk to `vmehil plant-node` over CAN")
    add_bus_arguments(g)  # type: ignore[arg-type]
    g.add_argument("--plant-mode", choices=("lockstep", "free-running"), default="lockstep",
                   help="lockstep (tick per exchange; equals the in-process run) or free-running (latch newest)")
    g.add_argument("--can-timeout", type=float, default=1.0, help="answer / heartbeat timeout in seconds (1.0)")
    g.add_argument("--stale-ticks", type=int, default=None,
                   help="exchanges without fresh plant data before a safe stop (lockstep 1, free-running 5)")


def make_link(args: argparse.Namespace, rig: Any):
    """The :class:`~emulators.can.link.CanPlantLink` for ``--plant can``, else ``None``."""
    if getattr(args, "plant", "inprocess") != "can":
        return None
    from emulators.can.bus import Endpoint, open_bus
    from emulators.can.link import CONTROLLER_IDS, CanPlantLink

    bus = open_bus(args.interface, args.channel)
    ep = Endpoint(bus, CONTROLLER_IDS, log_path=args.can_log)
    from emulators.harness import PlantLinkError

    try:
        link = CanPlantLink(ep, [j.name for j in rig.joints], seed=args.seed,
                            free_running=args.plant_mode == "free-running", answer_timeout_s=args.can_timeout,
                            heartbeat_timeout_s=args.can_timeout, stale_ticks=args.stale_ticks)
        link.connect()
        return link
    except PlantLinkError as e:  # no node / wrong rig or mode: a user error, not a crash
        ep.close()
        raise ValueError(str(e)) from e
    except Exception:
        ep.close()
        raise


def attach(args: argparse.Namespace, system: Any, loop: Any, runner: Any) -> None:
    """Nothing to attach: the link is closed with the system."""
    return None
