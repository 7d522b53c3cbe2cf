"""``vmehil run --mavlink URL``: the MAVLink endpoint as a RUN_EXTENSIONS module.

Options::

    --mavlink URL                 e.g. udpin:127.0.0.1:14550 (listen) or udpout:127.0.0.1:14550
    --mavlink-rate HZ             telemetry samples per second of loop time (default 10; 0 = off)
    --mavlink-telemetry KIND      array (DEBUG_FLOAT_ARRAY, default) or named (NAMED_VALUE_FLOAT)
    --mavlink-key-file PATH       MAVLink 2 signing key (64 hex digits, file mode 600)
    --mavlink-allow-unsigned-read with a key, still answer unsigned parameter reads
    --mavlink-allow-remote        allow a non-loopback address in URL
    --mavlink-sysid N             our system id (default 1; component id 1)
    --mavlink-min-margin M        stability margin 1-rho a new gain set must keep (default 0)
    --mavlink-wait S              before the first tick, wait up to S s (wall clock) for a client
                                  to arm (MAV_CMD_COMPONENT_ARM_DISARM); parameters set meanwhile
                                  apply from tick 0. Not armed in time: the run is not started.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any, Protocol

from servo.control.linear import delay_periods
from vmehil.mavlink.endpoint import MavlinkEndpoint, MavlinkError
from vmehil.mavlink.signing import load_key_file
from vmehil.option_groups.cli_types import bounded_float


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("MAVLink live tuning and telemetry (docs/mavlink.md)")
    g.add_argument("--mavlink", metavar="URL", default=None,
                   help="serve MAVLink on URL, e.g. udpin:127.0.0.1:14550 (loopback only by default)")
    g.add_argument("--mavlink-rate", metavar="HZ", type=float, default=10.0,
                   help="telemetry rate in Hz of loop time (default 10, 0 = off)")
    g.add_argument("--mavlink-telemetry", choices=("array", "named"), default="array",
                   help="DEBUG_FLOAT_ARRAY per joint (array, default) or NAMED_VALUE_FLOAT per value (named)")
    g.add_argument("--mavlink-key-file", metavar="PATH", default=None,
                   help="MAVLink 2 signing key file (64 hex digits, mode 600); unsigned PARAM_SET is then refused")
    g.add_argument("--mavlink-allow-unsigned-read", action="store_true",
                   help="with a key, still answer unsigned PARAM_REQUEST_LIST/READ")
    g.add_argument("--mavlink-allow-remote", action="store_true",
                   help="allow a non-loopback address in --mavlink (exposes live gain changes to the network)")
    g.add_argument("--mavlink-sysid", metavar="N", type=int, default=1, help="MAVLink system id (default 1)")
    g.add_argument("--mavlink-min-margin", metavar="M", default=0.0,
                   type=bounded_float(0.0, 1.0, what="a stability margin 1 − ρ in [0, 1]"),
                   help="refuse gains leaving less than this stability margin 1-rho (default 0)")
    g.add_argument("--mavlink-wait", metavar="S", type=float, default=0.0,
                   help="wait up to S s for a client to arm before the first tick (default 0: start at once)")


@dataclass(frozen=True)
class MavlinkOptions:
    """``--mavlink URL`` and its settings (``url`` None: no MAVLink endpoint)."""

    url: str | None = None
    rate_hz: float = 10.0
    telemetry: str = "array"
    key_file: str | None = None
    allow_unsigned_read: bool = False
    allow_remote: bool = False
    sysid: int = 1
    min_margin: float = 0.0
    wait_s: float = 0.0

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> MavlinkOptions:
        return cls(url=args.mavlink, rate_hz=args.mavlink_rate, telemetry=args.mavlink_telemetry,
                   key_file=args.mavlink_key_file, allow_unsigned_read=args.mavlink_allow_unsigned_read,
                   allow_remote=args.mavlink_allow_remote, sysid=args.mavlink_sysid,
                   min_margin=args.mavlink_min_margin, wait_s=args.mavlink_wait)


class RunNeeds(Protocol):
    """What of ``vmehil run``'s options (:class:`vmehil.commands.run_options.RunOptions`) MAVLink reads."""

    @property
    def mavlink(self) -> MavlinkOptions: ...


def attach(run: RunNeeds, system: Any, loop: Any, runner: Any, prepared: None = None) -> MavlinkEndpoint | None:
    """Open the endpoint and hook it to ``runner.after_tick``; None when --mavlink is not given."""
    opts = run.mavlink
    if not opts.url:
        return None
    key = load_key_file(opts.key_file) if opts.key_file else None
    delay = delay_periods(getattr(runner, "delay_s", 0.0) or 0.0, loop.period_s)
    endpoint = MavlinkEndpoint(
        loop, opts.url, sysid=opts.sysid, rate_hz=opts.rate_hz, key=key,
        allow_unsigned_read=opts.allow_unsigned_read, allow_remote=opts.allow_remote,
        delay_periods=delay, min_margin=opts.min_margin,
        telemetry=opts.telemetry)
    if opts.wait_s > 0:
        if not endpoint.wait_for_start(opts.wait_s):
            endpoint.close()
            raise MavlinkError(f"--mavlink-wait: no client armed within {opts.wait_s:g} s; "
                               "arm from the ground station (MAVProxy: 'arm throttle') or drop --mavlink-wait")
    runner.after_tick.append(endpoint.after_tick)
    return endpoint
