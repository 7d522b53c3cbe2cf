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
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from servo.rig import RigSpec, crate_boards
from vmehil.errors import CliError
from vmehil.option_groups.cli_types import bounded_float, duration_s, positive_float


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


@dataclass(frozen=True)
class VisionOptions:
    """``--vision`` and its settings (``mode`` None: no visual servoing)."""

    mode: str | None = None
    target: str | None = None
    rate_hz: float = 30.0
    latency_ms: float = 30.0
    tolerance_mm: float = 5.0
    timeout_s: float = 20.0

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> VisionOptions:
        return cls(mode=args.vision, target=args.vision_target, rate_hz=args.vision_rate_hz,
                   latency_ms=args.vision_latency_ms, tolerance_mm=args.vision_tolerance_mm,
                   timeout_s=args.vision_timeout)


class RunNeeds(Protocol):
    """What of ``vmehil run``'s options (:class:`vmehil.commands.run_options.RunOptions`) the vision reads."""

    @property
    def vision(self) -> VisionOptions: ...
    @property
    def realtime(self) -> bool: ...
    @property
    def motion(self) -> str | None: ...


@dataclass(frozen=True)
class VisionPreparation:
    """What :func:`prepare` made before the rig was built: the run's default motion and duration,
    the shared memory of ``process`` (closed and unlinked by :meth:`close`, at the run's end) and
    the ready move's joint deltas (where the ``vservo`` move will start)."""

    defaults: dict[str, Any] = field(default_factory=dict)
    shm: Any = None
    ready_delta: Any = 0.0

    def close(self) -> None:
        if self.shm is not None:
            self.shm.close(unlink=True)


def prepare(run: RunNeeds, rig: RigSpec) -> VisionPreparation | None:
    """Before the rig is built: pick the default motion and, for ``process``, the shared memory."""
    opts = run.vision
    if not opts.mode:
        return None
    board = _bit3_board(rig)
    shm = None
    if opts.mode == "process":
        if not run.realtime:
            raise CliError("--vision process runs the vision system on the wall clock: add --realtime")
        from emulators.bit3 import Bit3Link

        shm = Bit3Link.create_shared(int(board.get("window_size", board.get("mem_size", 0x10000))))
        board["shm"] = shm.shm_name
        board["poll_period_us"] = 100.0
    prepared = VisionPreparation(shm=shm)  # closes the shared memory if what follows fails
    if run.motion is None:
        from servo.motion import Motion, QuinticMove, WaitMove
        from servo.vservo import VservoMove

        try:
            # Out of the stretched-out (singular) start pose first (joints 1–3 only, relative to
            # where they start), then the vision task, then a hold.
            ready = np.radians(np.array([10.0, 30.0, -60.0] + [0.0] * (rig.n_joints - 3)))
            from servo.settings import servo_settings

            # the planning limits the servo will plan the move with (a quintic's peak speed is 1.875·Δ/t)
            vmax = np.asarray(servo_settings(rig).max_velocity_rad_s, float)
        except BaseException:
            prepared.close()
            raise
        t_ready = 1.875 * float(np.max(np.abs(ready) / vmax))
        prepared = VisionPreparation(
            {"motion": Motion((QuinticMove(None, ready, 1.0), VservoMove(opts.timeout_s), WaitMove(3.0)),
                              "vservo", "<--vision>"),
             "duration": t_ready + opts.timeout_s + 3.0}, shm, ready)
    return prepared


def _bit3_board(rig: RigSpec) -> dict[str, Any]:
    boards = [b.data for b in crate_boards(rig, "bit3")]
    if not boards:
        raise CliError(f"rig {rig.name} has no BIT3 card (a [[crate.board]] with type = \"bit3\")")
    return boards[0]


def _link_driver(crate: Any, board: dict[str, Any]) -> tuple[Any, Any]:
    """The vision link's driver for the rig's card, and what to call once the link is up (the
    reference card: reset the link; the SBS 617: its reset sequence, then map the window)."""
    if board["type"] == "sbs617":
        from hal.bit3 import Sbs617Driver

        drv617 = Sbs617Driver(crate, int(board["base"]), int(board["map_base"]), int(board["window_base"]),
                              remote_base=int(board["remote_base"]), remote_space=board.get("remote_space", "A24"),
                              mem_size=int(board.get("mem_size", 0x1000)), bar_space=board.get("space", "A32"),
                              irq_level=int(board.get("irq_level", 3)), irq_vector=int(board.get("irq_vector", 0xB3)))
        return drv617, drv617.setup
    from hal.bit3 import Bit3Driver

    drv = Bit3Driver(crate, int(board["base"]), int(board["window_base"]),
                     csr_space=board.get("space", "A16"), window_space=board.get("window_space", "A24"),
                     window_size=int(board.get("window_size", 0x10000)))
    return drv, drv.reset_link


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


def attach(run: RunNeeds, system, loop, runner, prepared: VisionPreparation | None = None) -> _Attachment | None:
    opts = run.vision
    if not opts.mode:
        return None
    prepared = prepared or VisionPreparation()
    from emulators.vision import VisionParams, VisionSystem
    from emulators.vision_protocol import VisionServer
    from hal.bit3.protocol import Timeouts, VisionServoClient, format_layout
    from hal.kinematics import ArmModel
    from servo.vservo import VisionLink

    rig = system.rig
    board = _bit3_board(rig)
    card = system.crate.board(board["name"])
    drv, link_up = _link_driver(system.crate, board)
    # the arm the servo plans with (ServoSettings.arm, parsed once); a rig that states no [arm]
    # gets the model's default lengths, as visual servoing always did
    ctx = loop.plan_context or loop.sequencer.ctx
    bounds = ctx.bounds if ctx is not None else None
    arm = bounds.arm if bounds is not None and bounds.arm is not None else ArmModel.from_table({})
    theta0 = system.io.read().theta + prepared.ready_delta  # where vservo will start
    target = _target(opts.target, arm, theta0)
    params = VisionParams(rate_hz=opts.rate_hz, latency_s=opts.latency_ms * 1e-3,
                          tolerance_m=opts.tolerance_mm * 1e-3)
    vision = None
    proc = None
    if opts.mode == "inprocess":
        from emulators.bit3 import Bit3RemotePort

        remote = Bit3RemotePort(card.link)
        remote.power_on()
        if board["type"] != "bit3":
            link_up()  # the reference card's window works from reset; the 617's must be mapped
        format_layout(drv.memory())
        server = VisionServer(remote.memory, ring=remote.ring)
        remote.on_doorbell(server.notify)
        vision = VisionSystem(server, target.tolist(), arm, params)
        timeouts = Timeouts()
    else:
        shm = prepared.shm
        proc = subprocess.Popen(vision_process_argv(shm.shm_name, target, opts),
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        t0 = time.monotonic()
        while not drv.status().link_up:  # the vision process formats the memory and powers on
            if proc.poll() is not None:
                raise RuntimeError(f"vision process exited: {proc.stderr.read() if proc.stderr else ''}")
            if time.monotonic() - t0 > 15:
                raise RuntimeError("vision process did not bring the BIT3 link up within 15 s")
            time.sleep(0.01)
        link_up()
        timeouts = Timeouts(peer_timeout_s=1.0, accept_timeout_s=3.0, ending_timeout_s=0.5)
    client = VisionServoClient(drv.memory(), timeouts, ring=drv.ring_doorbell)
    drv.on_doorbell(client.notify)
    link = VisionLink(client, arm, system.crate.now, lambda: loop.last.get("theta"), rig.n_joints, vision)
    loop.sequencer.ctx.extras["vision"] = link
    loop.vision = link
    print(f"vision: {opts.mode}, target {np.round(target, 4).tolist()} m")
    # the shared memory itself is unlinked by `vmehil run` at exit
    return _Attachment(proc, card if opts.mode == "process" else None)


def vision_process_argv(shm_name: str, target: np.ndarray, opts: VisionOptions) -> list[str]:
    """The command line of ``--vision process``'s vision system: ``vmehil vision`` (its own
    process, attached to the robot side's shared memory by name)."""
    return [sys.executable, "-m", "vmehil", "vision", "--shm", shm_name, "--target",
            ",".join(f"{x:.6f}" for x in target), "--rate-hz", str(opts.rate_hz),
            "--latency-ms", str(opts.latency_ms), "--peer-timeout-ms", "1000",
            "--tolerance-mm", str(opts.tolerance_mm)]


def _target(text: str | None, arm, theta0: np.ndarray) -> np.ndarray:
    if text:
        try:
            xyz = np.array([float(v) for v in text.split(",")])
        except ValueError:
            raise CliError(f"--vision-target {text!r}: expected x,y,z in metres") from None
        if xyz.shape != (3,) or not np.all(np.isfinite(xyz)):
            raise CliError(f"--vision-target {text!r}: expected three finite numbers x,y,z")
        return xyz
    return np.asarray(arm.position(theta0[:6]), float) + np.array([0.04, 0.03, -0.03])
