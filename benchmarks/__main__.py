"""Run every ``benchmarks/bench_*.py`` and print its figures: ``python -m benchmarks [--quick] [--check] [NAME...]``."""

from __future__ import annotations

import argparse
import importlib
import inspect
import pkgutil
import sys
from pathlib import Path

from benchmarks.goals import recorded


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
    ap.add_argument("names", nargs="*", help="benchmark module names (default: all bench_*)")
    ap.add_argument("--quick", action="store_true", help="shorter runs (rougher figures)")
    ap.add_argument("--seconds", type=float, default=None, help="real-time runs: seconds per rig (bench_servo)")
    ap.add_argument("--check", action="store_true",
                    help="exit 1 when a goal is missed (for people on an idle machine, not for CI)")
    args = ap.parse_args(argv)
    here = Path(__file__).parent
    names = args.names or sorted(m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_"))
    for name in names:
        mod = importlib.import_module(f"benchmarks.{name}")
        print(f"== {name} ==", flush=True)
        extra = {"seconds": args.seconds} if "seconds" in inspect.signature(mod.main).parameters else {}
        mod.main(quick=args.quick, **extra)
    goals = recorded()
    if goals:
        print("== goals (each against its baseline from this run) ==")
        for goal in goals:
            print(goal.line())
        missed = [g for g in goals if not g.met]
        print(f"{len(goals) - len(missed)} of {len(goals)} goals met")
        if args.check and missed:
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
