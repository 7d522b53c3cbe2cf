"""How far each joint moves after a safe stop, with and without the holding brakes (issue #29).

``python -m benchmarks.stop_excursion [--rig jpl-arm] [--stop-s 2.0] [--after-s 2.0]``

Runs the rig's default demo in lockstep (seed 0), safe-stops the loop at ``--stop-s`` the way
every stop does today (amplifiers off at once, DACs 0 V, brake lines low), keeps stepping the
plant for ``--after-s`` of simulated time and prints, per joint, the largest movement of the
true joint angle from its value at the stop (degrees). "without" is the same rig file with every
holding brake taken out of the plant (the drivers still drive the lines: nothing holds). Then a
re-enable: the loop resumes (holding the measured position) and the largest movement over the
next second is printed.
"""

from __future__ import annotations

import argparse
import re
import tempfile
from pathlib import Path

import numpy as np

from emulators.presets import resolve_rig
from servo.rig import load_rig
from servo.runner import LockstepRunner
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig


def _without_brakes(text: str) -> str:
    """The rig file with every plant holding brake removed (the wiring stays)."""
    keys = "present|holding_torque_nm|engage_delay_s|release_delay_s"
    text = re.sub(rf"^\[joint\.holding_brake\].*\n(?:(?:{keys}) =.*\n)*", "", text, flags=re.M)
    return re.sub(r"^holding_brake = \{[^\n]*\n", "", text, flags=re.M)


def measure(rig_path: Path, stop_s: float, after_s: float, resume_s: float = 1.0) -> dict[str, np.ndarray]:
    system = build_emulated_rig(rig_path, seed=0)
    try:
        n_stop = round(stop_s / system.period_s)
        loop = build_loop(system, n_ticks=n_stop + round((after_s + resume_s) / system.period_s) + 10)
        runner = LockstepRunner(system, loop)
        loop.start()
        for _ in range(n_stop):
            runner.tick()
        if loop.fault is not None:
            raise RuntimeError(f"the demo stopped by itself: {loop.fault}")
        truth = system.truth()
        assert truth is not None
        at_stop = truth["theta_joint"].copy()
        loop.safe_stop("test_stop", "benchmarks.stop_excursion")
        worst = np.zeros_like(at_stop)
        for _ in range(round(after_s / system.period_s)):
            runner.tick()
            th = system.truth()["theta_joint"]  # type: ignore[index]
            worst = np.maximum(worst, np.abs(th - at_stop))
        before = system.truth()["theta_joint"].copy()  # type: ignore[index]
        loop.resume()
        worst_resume = np.zeros_like(before)
        for _ in range(round(resume_s / system.period_s)):
            runner.tick()
            th = system.truth()["theta_joint"]  # type: ignore[index]
            worst_resume = np.maximum(worst_resume, np.abs(th - before))
        return {"stop": np.degrees(worst), "resume": np.degrees(worst_resume),
                "fault": np.array([str(loop.fault)])}
    finally:
        system.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.stop_excursion", description=__doc__)
    ap.add_argument("--rig", action="append", help="rig name or path (default: jpl-arm and melmalec-16)")
    ap.add_argument("--stop-s", type=float, default=2.0, help="when the stop comes (s of the demo)")
    ap.add_argument("--after-s", type=float, default=2.0, help="simulated seconds watched after the stop")
    args = ap.parse_args(argv)
    for rig in args.rig or ["jpl-arm", "melmalec-16"]:
        path = Path(resolve_rig(rig))
        with tempfile.TemporaryDirectory() as tmp:
            bare = Path(tmp) / path.name
            bare.write_text(_without_brakes(path.read_text()))
            got = {"with brakes": measure(path, args.stop_s, args.after_s),
                   "without brakes": measure(bare, args.stop_s, args.after_s)}
        names = load_rig(path).joints
        print(f"{rig}: largest |true angle - angle at the stop| over {args.after_s:g} s after a safe stop at "
              f"{args.stop_s:g} s (deg); then over 1 s after a resume")
        print(f"  {'joint':<12}{'with':>10}{'without':>10}{'resume(with)':>14}{'resume(without)':>17}")
        for i, j in enumerate(names):
            w, wo = got["with brakes"], got["without brakes"]
            print(f"  {j.name:<12}{w['stop'][i]:>10.3f}{wo['stop'][i]:>10.3f}{w['resume'][i]:>14.3f}"
                  f"{wo['resume'][i]:>17.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
