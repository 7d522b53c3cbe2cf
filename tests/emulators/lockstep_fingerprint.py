"""Fingerprint of `vmehil run` lockstep runs: the SHA-256 of every recorded array, the crate's
access counters, the summary (wall-clock fields dropped) and the loop's log.

Used to show that a change to the emulated crate's hot path is bit-identical: run it on the
tree before and after the change and compare the two outputs (``diff``)::

    cd /path/to/tree && python -m tests.emulators.lockstep_fingerprint > after.txt

``--batch`` (instead of the cases above) fingerprints batched lockstep (vmehil.analysis.batch):
each instance of :data:`BATCH_CASES` — different gains, plant values, seeds and faults, one
tripping its watchdog — run in one batch and again alone (the scalar run), and prints every
instance's digests with ``batch == scalar: yes`` (exit 1 on any ``no``). ``--lanes`` runs the same
instances as rigs of lanes (vmehil.analysis.lane_batch; one rig of lanes per rig file, the instances
with injected faults left out: they have no lane form) and prints each lane's digests with
``lanes == scalar: yes`` — or, for a lane left at a watchdog trip, where and why, beside its scalar
run's fault. The output of the default cases does not change with either.

It drives the real CLI (``vmehil.cli.main(["run", ...])``) and captures the loop it built when
the run is summarized, so what it fingerprints is exactly what ``vmehil run`` computed. Not a
test module (no ``test_`` prefix): a test that pinned these hashes would break on every
legitimate numeric change elsewhere (the plant kernel); compare two trees instead.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import sys
from typing import Any

import numpy as np

# (label, argv after "run"): the default demo on both presets and two seeds, and fault scenarios
# that exercise the boards' fault paths (ADC noise burst, DAC dead channel, PIO stuck line,
# decoder glitch and missed counts, a pulled board: BERR and the bus timeout).
CASES: list[tuple[str, list[str]]] = [
    ("jpl-arm seed 0", ["--rig", "jpl-arm", "--seed", "0"]),
    ("jpl-arm seed 3", ["--rig", "jpl-arm", "--seed", "3"]),
    ("melmalec-16 seed 0", ["--rig", "melmalec-16", "--seed", "0"]),
    ("melmalec-16 seed 5", ["--rig", "melmalec-16", "--seed", "5", "--no-integrator-switch-off"]),
    ("jpl-arm faults", ["--rig", "jpl-arm", "--seed", "1", "--duration", "4",
                        "--fault", "adc_noise@0.5:joint=j2,rms_v=0.05",
                        "--fault", "encoder_glitch@1.0:joint=j3,counts=50,intervals=20",
                        "--fault", "encoder_missed@1.5:joint=j4,counts=300",
                        "--fault", "dac_dead@3.0:joint=j1"]),
    ("melmalec-16 faults", ["--rig", "melmalec-16", "--seed", "2", "--duration", "3",
                            "--fault", "adc_noise@0.2:board=adc0,rms_v=0.02",
                            "--fault", "enable_stuck_low@1.0:joint=leg2_knee",
                            "--fault", "encoder_glitch@2.0:joint=leg1_lift"]),
    ("jpl-arm board removed", ["--rig", "jpl-arm", "--seed", "0", "--duration", "2",
                               "--fault", "board_removed@1.0:board=quad0"]),
]

_WALL = ("compute", "timing", "wall", "elapsed")


def _digest(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    return hashlib.sha256(a.dtype.str.encode() + str(a.shape).encode() + a.tobytes()).hexdigest()[:20]


def _scrub(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _scrub(v) for k, v in x.items() if not any(w in str(k) for w in _WALL)}
    if isinstance(x, list | tuple):
        return [_scrub(v) for v in x]
    if isinstance(x, float) and x != x:
        return "nan"
    return x


def fingerprint(argv: list[str]) -> dict[str, Any]:
    import os

    import vmehil.reports.run_report as run_report

    # the black box is kept on every tick all the same; its files (and their path, with the UTC
    # time, in final_stop) are not the behaviour compared here
    os.environ.setdefault("VMEHIL_BLACKBOX", "off")
    from vmehil.cli import main

    captured: dict[str, Any] = {}
    original = run_report.summarize

    def summarize(loop, **kw):
        summary = original(loop, **kw)
        captured["loop"] = loop
        captured["summary"] = summary
        return summary

    run_report.summarize = summarize
    try:
        err = io.StringIO()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            status = main(["run", "--quiet", *argv])
        if "loop" not in captured:
            raise RuntimeError(f"vmehil run {' '.join(argv)} did not run: {err.getvalue()}")
    finally:
        run_report.summarize = original
    loop = captured["loop"]
    rec = loop.recorder.trimmed()
    out: dict[str, Any] = {"exit": status}
    out["arrays"] = {k: _digest(v) for k, v in sorted(rec.items()) if k != "compute_s"}
    out["ticks"] = int(loop.tick_count)
    out["fault"] = None if loop.fault is None else loop.fault.as_dict()
    out["final_stop"] = _scrub(loop.final_stop)
    out["log"] = hashlib.sha256(repr([(t, s, m) for t, s, m in loop.log]).encode()).hexdigest()[:20]
    bus = getattr(loop.io, "bus", None)
    if bus is not None and hasattr(bus, "counter_snapshot"):
        out["counters"] = bus.counter_snapshot()
        out["clock_ns"] = bus.clock.now_ns
    out["summary"] = hashlib.sha256(json.dumps(_scrub(captured["summary"]), sort_keys=True,
                                               default=str).encode()).hexdigest()[:20]
    return out


# (label, rig, gains, tolerance plant values, seed, faults) of the batch's instances (joint 1, a
# 10° move and a 1 s hold): gains differ; the third's tach brush drop trips the velocity
# cross-check (docs/sweeps.md); the fourth has its own sensor faults, the sixth a pulled board
# (BERR: a driver-error stop); the fifth another seed and +15 % Coulomb friction (0.0388 N·m
# nominal); the seventh runs the arm on a VMIVME-4116 as its DAC, the eighth is another rig, the
# ninth the arm on the VMIC boards (3113A, 4116, 2536, SBS 617).
BATCH_CASES: list[tuple[str, str, dict[str, float], dict[str, float], int, tuple[str, ...]]] = [
    ("kp 80", "jpl-arm", {"kp": 80.0}, {}, 0, ()),
    ("kp 120 kvi 700", "jpl-arm", {"kp": 120.0, "kvi": 700.0}, {}, 0, ()),
    ("brush drop 0.2 V (trips)", "jpl-arm", {}, {"tach_brush_drop": 0.2}, 0, ()),
    ("faults", "jpl-arm", {"kv": 40.0}, {}, 0,
     ("adc_noise@0.3:joint=j1,rms_v=0.02", "encoder_missed@0.6:joint=j1,counts=30")),
    ("seed 3, coulomb +15 %", "jpl-arm", {}, {"coulomb": 0.04462}, 3, ()),
    ("board pulled", "jpl-arm", {}, {}, 1, ("board_removed@0.5:board=quad0",)),
    ("VMIVME-4116 DAC", "jpl-arm/vmivme-4116", {"kp": 90.0}, {}, 5, ()),
    ("melmalec-16", "melmalec-16", {}, {}, 2, ()),
    ("VMIC boards (jpl-arm-vmic)", "jpl-arm-vmic", {"kp": 95.0}, {}, 4, ()),
]
#: the jpl-arm preset's reference DAC, and the crate entry that makes it a VMIVME-4116 (as
#: tests/vmehil/test_vmivme4116_rig.py does)
_REFERENCE_DAC = 'type = "dac"\nname = "dac0"'
_VMIVME_4116 = 'type = "vmivme-4116"\nupdate = "synchronized"\ncoding = "offset_binary"\nname = "dac0"'


def _instance_digest(run: Any) -> dict[str, Any]:
    loop = run.loop
    rec = loop.recorder.trimmed()
    out: dict[str, Any] = {"arrays": {k: _digest(v) for k, v in sorted(rec.items()) if k != "compute_s"}}
    out["ticks"] = int(loop.tick_count)
    out["fault"] = None if loop.fault is None else loop.fault.as_dict()
    out["log"] = hashlib.sha256(repr([(t, s, m) for t, s, m in loop.log]).encode()).hexdigest()[:20]
    out["counters"] = run.system.crate.counter_snapshot()
    out["clock_ns"] = run.system.crate.clock.now_ns
    return out


def _maker() -> Any:
    """``make(rig, gains, plant, seed, faults)``: the SimRun of one of :data:`BATCH_CASES`."""
    from vmehil.analysis.rigparams import load_joint
    from vmehil.analysis.simulate import SimRun, SimSettings
    from vmehil.analysis.sweep import rig_text, task_rig

    texts = {name: rig_text(name) for name in ("jpl-arm", "melmalec-16", "jpl-arm-vmic")}
    texts["jpl-arm/vmivme-4116"] = texts["jpl-arm"].replace(_REFERENCE_DAC, _VMIVME_4116)
    if _VMIVME_4116 not in texts["jpl-arm/vmivme-4116"]:
        raise RuntimeError("the jpl-arm preset's dac0 entry changed: update _REFERENCE_DAC")

    def make(rig: str, gains: dict[str, float], plant: dict[str, float], seed: int, faults: tuple[str, ...]) -> Any:
        path = rig.split("/")[0]
        jp = load_joint(task_rig(texts[rig], path, 1, plant), 1, gains=gains)
        return SimRun(jp, False, SimSettings(seed=seed, move_deg=10, hold_s=1.0, allow_short=True), faults=faults)

    return make


def _alone(make: Any, case: tuple) -> dict[str, Any]:
    """The digests of one case run on its own (the scalar run)."""
    alone = make(*case[1:])
    try:
        with alone.loop.armed():
            alone.runner.run(alone.n_ticks, stop=alone.halt_when(None))
        return _instance_digest(alone)
    finally:
        alone.close()


def batch_fingerprints() -> list[tuple[str, dict[str, Any], dict[str, Any]]]:
    """Per instance of :data:`BATCH_CASES`: (label, digests in the batch, digests alone)."""
    from vmehil.analysis.batch import run_lockstep

    make = _maker()
    batch = [make(*case[1:]) for case in BATCH_CASES]
    try:
        run_lockstep(batch, window=1)  # every tick interleaved: the strictest order
        together = [_instance_digest(r) for r in batch]
    finally:
        for r in batch:
            r.close()
    return [(case[0], got, _alone(make, case)) for case, got in zip(BATCH_CASES, together, strict=True)]


def lane_fingerprints() -> list[tuple[str, dict[str, Any], dict[str, Any]]]:
    """Per instance of :data:`BATCH_CASES` without faults, run in a rig of lanes with the others of
    its rig file: (label, its lane's digests — or where and why it was left —, digests alone)."""
    from hal.lanes import LaneSet
    from vmehil.analysis.lane_batch import stack_runs

    make = _maker()
    groups: dict[str, list[tuple]] = {}
    for case in BATCH_CASES:
        if not case[5]:
            groups.setdefault(case[1], []).append(case)
    out = []
    for cases in groups.values():
        runs = [make(*case[1:]) for case in cases]
        lanes = LaneSet(len(runs))
        try:
            rig, loop, runner = stack_runs(runs, lanes)
        except NotImplementedError as e:
            for case in cases:
                out.append((case[0], {"no lane form": str(e)}, _alone(make, case)))
            continue
        runner.after_tick.append(lambda lp, lanes=lanes: setattr(lanes, "tick", lp.tick_count))
        with loop.armed():
            runner.run(runs[0].n_ticks, stop=lambda lanes=lanes: lanes.n_alive == 0)
        for b, (case, r) in enumerate(zip(cases, runs, strict=True)):
            alone = _alone(make, case)
            if not lanes.alive[b]:
                got: dict[str, Any] = {"left at tick": lanes.first_tick[b], "why": lanes.reasons[b]}
                fault = alone["fault"]
                # left at its scalar run's fault (that tick, that cause), or left where its program
                # went another way than the others': either way its result is its run alone
                same = fault is None or (fault["tick"] == lanes.first_tick[b]
                                         and lanes.reasons[b].startswith(fault["cause"]))
                out.append((case[0], got, got if same else alone))
                continue
            loop.write_lane(b, r.loop)
            r.system.crate = rig.crate  # the lanes' crate: its counters and clock are every live lane's
            out.append((case[0], _instance_digest(r), alone))
    return out

def main_batch(lanes: bool = False) -> int:
    same_all = True
    what = "lanes" if lanes else "batch"
    for label, got, alone in (lane_fingerprints() if lanes else batch_fingerprints()):
        same = got == alone
        same_all &= same
        print(f"== {what} instance {label}: {what} == scalar: {'yes' if same else 'no'}")
        for k, v in got.items():
            if k == "arrays":
                for name, h in v.items():
                    print(f"  array {name:12s} {h}")
            else:
                print(f"  {k}: {json.dumps(v, sort_keys=True, default=str)}")
        sys.stdout.flush()
    return 0 if same_all else 1


def main(labels: list[str]) -> int:
    if labels == ["--batch"]:
        return main_batch()
    if labels == ["--lanes"]:
        return main_batch(lanes=True)
    for label, argv in CASES:
        if labels and label not in labels:
            continue
        fp = fingerprint(argv)
        print(f"== {label}: {' '.join(argv)}")
        for k, v in fp.items():
            if k == "arrays":
                for name, h in v.items():
                    print(f"  array {name:12s} {h}")
            else:
                print(f"  {k}: {json.dumps(v, sort_keys=True, default=str)}")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
