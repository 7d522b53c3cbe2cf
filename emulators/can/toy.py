"""A small deterministic stand-in plant with the :class:`emulators.plant.Plant` interface, for
tests and benchmarks of the CAN transport that must not depend on the plant's physics.

Per joint: a current-driven double integrator (``i = enable·gain·v``, ``J·ω̇ = Kt·i``), integrated
at 1 kHz, with seeded sensor noise, a 1000-line encoder (x4) with an index per motor revolution
and an amplifier that faults above 10 V command. Commands and sensors are the plant's own
``PlantCommand`` / ``PlantSensors`` (aliased :data:`ToyCommand`, :data:`ToySensors`).
"""

from __future__ import annotations

import math

import numpy as np

from emulators.plant import PlantCommand, PlantSensors
from emulators.rng import rng_for
from emulators.signals import QuadratureEvents

# The toy speaks the plant's own exchange types (kept under these names for the tests).
ToyCommand = PlantCommand
ToySensors = PlantSensors


class ToyPlant:
    """``n`` independent double integrators (SI units; see the module docstring)."""

    LINES = 1000
    RATIO = 100.0

    def __init__(self, n: int = 3, *, seed: int = 0, rate_hz: float = 1000.0) -> None:
        self.n_joints = n
        self.names = [f"j{i + 1}" for i in range(n)]
        self.rate_hz = rate_hz
        self.seed = seed
        self.gain_a_per_v = 1.0
        self.kt = 0.05
        self.j_m = 2e-5
        self.theta_m = np.zeros(n)
        self.omega_m = np.zeros(n)
        self.i = np.zeros(n)
        self.fault = np.zeros(n, bool)
        self.time_s = 0.0
        self._prev = ToyCommand.idle(n)
        self._noise = [rng_for(seed, "toy", name) for name in self.names]

    def _current(self, cmd: ToyCommand) -> np.ndarray:
        v = np.asarray(cmd.amp_command_v, float)
        return np.where(np.asarray(cmd.amp_enable, bool) & ~self.fault, self.gain_a_per_v * v, 0.0)

    def step_period(self, cmd: ToyCommand, period_s: float, delay_s: float = 0.0) -> ToySensors:
        if period_s < 0:
            raise ValueError(f"period_s must be >= 0, got {period_s}")
        reset = np.asarray(cmd.fault_reset, bool) & ~np.asarray(self._prev.fault_reset, bool)
        self.fault &= ~reset
        self.fault |= np.abs(np.asarray(cmd.amp_command_v, float)) > 10.0
        n_sub = round(period_s * self.rate_hz)
        h = period_s / n_sub if n_sub else 0.0
        n_old = min(n_sub, round(delay_s / h)) if h else 0
        cpr = 4 * self.LINES
        x4 = [np.floor(self.theta_m / (2 * math.pi) * cpr)]
        index_hits: list[list[int]] = [[] for _ in range(self.n_joints)]
        for s in range(n_sub):
            self.i = self._current(self._prev if s < n_old else cmd)
            self.omega_m = self.omega_m + h * self.kt * self.i / self.j_m
            self.theta_m = self.theta_m + h * self.omega_m
            x = np.floor(self.theta_m / (2 * math.pi) * cpr)
            for j in np.nonzero(np.floor_divide(x, cpr) != np.floor_divide(x4[-1], cpr))[0]:
                index_hits[j].append(int(max(x[j], x4[-1][j]) - x4[0][j]))
            x4.append(x)
        self._prev = cmd
        self.time_s += period_s
        counts = (x4[-1] - x4[0]).astype(int)
        theta_j = self.theta_m / self.RATIO
        omega_j = self.omega_m / self.RATIO
        noise = np.array([g.normal(size=3) for g in self._noise]) * 1e-3
        return ToySensors(
            pot_v=np.clip(5.0 * theta_j + noise[:, 0], -10.0, 10.0),
            tach_v=0.5 * omega_j + noise[:, 1],
            imon_v=0.5 * self.i + noise[:, 2],
            amp_fault=self.fault.copy(),
            encoder=[QuadratureEvents(counts=int(counts[j]), illegal=0, index_offsets=tuple(index_hits[j]),
                                      phase=int(x4[-1][j]) % 4) for j in range(self.n_joints)],
            switching=np.asarray(cmd.pwm_duty, float) > 0.0,
            truth={"theta_joint": theta_j, "omega_joint": omega_j, "current_a": self.i.copy(),
                   "friction_torque_nm": np.zeros(self.n_joints), "time_s": np.full(self.n_joints, self.time_s)},
        )


def main(argv: list[str] | None = None) -> int:
    """``python -m emulators.can.toy``: serve a :class:`ToyPlant` as a plant node (tests, benchmarks)."""
    import argparse

    from emulators.can.bus import Endpoint, open_bus
    from emulators.can.node import PLANT_IDS, PlantNode, exit_on_sigterm

    p = argparse.ArgumentParser(prog="python -m emulators.can.toy")
    p.add_argument("--interface", default=None)
    p.add_argument("--channel", default=None)
    p.add_argument("--port", type=int, default=None, help="udp_multicast port")
    p.add_argument("--joints", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--free-running", action="store_true")
    p.add_argument("--duration", type=float, default=None)
    p.add_argument("--can-log", default=None)
    args = p.parse_args(argv)
    kw = {"port": args.port} if args.port else {}
    ep = Endpoint(open_bus(args.interface, args.channel, **kw), PLANT_IDS, log_path=args.can_log)
    node = PlantNode(ep, lambda s: ToyPlant(args.joints, seed=s), args.joints, seed=args.seed,
                     free_running=args.free_running, command_type=ToyCommand)
    exit_on_sigterm()
    print(f"toy plant node ready, boot id {node.boot_id:#06x}", flush=True)
    try:
        node.serve(duration_s=args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        node.close()
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
