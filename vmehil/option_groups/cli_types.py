"""argparse types for every number the ``vmehil`` commands take: finite and bounded.

One place for them, so that no command accepts ``--duration inf`` (an OverflowError later),
``1e12`` (an allocation of petabytes), ``nan`` (a loop that never ends) or ``--points 100000``
(a procedure that runs for days). Each bound is stated in the flag's error message.
"""

from __future__ import annotations

import argparse
import ipaddress
import math
from collections.abc import Callable

#: the longest run a command accepts: a day of simulated or wall time
MAX_DURATION_S = 86_400.0


def bounded_float(lo: float, hi: float, *, what: str = "a number", lo_open: bool = False) -> Callable[[str], float]:
    """A finite float in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``)."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not math.isfinite(v) or v > hi or v < lo or (lo_open and v == lo):
            bracket = "(" if lo_open else "["
            raise argparse.ArgumentTypeError(f"{text}: expected {what} in {bracket}{lo:g}, {hi:g}]")
        return v

    return parse


def bounded_int(lo: int, hi: int, *, what: str = "a whole number") -> Callable[[str], int]:
    """An integer in ``[lo, hi]``."""

    def parse(text: str) -> int:
        try:
            v = int(text, 0)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{v}: expected {what} in [{lo}, {hi}]")
        return v

    return parse


def nonzero_float(text: str) -> float:
    """A finite, non-zero float (a signed step or move), at most 1e6 in magnitude."""
    v = bounded_float(-1e6, 1e6)(text)
    if v == 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a non-zero finite number")
    return v


positive_float = bounded_float(0.0, 1e9, what="a positive number", lo_open=True)
duration_s = bounded_float(0.0, MAX_DURATION_S, what="a duration in seconds", lo_open=True)
seed = bounded_int(0, 2**32 - 1, what="a seed")
joint_number = bounded_int(1, 64, what="a joint number (joints are numbered from 1)")


def is_loopback(host: str) -> bool:
    """Whether ``host`` is this machine only: ``localhost`` or a loopback address (127.0.0.0/8,
    ::1). Any other name is not (it could resolve anywhere). The one check behind every
    ``--…-allow-remote`` refusal (``--live``, ``--mavlink``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
