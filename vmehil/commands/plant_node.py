"""``vmehil plant-node``: serve a rig's plant as a node on a CAN bus.

    vmehil plant-node [--rig NAME|PATH] [--seed N] [--interface virtual|socketcan|udp_multicast]
                      [--channel NAME] [--free-running] [--can-log PATH] [--duration S]

The controller side is ``vmehil run --plant can`` with the same rig, interface and channel (see
docs/can.md). A controller's RESET rebuilds the plant with the controller's seed, so one node
serves any number of runs. Stop with Ctrl-C (or ``--duration``).
"""

from __future__ import annotations

import argparse
import sys

from vmehil.cli_types import duration_s


def register(sub: argparse._SubParsersAction) -> None:
    from vmehil.can_options import add_bus_arguments
    from vmehil.commands.run import add_rig_args

    p = sub.add_parser("plant-node", help="serve the plant as a node on a CAN bus (vcan, udp_multicast)")
    add_rig_args(p)
    add_bus_arguments(p)
    p.add_argument("--free-running", action="store_true",
                   help="step on the wall clock at the servo rate instead of on the controller's SYNC")
    p.add_argument("--duration", type=duration_s, default=None, help="serve this many seconds (default: until Ctrl-C)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from emulators.can.bus import Endpoint, open_bus, resolve
    from emulators.can.node import PLANT_IDS, PlantNode, exit_on_sigterm, node_spec
    from emulators.plant import Plant
    from vmehil.system import NON_PLANT_JOINT_KEYS

    spec = node_spec(args.rig, foreign_keys=NON_PLANT_JOINT_KEYS)  # fails early on a bad rig file
    bus = open_bus(args.interface, args.channel)
    ep = Endpoint(bus, PLANT_IDS, log_path=args.can_log)
    node = PlantNode(ep, lambda seed: Plant.from_config(spec.table, seed=seed), spec.n_joints, seed=args.seed,
                     free_running=args.free_running, period_s=spec.period_s, delay_s=spec.delay_s)
    mode = "free-running" if args.free_running else "lockstep"
    iface, chan = resolve(args.interface, args.channel)
    exit_on_sigterm()
    print(f"plant node: rig {spec.name} ({spec.n_joints} joints), {mode}, {iface} {chan}, "
          f"boot id {node.boot_id:#06x}", file=sys.stderr, flush=True)
    try:
        node.serve(duration_s=args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        node.close()
        c = node.counters
        print(f"plant node: {c.steps} steps, {c.resets} resets, missing commands {c.missing_cmd}, dropped "
              f"{node.dropped_total()}, sequence jumps {c.seq_jumps}", file=sys.stderr)
    return 0
