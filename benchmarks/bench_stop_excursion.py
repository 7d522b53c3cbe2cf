"""How far the joints move after a stop and during the re-enable after it (issue #29), as goals.

For jpl-arm and melmalec-16 (seed 0, lockstep, the rig's default demo) the loop is stopped with
power removed at once (category 0: the worst stop for the brakes) in mid-move (2 s: the joints
moving at up to 20°/s) and — without ``--quick`` — holding (8 s); the plant steps on for 2 s,
then the loop resumes holding where the joints are (the console's ``enable``) for 1 s. The
figures are the largest true-angle movements (:func:`benchmarks.stop_excursion.measure`):

* after the stop, of every joint with a holding brake — goal ≤ 1° (the issue's "no joint moves
  more than 1°"; melmalec-16's arm has no brakes and falls whatever the stop);
* during the re-enable, of every joint — goal ≤ 0.1° (the issue's "no joint moves more than
  0.1° during a re-enable").

Absolute goals (degrees of simulated motion: no baseline, and the machine's load changes none of
them). Run: ``python -m benchmarks bench_stop_excursion``; the same measurement with the figures
of every joint and without the brakes: ``python -m benchmarks.stop_excursion``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchmarks.goals import Goal, record
from benchmarks.stop_excursion import measure
from emulators.presets import resolve_rig
from servo.rig import load_rig

STOP_GOAL_DEG = 1.0
RESUME_GOAL_DEG = 0.1
RIGS = ("jpl-arm", "melmalec-16")


def main(quick: bool = False) -> list[str]:
    lines = [f"{'rig':<12} {'stop at':>8} {'after the stop (braked)':>24} {'re-enable (any joint)':>22}"]
    print(lines[0], flush=True)
    for rig in RIGS:
        path = Path(resolve_rig(rig))
        joints = load_rig(path).joints
        braked = np.array(["holding_brake" in j.wiring for j in joints])
        for stop_s, what in ((2.0, "mid-move"), *(() if quick else ((8.0, "holding"),))):
            got = measure(path, stop_s, after_s=2.0)
            stop_deg, resume_deg = got["stop"], got["resume"]
            i, k = int(np.argmax(np.where(braked, stop_deg, -1.0))), int(np.argmax(resume_deg))
            line = (f"{rig:<12} {stop_s:>6.0f} s {stop_deg[i]:>15.3f}° ({joints[i].name})"
                    f" {resume_deg[k]:>13.3f}° ({joints[k].name})")
            print(line, flush=True)
            lines.append(line)
            record(Goal(f"{rig}: braked joints' movement after a category-0 stop {what} ({joints[i].name})",
                        float(stop_deg[i]), STOP_GOAL_DEG, "deg", "at_most"))
            record(Goal(f"{rig}: largest movement during the re-enable after it ({joints[k].name})",
                        float(resume_deg[k]), RESUME_GOAL_DEG, "deg", "at_most"))
    return lines


if __name__ == "__main__":
    main()
