"""Fingerprint of `vmehil run` lockstep runs: the SHA-256 of every recorded array, the crate's
access counters, the summary (wall-clock fields dropped) and the loop's log.

Used to show that a change to the emulated crate's hot path is bit-identical: run it on the
tree before and after the change and compare the two outputs (``diff``)::

    cd /path/to/tree && python -m tests.emulators.lockstep_fingerprint > after.txt

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


def main(labels: list[str]) -> int:
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
