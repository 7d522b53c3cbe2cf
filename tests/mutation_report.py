"""Per-module counts of a mutation run (``make mutation``; docs/mutation.md), read from the state
mutmut 3 keeps under ``mutants/`` (one ``<file>.meta`` JSON per mutated source file).

    python -m tests.mutation_report [MUTANTS_DIR] [--survivors | --unkilled]

Prints, per mutated file, the mutants and how many were killed, survived, had no test calling
them, timed out or are not checked yet, then the total and the score killed / (killed +
survived). ``--survivors`` lists the surviving mutants' names (``mutmut show NAME`` prints the
diff of one). ``--unkilled`` prints only the names of every mutant not killed (survived, no
tests, timeout, not checked), one a line, for checking them again after new tests: mutmut keeps
a verdict until the mutated function changes, so new tests kill nothing until the mutants are
named (``python -m tests.mutation_report --unkilled | xargs -d '\\n' mutmut run --max-children 2``).
Not a test module (no ``test_`` prefix).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

# mutmut 3's meaning of a mutant's recorded exit code (mutmut/stats.py, 3.8.1)
_STATUS = {1: "killed", 3: "killed", 0: "survived", 5: "no tests", 33: "no tests", 34: "skipped", 36: "timeout",
           24: "timeout", -24: "timeout", 152: "timeout", 255: "timeout", 37: "type check", None: "not checked"}
COLUMNS = ("killed", "survived", "no tests", "timeout", "not checked", "other")


def status(exit_code: int | None) -> str:
    s = _STATUS.get(exit_code, "other")
    return s if s in COLUMNS else "other"


def read(mutants: Path) -> dict[str, dict[str, int | None]]:
    """``{source file: {mutant name: exit code}}`` for every file that has mutants."""
    out: dict[str, dict[str, int | None]] = {}
    for meta in sorted(mutants.rglob("*.py.meta")):
        codes = json.loads(meta.read_text()).get("exit_code_by_key", {})
        if codes:
            out[str(meta.relative_to(mutants))[: -len(".meta")]] = codes
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mutants", nargs="?", default="mutants", type=Path)
    ap.add_argument("--survivors", action="store_true", help="list the surviving mutants")
    ap.add_argument("--unkilled", action="store_true", help="only the names of the mutants not killed, one a line")
    args = ap.parse_args(argv)
    data = read(args.mutants)
    if not data:
        print(f"no mutation results under {args.mutants}/ (run `make mutation` first)", file=sys.stderr)
        return 1
    if args.unkilled:
        for codes in data.values():
            for name, code in sorted(codes.items()):
                if status(code) != "killed":
                    print(name)
        return 0
    width = max(len(f) for f in data)
    print(f"{'file':<{width}}  {'mutants':>7}  " + "  ".join(f"{c:>11}" for c in COLUMNS) + "  score")
    total: Counter[str] = Counter()
    for path, codes in data.items():
        n = Counter(status(c) for c in codes.values())
        total += n
        print(_row(path, width, len(codes), n))
    print(_row("total", width, sum(len(c) for c in data.values()), total))
    if args.survivors:
        for codes in data.values():
            for name, code in sorted(codes.items()):
                if status(code) == "survived":
                    print(name)
    return 0


def _row(label: str, width: int, mutants: int, n: Counter[str]) -> str:
    decided = n["killed"] + n["survived"]
    score = f"{100 * n['killed'] / decided:5.1f} %" if decided else "    —"
    return f"{label:<{width}}  {mutants:>7}  " + "  ".join(f"{n[c]:>11}" for c in COLUMNS) + f"  {score}"


if __name__ == "__main__":
    sys.exit(main())
