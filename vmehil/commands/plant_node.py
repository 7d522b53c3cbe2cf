"""``vmehil plant-node``: serve a rig's plant as a node on a CAN bus.

    vmehil plant-node [--rig NAME|PATH] [--seed N] [--interface virtual|socketcan|udp_multicast]
                      [--channel NAME] [--free-running] [--can-log PATH] [--duration S]
                      [--command-timeout S] [--json PATH]

The controller side is ``vmehil run --plant can`` with the same rig, interface and channel (see
docs/can.md). A controller's RESET rebuilds the plant with the controller's seed, so one node
serves any number of runs. Stop with Ctrl-C, SIGTERM (or ``--duration``).

``--command-timeout`` (default auto: 25 servo periods, or 3 × the longest recent gap between the
controller's commands when longer, at most 1 s; 0 = off): no CONTROL/SYNC from the controller for
that long (wall clock) latches every enabled amplifier off — a killed or hung controller leaves no
powered joints, also in lockstep, where the plant's own enable watchdog cannot run out because
simulated time stops with the controller. ``--json PATH`` writes the node's summary at exit:
counters and the amplifiers' state (on or off, and why).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

from vmehil.commands.errors import CliError
from vmehil.option_groups.cli_types import bounded_float, duration_s
from vmehil.writers.files import write_json


def command_timeout(text: str) -> float | str:
    """``--command-timeout``: ``auto`` or seconds (0: off)."""
    if text.strip().lower() == "auto":
        return "auto"
    return bounded_float(0.0, 3600.0, what="seconds (0 = off) or auto")(text)


def register(sub: argparse._SubParsersAction) -> None:
    from vmehil.commands.run import add_rig_args
    from vmehil.option_groups.can_options import add_bus_arguments

    p = sub.add_parser("plant-node", help="serve the plant as a node on a CAN bus (vcan, udp_multicast)")
    add_rig_args(p)
    add_bus_arguments(p)
    p.add_argument("--free-running", action="store_true",
                   help="step on the wall clock at the servo rate instead of on the controller's SYNC")
    p.add_argument("--duration", metavar="S", type=duration_s, default=None,
                   help="serve this many seconds (default: until Ctrl-C)")
    p.add_argument("--command-timeout", type=command_timeout, default="auto", metavar="S|auto",
                   help="latch every enabled amplifier off when no CONTROL/SYNC came for S seconds of wall-clock "
                        "time (default auto: 25 servo periods, or 3 × the longest recent gap between the "
                        "controller's commands when longer, at most 1 s; 0 = off; docs/can.md)")
    p.add_argument("--json", default=None, metavar="PATH",
                   help="write the node's summary here at exit (counters, amplifier state and why)")
    p.set_defaults(func=run, options=PlantNodeOptions.from_args)


@dataclass(frozen=True)
class PlantNodeOptions:
    """``vmehil plant-node``'s options (``command_timeout`` 0: off)."""

    rig: str | None = None
    seed: int = 0
    interface: str | None = None
    channel: str | None = None
    can_log: str | None = None
    free_running: bool = False
    duration: float | None = None
    command_timeout: float | str = "auto"
    json: str | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> PlantNodeOptions:
        return cls(rig=args.rig, seed=args.seed, interface=args.interface, channel=args.channel,
                   can_log=args.can_log, free_running=args.free_running, duration=args.duration,
                   command_timeout=args.command_timeout, json=args.json)


def run(opts: PlantNodeOptions) -> int:
    from emulators.can.bus import Endpoint, open_bus, resolve
    from emulators.can.node import PLANT_IDS, PlantNode, exit_on_sigterm, node_spec
    from emulators.plant import Plant
    from vmehil.rig_setup.system import NON_PLANT_JOINT_KEYS

    spec = node_spec(opts.rig, foreign_keys=NON_PLANT_JOINT_KEYS)  # fails early on a bad rig file
    if resolve(opts.interface, opts.channel)[0] == "virtual":
        raise CliError("a plant node on python-can's virtual interface (the default) can serve no controller: "
                       "virtual does not cross processes. Give --interface udp_multicast (between processes, "
                       "docs/can.md) or --interface socketcan --channel vcan0; for one process, "
                       "`vmehil run --plant can` alone starts its node itself")
    bus = open_bus(opts.interface, opts.channel)
    ep = Endpoint(bus, PLANT_IDS, log_path=opts.can_log)
    node = PlantNode(ep, lambda seed: Plant.from_config(spec.table, seed=seed), spec.n_joints, seed=opts.seed,
                     free_running=opts.free_running, period_s=spec.period_s, delay_s=spec.delay_s,
                     command_timeout_s=opts.command_timeout or None, names=spec.names)
    mode = "free-running" if opts.free_running else "lockstep"
    iface, chan = resolve(opts.interface, opts.channel)
    exit_on_sigterm()
    timeout = (f"command timeout auto (now {node.effective_command_timeout_s() or 0.0:g} s)"
               if opts.command_timeout == "auto" else
               f"command timeout {opts.command_timeout:g} s" if opts.command_timeout else "no command timeout")
    print(f"plant node: rig {spec.name} ({spec.n_joints} joints), {mode}, {iface} {chan}, {timeout}, "
          f"boot id {node.boot_id:#06x}", file=sys.stderr, flush=True)
    try:
        node.serve(duration_s=opts.duration)
    except KeyboardInterrupt:
        pass
    finally:
        node.close()
        c = node.counters
        print(f"plant node: {c.steps} steps, {c.resets} resets, missing commands {c.missing_cmd}, dropped "
              f"{node.dropped_total()}, sequence jumps {c.seq_jumps}, refused {c.refused} (other controllers); "
              f"{node.amplifiers().describe(spec.names)}",
              file=sys.stderr)
        if opts.json:
            write_json(opts.json, summary(node, spec, mode))
    return 0


def summary(node, spec, mode: str) -> dict:
    """The node's ``--json`` summary: what it served and the amplifiers' state at exit."""
    c = node.counters
    return {
        "rig": spec.name, "mode": mode, "boot_id": node.boot_id, "steps": c.steps, "resets": c.resets,
        "missing_cmd": c.missing_cmd, "dropped": node.dropped_total(), "seq_jumps": c.seq_jumps,
        "step_errors": c.step_errors, "controller_lost": c.controller_lost,
        "command_timeout_s": node.effective_command_timeout_s(),
        "command_timeout_mode": "auto" if node.command_timeout_s == "auto" else
        "fixed" if node.command_timeout_s else "off", "command_timeouts": c.command_timeouts,
        "last_command_silence_s": node.last_silence_s, "watchdog_trips": c.watchdog_trips,
        "refused": c.refused, "refused_resets": c.refused_resets, "session_owner": node.session_owner,
        "amplifiers": node.amplifiers().as_dict(spec.names),
    }
