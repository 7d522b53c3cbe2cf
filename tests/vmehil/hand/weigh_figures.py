"""The weigh figures of docs/hand.md: ``python -m tests.vmehil.hand.weigh_figures``.

For each pose, mass and seed: open (rest 1 s), close on the object (at rest 1 s), grasp, weigh,
through the console's commands on the emulated jpl-arm; prints the estimate, its stated
uncertainty and its error against the object's mass."""

from __future__ import annotations

import itertools

import numpy as np

from tests.vmehil.hand import test_hand as th

POSES = {"ahead": [0.0, 0.3, -0.6, 0.3, 0.0, 0.0, 0.6], "left-high": [0.5, 0.6, -1.0, 0.2, 0.0, 0.0, 0.6]}
MASSES_KG = (0.25, 0.5, 1.0, 2.0)
SEEDS = (1, 2, 3)


def main() -> None:
    print("pose       mass_kg seed  estimate_kg  uncertainty_kg  error_kg  |error|/uncertainty")
    ratios, errors = [], []
    for (pose_name, pose), mass, seed in itertools.product(POSES.items(), MASSES_KG, SEEDS):
        th.POSE_RAD, th.MASS_KG = pose, mass
        r = th.Rig(seed=seed)
        try:
            r.runner.run(25)
            r.until(r.cmd("open"), 1200)
            r.until(r.cmd("close"), 1200)
            r.cmd("grasp", object="sample")
            ok = r.cmd("weigh").ok
            kv = dict(p.split("=") for p in ok.split())
            est, sigma = float(kv["mass_kg"]), float(kv["uncertainty_kg"])
        finally:
            r.close()
        ratios.append(abs(est - mass) / sigma)
        errors.append(est - mass)
        print(f"{pose_name:10s} {mass:7.2f} {seed:4d} {est:12.4f} {sigma:15.4f} {est - mass:+9.4f} {ratios[-1]:10.2f}")
    e = np.asarray(errors)
    print(f"rms error {np.sqrt(np.mean(e ** 2)):.4f} kg, max |error| {np.max(np.abs(e)):.4f} kg, "
          f"max |error|/uncertainty {max(ratios):.2f}, "
          f"within 1 uncertainty: {sum(x <= 1 for x in ratios)}/{len(ratios)}")


if __name__ == "__main__":
    main()
