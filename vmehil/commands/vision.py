"""``vmehil vision``: run the emulated vision system as its own process on a BIT3 link.

The robot side creates the shared-memory segment (``emulators.bit3.Bit3Link.create_shared``)
and unlinks it when done; this command attaches to it by name, formats the protocol layout if
the memory is blank, powers the remote crate on, serves visual-servoing tasks until
SIGTERM/SIGINT (or ``--duration`` / ``--exit-after-task``), then writes IDLE, powers off and
detaches. It never unlinks the segment.

Example::

    vmehil vision --shm vmehil-bit3 --rate-hz 30 --latency-ms 30 --target 0.8,0.2,0.5
"""

from __future__ import annotations

import argparse
import logging
import math
from dataclasses import dataclass

from emulators.vision import VisionParams, run_vision_process
from emulators.vision_protocol import VisionTimeouts
from hal.kinematics import ArmModel
from vmehil.option_groups.cli_types import bounded_float, bounded_int, duration_s, positive_float
from vmehil.writers.files import to_json, write_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("vision", help="run the emulated vision system on a shared-memory BIT3 link")
    p.add_argument("--shm", required=True, metavar="NAME",
                   help="name of the shared-memory segment the robot side created")
    p.add_argument("--target", metavar="X,Y,Z",
                   type=_xyz, default=(0.8, 0.2, 0.5), help="target x,y,z in metres (base frame)")
    p.add_argument("--rate-hz", metavar="HZ", type=bounded_float(0.1, 1000.0, what="a frame rate (Hz)"), default=30.0,
                   help="camera frame rate (Hz)")
    p.add_argument("--latency-ms", metavar="MS", type=bounded_float(0.0, 10_000.0, what="a latency (ms)"), default=30.0,
                   help="frame-to-command latency (ms)")
    p.add_argument("--gain", metavar="F", type=bounded_float(0.0, 1.0, what="a fraction", lo_open=True), default=0.5,
                   help="fraction of the error commanded per frame")
    p.add_argument("--max-step-mm", metavar="MM", type=positive_float, default=10.0,
                   help="saturation of one command (mm)")
    p.add_argument("--tolerance-mm", metavar="MM",
                   type=positive_float, default=2.0, help="target reached within this (mm)")
    p.add_argument("--hold-frames", metavar="N", type=bounded_int(0, 10_000, what="a frame count"), default=3,
                   help="frames within tolerance before ending (0: never)")
    p.add_argument("--fov-deg", metavar="DEG",
                   type=bounded_float(0.0, 180.0, what="a half angle (deg)", lo_open=True), default=180.0,
                   help="half angle of the field of view (deg)")
    p.add_argument("--arm", metavar="D1,A2,A3",
                   type=_xyz, default=None, help="arm lengths d1,a2,a3 in metres (default 0.30,0.60,0.55)")
    p.add_argument("--offset", metavar="N",
                   type=lambda s: int(s, 0), default=0, help="protocol base offset in the memory")
    p.add_argument("--peer-timeout-ms", metavar="MS",
                   type=bounded_float(1.0, 3_600_000.0, what="a timeout (ms)"), default=250.0,
                   help="robot silent this long: end the task")
    p.add_argument("--duration", metavar="S", type=duration_s, default=None, help="exit after this many seconds")
    p.add_argument("--exit-after-task", action="store_true", help="exit when the first task has ended")
    p.add_argument("--json", default=None, metavar="PATH",
                   help="also write the summary here (it is always printed as one JSON line on stdout)")
    p.add_argument("-v", "--verbose", action="store_true", help="log to stderr")
    p.set_defaults(func=run, options=VisionCommandOptions.from_args)


@dataclass(frozen=True)
class VisionCommandOptions:
    """``vmehil vision``'s options (the vision system's own process; SI where the flag is not)."""

    shm: str
    target: tuple[float, float, float] = (0.8, 0.2, 0.5)
    rate_hz: float = 30.0
    latency_ms: float = 30.0
    gain: float = 0.5
    max_step_mm: float = 10.0
    tolerance_mm: float = 2.0
    hold_frames: int = 3
    fov_deg: float = 180.0
    arm: tuple[float, float, float] | None = None
    offset: int = 0
    peer_timeout_ms: float = 250.0
    duration: float | None = None
    exit_after_task: bool = False
    json: str | None = None
    verbose: bool = False

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> VisionCommandOptions:
        return cls(shm=args.shm, target=args.target, rate_hz=args.rate_hz, latency_ms=args.latency_ms,
                   gain=args.gain, max_step_mm=args.max_step_mm, tolerance_mm=args.tolerance_mm,
                   hold_frames=args.hold_frames, fov_deg=args.fov_deg, arm=args.arm, offset=args.offset,
                   peer_timeout_ms=args.peer_timeout_ms, duration=args.duration,
                   exit_after_task=args.exit_after_task, json=args.json, verbose=args.verbose)


def _xyz(text: str) -> tuple[float, float, float]:
    parts = [float(x) for x in text.split(",")]
    if len(parts) != 3 or not all(math.isfinite(x) for x in parts):
        raise argparse.ArgumentTypeError(f"expected three numbers x,y,z, got {text!r}")
    return parts[0], parts[1], parts[2]


def run(opts: VisionCommandOptions) -> int:
    if opts.verbose:
        logging.basicConfig(level=logging.INFO, format="%(message)s")
    params = VisionParams(
        rate_hz=opts.rate_hz, latency_s=opts.latency_ms * 1e-3, gain=opts.gain,
        max_step_m=opts.max_step_mm * 1e-3, tolerance_m=opts.tolerance_mm * 1e-3,
        hold_frames=opts.hold_frames, fov_half_angle_rad=math.radians(opts.fov_deg),
    )
    arm = ArmModel() if opts.arm is None else ArmModel(*opts.arm)
    summary = run_vision_process(
        opts.shm, opts.target, params=params, arm=arm,
        timeouts=VisionTimeouts(peer_timeout_s=opts.peer_timeout_ms * 1e-3), offset=opts.offset,
        duration_s=opts.duration, exit_after_task=opts.exit_after_task,
    )
    print(to_json(summary, indent=None), end="")  # one line of standard JSON (NaN → null), as --json writes
    if opts.json:
        write_json(opts.json, summary)
    return 0
