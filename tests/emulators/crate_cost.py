"""Per-tick cost of the lockstep tick split in *thread CPU time* (steadier than wall time on a
shared machine): the controller (``loop.tick``: drivers → crate → boards), the harness (crate
clock, sensor nets, the exchange) and, inside the harness, the plant's ``step_period``; the
emulator side is harness − plant. Medians (and means) over the run, default demo, seed 0::

    python -m tests.emulators.crate_cost [TICKS]

Not a test module (no ``test_`` prefix) and not a benchmark goal: a measuring aid for the
emulated crate's per-cycle cost (docs/benchmarks.md, "The emulated crate's per-cycle cost").
"""

from __future__ import annotations

import statistics
import sys
import time
import types


def main(n: int = 400) -> None:
    import servo.runner as runner_mod
    from servo.runner import LockstepRunner
    from vmehil.rig_setup.session import build_loop
    from vmehil.rig_setup.system import build_emulated_rig

    runner_mod.time = types.SimpleNamespace(perf_counter=time.thread_time)  # type: ignore[assignment]
    for rig in ("jpl-arm", "melmalec-16"):
        system = build_emulated_rig(rig, seed=0)
        loop = build_loop(system, n_ticks=n)
        loop.start()
        runner = LockstepRunner(system, loop)
        plant = system.plant
        step_period = plant.step_period
        spent = [0.0]

        def timed(*args, _step=step_period, _spent=spent, **kw):
            t = time.thread_time()
            out = _step(*args, **kw)
            _spent[0] += time.thread_time() - t
            return out

        plant.step_period = timed  # type: ignore[method-assign]
        for _ in range(20):
            runner.tick()
        ctl, har, pl = [], [], []
        for _ in range(n - 20):
            spent[0] = 0.0
            runner.tick()
            c, h = runner.last_split
            ctl.append(c)
            har.append(h)
            pl.append(spent[0])
        emu = [h - p for h, p in zip(har, pl, strict=True)]

        def ms(x: list[float]) -> str:
            return f"{statistics.median(x) * 1e3:.3f} ({statistics.fmean(x) * 1e3:.3f})"

        print(f"{rig:12s} CPU ms/tick median (mean): controller {ms(ctl)}  harness {ms(har)}  plant {ms(pl)}  "
              f"emulator side {ms(emu)}", flush=True)
        system.close()


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 400)
