"""The long fuzz run: ``python -m tests.fuzz --n 100000 [HARNESS ...]``.

Runs every ``tests/fuzz/test_*.py`` (or the harnesses named: ``console_lines``, ``test_rig_file.py``,
a pytest node id, ...) with ``max_examples = n`` (the hypothesis profile ``fuzz-long``, random,
seeded: ``--seed``, printed), each example bounded in time (``--timeout-s``: a hang is reported with
its harness and input), and prints per harness: examples run, escaped exceptions, property
failures, hangs and typed refusals. Exit status 0 when there were none of the first three, 1
otherwise, 3 when an example hung where even SIGALRM could not stop it. Not part of CI: the suite
runs the same harnesses briefly (the ``fuzz-short`` profile).
"""

from __future__ import annotations

import argparse
import random
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from tests.fuzz import harness

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent


def _targets(names: list[str]) -> list[str]:
    if not names:
        return [str(p.relative_to(ROOT)) for p in sorted(HERE.glob("test_*.py"))]
    out = []
    for name in names:
        if "::" in name or "/" in name:
            out.append(name)
            continue
        stem = name.removesuffix(".py")
        stem = stem if stem.startswith("test_") else f"test_{stem}"
        path = HERE / f"{stem}.py"
        if not path.exists():
            known = ", ".join(p.stem.removeprefix("test_") for p in sorted(HERE.glob("test_*.py")))
            raise SystemExit(f"python -m tests.fuzz: no harness {name!r} (known: {known})")
        out.append(str(path.relative_to(ROOT)))
    return out


def table() -> str:
    rows = [f"{'harness':<72s} {'examples':>9s} {'escaped':>8s} {'failed':>7s} {'hangs':>6s} {'refused':>8s}"]
    for name, c in sorted(harness.COUNTS.items()):
        short = name.removeprefix("tests/fuzz/")
        rows.append(f"{short:<72s} {c.examples:9d} {c.escaped:8d} {c.failed:7d} {c.hangs:6d} "
                    f"{sum(c.refused.values()):8d}")
        if c.refused:
            rows.append("    refused: " + ", ".join(f"{k} {v}" for k, v in sorted(c.refused.items())))
        if c.first_problem:
            rows.append(f"    first problem: {c.first_problem}")
    tot = list(harness.COUNTS.values())
    rows.append(f"{'total':<72s} {sum(c.examples for c in tot):9d} {sum(c.escaped for c in tot):8d} "
                f"{sum(c.failed for c in tot):7d} {sum(c.hangs for c in tot):6d} "
                f"{sum(sum(c.refused.values()) for c in tot):8d}")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.fuzz", description=__doc__.split("\n\n")[0])
    ap.add_argument("harnesses", nargs="*", help="harness names (default: every tests/fuzz/test_*.py)")
    ap.add_argument("--n", type=int, default=1000, help="examples per harness (default 1000)")
    ap.add_argument("--timeout-s", type=float, default=10.0, help="per-example bound, s (default 10)")
    ap.add_argument("--seed", type=int, default=None, help="hypothesis seed (default: a random one, printed)")
    ap.add_argument("--pytest", action="append", default=[], metavar="ARG", help="an extra pytest argument")
    a = ap.parse_args(argv)
    if a.n < 1 or not a.timeout_s > 0:
        ap.error("--n must be at least 1 and --timeout-s above 0")
    seed = a.seed if a.seed is not None else random.randrange(2**32)
    targets = _targets(a.harnesses)
    print(f"fuzz: {len(targets)} harness file(s), n={a.n} examples each, seed {seed}, "
          f"per-example bound {a.timeout_s:g} s", flush=True)
    dog = harness.Watchdog(a.timeout_s, report=lambda: print(table(), flush=True)).start()
    t0 = time.monotonic()
    args: list[Any] = ["-q", "-W", "ignore::pytest.PytestAssertRewriteWarning", f"--fuzz-n={a.n}",
                       f"--fuzz-timeout-s={a.timeout_s}", f"--hypothesis-seed={seed}",
                       "--rootdir", str(ROOT), *a.pytest, *targets]
    try:
        rc = pytest.main(args)
    finally:
        dog.stop()
    print(f"\nfuzz: seed {seed}, {time.monotonic() - t0:.0f} s (wall; the machine may be shared)")
    print(table())
    counts = harness.COUNTS.values()
    bad = sum(c.escaped + c.failed + c.hangs for c in counts)
    if bad or rc not in (pytest.ExitCode.OK, pytest.ExitCode.NO_TESTS_COLLECTED):
        print(f"fuzz: FAILED ({bad} escaped/failed/hung example(s); pytest exit status {int(rc)})")
        return 1
    print("fuzz: 0 escaped exceptions, 0 property failures, 0 hangs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
