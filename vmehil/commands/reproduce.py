"""``vmehil reproduce``: re-run the README's "What it reproduces" table and compare with the paper.

    vmehil reproduce [--rig NAME|PATH] [--seed N] [--json PATH] [--quiet]

Runs each figure's own command (``vmehil run …``, ``vmehil calibrate …``) in a temporary directory,
in the README's order, from a fresh clone's state (no calibration file; nothing in the current
directory is read or written but ``--json``), then prints paper / ours / band / command side by
side. Exit status 0 when every figure lies in the paper's band, 1 when one does not
(:mod:`vmehil.analysis.paper_figures`). Progress: a bar on stderr when it is a terminal, without ``--quiet``.
``--rig`` runs every step on that rig (``make reproduce RIG=jpl-arm-vmic``); the bands stay the paper's.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from vmehil.exit_status import EXIT_CHECK_FAILED, EXIT_OK
from vmehil.option_groups.cli_types import seed
from vmehil.writers.files import write_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reproduce", help="re-run the README's table of the JPL paper's figures and compare",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rig", metavar="NAME|PATH", default=None,
                   help="rig preset name or TOML path every step runs on (default jpl-arm)")
    p.add_argument("--seed", type=seed, default=0, help="seed of every step's emulated rig (default 0, the README's)")
    p.add_argument("--json", default=None, help="write the figures, bands and steps here")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run, options=ReproduceOptions.from_args)


@dataclass(frozen=True)
class ReproduceOptions:
    """``vmehil reproduce``'s options."""

    seed: int = 0
    json: str | None = None
    quiet: bool = False
    #: a preset name or a rig file's path; None: every step's default (jpl-arm)
    rig: str | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> ReproduceOptions:
        return cls(seed=args.seed, json=args.json, quiet=args.quiet, rig=args.rig)


def step_rig(rig: str | None) -> str | None:
    """What each step is given as ``--rig``: a preset's name as typed (the printed commands read as
    a user types them), a file's absolute path (the steps run in a temporary directory). A rig
    that is neither is refused now (``FileNotFoundError`` naming the presets: exit 2), not by
    each of the four steps."""
    if rig is None:
        return None
    from emulators.presets import resolve_rig

    path = resolve_rig(rig)
    return str(path.resolve()) if Path(rig).suffix == ".toml" or Path(rig).exists() else rig


def run(opts: ReproduceOptions) -> int:
    from vmehil.analysis.paper_figures import STEPS, reproduce
    from vmehil.writers.progress import progress_bar, say

    rig = step_rig(opts.rig)
    on = f", rig {opts.rig}" if opts.rig else ""
    say(f"reproducing the README's table (seed {opts.seed}{on}): {len(STEPS)} commands in a temporary directory, "
        "no calibration file (a fresh clone's state)")
    with progress_bar("reproduce", len(STEPS), quiet=opts.quiet, unit="command") as bar:
        result = reproduce(seed=opts.seed, rig=rig, say=say, advance=lambda: bar.update(1))
    say("")
    say(result["table"])
    say("")
    say("every figure in the paper's band" if result["passed"] else "a figure is OUTSIDE the paper's band")
    if opts.json:
        write_json(opts.json, {k: v for k, v in result.items() if k != "table"})
    return EXIT_OK if result["passed"] else EXIT_CHECK_FAILED
