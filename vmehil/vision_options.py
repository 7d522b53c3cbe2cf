"""``vmehil run --vision inprocess|process``: visual servoing over the BIT3 link.

* ``inprocess``: the vision emulator runs in this process on the far side of the emulated BIT3
  card, stepped each tick on the crate's clock (lockstep or real time; deterministic).
* ``process``: the robot side creates a ``multiprocessing.shared_memory`` segment as the
  card's dual-port memory and starts ``vmehil vision --shm NAME`` as its own process, which
  runs on the wall clock — so this mode needs ``--realtime``.

Without ``--motion`` the run is a ``vservo`` task (timeout ``--vision-timeout``) then a 3 s hold.
The target (``--vision-target x,y,z`` in metres, base frame) defaults to about 6 cm from where
the end effector is when the ``vservo`` move starts.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from typing import Any

import numpy as np

from servo.rig import RigSpec
from vmehil.cli_types import bounded_float, duration_s, positive_float


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("visual servoing (BIT3 vision link)")
    g.add_argument("--vision", choices=("inprocess", "process"), default=None,
                   help="run the vision system in this process or as its own process (needs --realtime)")
    g.add_argument("--vision-target", default=None, metavar="X,Y,Z", help="target x,y,z in metres (base frame)")
    g.add_argument("--vision-rate-hz", metavar="HZ",
                   type=bounded_float(0.1, 1000.0, what="a frame rate (Hz)"), default=30.0,
                   help="camera frame rate (default 30)")
    g.add_argument("--vision-latency-ms", metavar="MS",
                   type=bounded_float(0.0, 10_000.0, what="a latency (ms)"), default=30.0,
                   help="image-processing latency (default 30)")
    g.add_argument("--vision-tolerance-mm", metavar="MM", type=positive_float, default=5.0,
                   help="the vision system ends the task within this distance (default 5 mm: the 12-bit "
                        "pots resolve about 1.7 mm at full reach)")
    g.add_argument("--vision-timeout", metavar="S",
                   type=duration_s, default=20.0, help="end the vservo task after this long (s)")


def prepare(args: argparse.Namespace, rig: RigSpec) -> dict[str, Any] | None:
    """Before the rig is built: pick the default motion and, for ``process``, the shared memory."""
    if not getattr(args, "vision", None):
        return None
    board = _bit3_board(rig)
    if args.vision == "process":
        if not args.realtime:
            raise ValueError("--vision process runs the vision system on the wall clock: add --realtime")
        from emulators.bit3 import Bit3Link

        link = Bit3Link.create_shared(int(board.get("window_size", 0x10000)))
        board["shm"] = link.shm_name
        board["poll_period_us"] = 100.0
        args._vision_shm = link  # closed and unlinked by the attachment
    out: dict[str, Any] = {}
    if args.motion is None:
        from servo.motion import Motion, QuinticMove, WaitMove
        from servo.vservo import VservoMove

        # Out of the stretched-out (singular) start pose first (joints 1–3 only, relative to where
        # they start), then the vision task, then a hold.
        ready = np.radians(np.array([10.0, 30.0, -60.0] + [0.0] * (rig.n_joints - 3)))
        from servo.settings import servo_settings

        # the planning limits the servo will plan the move with (a quintic's peak speed is 1.875·Δ/t)
        vmax = np.asarray(servo_settings(rig).max_velocity_rad_s, float)
        t_ready = 1.875 * float(np.max(np.abs(ready) / vmax))
        out["motion"] = Motion((QuinticMove(None, ready, 1.0), VservoMove(args.vision_timeout), WaitMove(3.0)),
                               "vservo", "<--vision>")
        out["duration"] = t_ready + args.vision_timeout + 3.0
        args._vision_ready_delta = ready
    return out


def _bit3_board(rig: RigSpec) -> dict[str, Any]:
    boards = [b for b in rig.table.data.get("crate", {}).get("board", []) if b.get("type") == "bit3"]
    if not boards:
        raise ValueError(f"rig {rig.name} has no BIT3 card (a [[crate.board]] with type = \"bit3\")")
    return boards[0]


class _Attachment:
    def __init__(self, proc: subprocess.Popen | None, card: Any) -> None:
        self.proc, self.card = proc, card

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.card is not None:  # our attachment to the shared segment (the creator unlinks it)
            try:
                self.card.link.close(unlink=False)
            except BufferError:
                pass


def attach(args: argparse.Namespace, system, loop, runner) -> _Attachment | None:
    if not getattr(args, "vision", None):
        return None
    from emulators.vision import VisionParams, VisionSystem
    from emulators.vision_protocol import VisionServer
    from hal.bit3 import Bit3Driver
    from hal.bit3.protocol import Timeouts, VisionServoClient, format_layout
    from hal.kinematics import ArmModel
    from servo.vservo import VisionLink

    rig = system.rig
    board = _bit3_board(rig)
    card = system.crate.board(board["name"])
    drv = Bit3Driver(system.crate, int(board["base"]), int(board["window_base"]),
                     csr_space=board.get("space", "A16"), window_space=board.get("window_space", "A24"),
                     window_size=int(board.get("window_size", 0x10000)))
    arm = ArmModel.from_table(rig.table.data.get("arm", {}))
    theta0 = system.io.read().theta + getattr(args, "_vision_ready_delta", 0.0)  # where vservo will start
    target = _target(args.vision_target, arm, theta0)
    params = VisionParams(rate_hz=args.vision_rate_hz, latency_s=args.vision_latency_ms * 1e-3,
                          tolerance_m=args.vision_tolerance_mm * 1e-3)
    vision = None
    proc = None
    if args.vision == "inprocess":
        from emulators.bit3 import Bit3RemotePort

        remote = Bit3RemotePort(card.link)
        remote.power_on()
        format_layout(drv.memory())
        server = VisionServer(remote.memory, ring=remote.ring)
        remote.on_doorbell(server.notify)
        vision = VisionSystem(server, target.tolist(), arm, params)
        timeouts = Timeouts()
    else:
        shm = args._vision_shm
        proc = subprocess.Popen(
            [sys.executable, "-m", "servo", "vision", "--shm", shm.shm_name, "--target",
             ",".join(f"{x:.6f}" for x in target), "--rate-hz", str(args.vision_rate_hz),
             "--latency-ms", str(args.vision_latency_ms), "--peer-timeout-ms", "1000",
             "--tolerance-mm", str(args.vision_tolerance_mm)],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        t0 = time.monotonic()
        while not drv.status().link_up:  # the vision process formats the memory and powers on
            if proc.poll() is not None:
                raise RuntimeError(f"vision process exited: {proc.stderr.read() if proc.stderr else ''}")
            if time.monotonic() - t0 > 15:
                raise RuntimeError("vision process did not bring the BIT3 link up within 15 s")
            time.sleep(0.01)
        drv.reset_link()
        timeouts = Timeouts(peer_timeout_s=1.0, accept_timeout_s=3.0, ending_timeout_s=0.5)
    client = VisionServoClient(drv.memory(), timeouts, ring=drv.ring_doorbell)
    drv.on_doorbell(client.notify)
    link = VisionLink(client, arm, system.crate.now, lambda: loop.last.get("theta"), rig.n_joints, vision)
    loop.sequencer.ctx.extras["vision"] = link
    loop.vision = link
    print(f"vision: {args.vision}, target {np.round(target, 4).tolist()} m")
    # the shared memory itself is unlinked by `vmehil run` at exit
    return _Attachment(proc, card if args.vision == "process" else None)


def _target(text: str | None, arm, theta0: np.ndarray) -> np.ndarray:
    if text:
        try:
            xyz = np.array([float(v) for v in text.split(",")])
        except ValueError:
            raise ValueError(f"--vision-target {text!r}: expected x,y,z in metres") from None
        if xyz.shape != (3,) or not np.all(np.isfinite(xyz)):
            raise ValueError(f"--vision-target {text!r}: expected three finite numbers x,y,z")
        return xyz
    return np.asarray(arm.position(theta0[:6]), float) + np.array([0.04, 0.03, -0.03])
