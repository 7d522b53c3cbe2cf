"""The real-time overrun options shared by every command that paces the loop by the wall clock."""

from __future__ import annotations

import argparse
import math
from typing import Any

from servo.runner import OVERRUN_POLICIES


def _lateness(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of periods") from None
    if not math.isfinite(v) or not 0 < v <= 1000:
        raise argparse.ArgumentTypeError(f"{text} periods: expected a number in (0, 1000]")
    return v


def add_overrun_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--overrun", choices=OVERRUN_POLICIES, default="stop",
                   help="real time: what a loop that falls --max-lateness periods behind does: safe-stop "
                        "(default) or warn and run on")
    p.add_argument("--max-lateness", type=_lateness, default=5.0, metavar="PERIODS",
                   help="real time: how far behind its deadline the loop may fall, in servo periods (default 5)")


def overrun_options(args: argparse.Namespace) -> dict[str, Any]:
    return {"overrun": args.overrun, "max_lateness_periods": args.max_lateness}
