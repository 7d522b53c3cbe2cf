"""The black box's and the live view's options, shared by ``vmehil run`` and ``vmehil console``
(docs/scope.md, "Black box" and "Live view")::

    --blackbox DIR|off            where the black box goes when the run stops (default: the report
                                  directory, else ./vmehil-blackbox/<rig>-<UTC time>; $VMEHIL_BLACKBOX)
    --live [HOST:PORT]            serve the loop's channels over the Foxglove WebSocket protocol
                                  (default 127.0.0.1:8765; port 0: a free one, printed)
    --live-allow-remote           allow a HOST that is not loopback
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

from vmehil.errors import CliError
from vmehil.option_groups.cli_types import is_loopback

#: ``--live`` with no address
DEFAULT_LIVE = "127.0.0.1:8765"


def add_scope_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("black box and live view (docs/scope.md)")
    g.add_argument("--blackbox", metavar="DIR|off", default=None,
                   help="where the black box (the last seconds before the stop: MCAP or .npz, and a PNG) goes "
                        "(default: the report directory, else ./vmehil-blackbox/<rig>-<UTC time>; "
                        "$VMEHIL_BLACKBOX); off: not written")
    g.add_argument("--live", metavar="HOST:PORT", nargs="?", const=DEFAULT_LIVE, default=None,
                   help=f"serve the loop's channels live over the Foxglove WebSocket protocol (default {DEFAULT_LIVE};"
                        " port 0: a free port, printed); needs the 'trace' extra")
    g.add_argument("--live-allow-remote", action="store_true",
                   help="allow a non-loopback HOST in --live (exposes the loop's signals to the network)")


@dataclass(frozen=True)
class ScopeOptions:
    """``--blackbox`` (``None``: the default place), ``--live`` (``None``: no live view)."""

    blackbox: str | None = None
    live: str | None = None
    live_allow_remote: bool = False

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> ScopeOptions:
        return cls(blackbox=getattr(args, "blackbox", None), live=getattr(args, "live", None),
                   live_allow_remote=getattr(args, "live_allow_remote", False))

    def live_address(self) -> tuple[str, int] | None:
        """``--live``'s host and port, checked (:class:`CliError`, exit 2: not HOST:PORT, or a host
        beyond loopback without ``--live-allow-remote``); ``None`` without ``--live``."""
        if self.live is None:
            return None
        return parse_live(self.live, allow_remote=self.live_allow_remote)


def parse_live(text: str, *, allow_remote: bool = False) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:PORT`` for IPv6) → (host, port)."""
    host, sep, port_s = text.rpartition(":")
    host = host.strip("[]")
    if not sep or not host:
        raise CliError(f"--live {text!r}: expected HOST:PORT, e.g. {DEFAULT_LIVE}")
    try:
        port = int(port_s)
    except ValueError:
        raise CliError(f"--live {text!r}: port {port_s!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise CliError(f"--live {text!r}: port {port} is out of range (0-65535; 0: a free one)")
    if not allow_remote and not is_loopback(host):
        raise CliError(f"--live {text!r}: {host} is not a loopback address; the live view serves 127.0.0.1 "
                       "(or ::1, localhost) only unless --live-allow-remote is given")
    return host, port


