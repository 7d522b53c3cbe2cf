"""Assemble an emulated rig: crate + boards wired to the plant through the harness, the
drivers (:class:`servo.io.JointIO`) and the servo loop. Rig assembly is the application's job
(``vmehil``): this module imports ``emulators``; the loop and the drivers do not.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from emulators.crate import Crate
from emulators.crate_file import build_crate
from emulators.grasp import GraspWorld
from emulators.harness import Harness, InProcessLink, JointNets, PlantLink, PlantLinkError
from emulators.plant import JointParams, Plant, plant_params_from_config
from emulators.presets import resolve_rig
from hal.board_types import board_role
from hal.config import ConfigTable
from servo.boundary import PlantBoundaryError
from servo.io import JointIO
from servo.joint_groups import rig_units
from servo.nominal import nominal_scaling, rig_nominal
from servo.rig import SERVO_JOINT_KEYS, WATCHDOG_NET, RigSpec, load_rig, loopback_net, reference_net
from vmehil.calibration.store import load_store_or_nominal
from vmehil.errors import CliError

#: The ``[[joint]]`` keys that are not the plant's: the servo side's and ``[joint.calibration]``
#: (the calibration procedures' settings, vmehil.calibration.pot). The plant is told them
#: (emulators.plant.params) so that any other key it does not know is reported as a typo.
NON_PLANT_JOINT_KEYS = (*SERVO_JOINT_KEYS, "calibration")


def wired_crate_table(rig: RigSpec) -> ConfigTable:
    """The rig's ``[crate]`` with every joint pin's net (and the calibration and watchdog nets)
    added to its board's wiring table."""
    data = copy.deepcopy(rig.table.data)
    boards = {b["name"]: b for b in data.get("crate", {}).get("board", [])}
    for j in rig.joints:
        for sig, pin in j.wiring.items():
            b = boards.get(pin.board)
            if b is None:
                raise j.table.table("wiring").error(sig, f"a board of [crate] (no board named {pin.board!r})")
            # by the board's role (hal.board_types): the emulator of a role takes its nets so
            role = board_role(b["type"])
            if role == "pio" and pin.channel == "PWM":
                b["pwm_net"] = j.net(sig)
                continue
            if role == "pio":
                b.setdefault("lines", {})[str(pin.channel)] = j.net(sig)
            elif role == "quad":
                chans = b.setdefault("channels", [])
                chans.extend([""] * (pin.index + 1 - len(chans)))
                chans[pin.index] = j.net(sig)
            else:  # adc, dac: a table channel → net
                b.setdefault("wiring", {})[str(pin.channel)] = j.net(sig)
    _wire_calibration_nets(rig, boards)
    if rig.watchdog is not None:
        pin = rig.watchdog.line
        boards[pin.board].setdefault("lines", {})[str(pin.channel)] = WATCHDOG_NET
    for out, inp in rig.readback.items():  # the input sits on the output's net: it reads the wire
        lines = boards[out.board]["lines"]
        lines[str(inp.channel)] = lines[str(out.channel)]
    return ConfigTable(data, rig.table.source)


# --- calibration wiring (rig [rig.references] and [rig.loopback]; see servo.rig) ----------------
def _wire_calibration_nets(rig: RigSpec, boards: dict[str, dict]) -> None:
    """Add the reference and loopback nets to the boards' wiring tables."""
    for pin in rig.references:
        boards[pin.board].setdefault("wiring", {})[str(pin.channel)] = reference_net(pin)
    for dac_pin, adc_pin in rig.loopback.items():
        boards[dac_pin.board].setdefault("wiring", {})[str(dac_pin.channel)] = loopback_net(dac_pin)
        boards[adc_pin.board].setdefault("wiring", {})[str(adc_pin.channel)] = loopback_net(dac_pin)


def publish_references(crate: Crate, rig: RigSpec) -> None:
    """Drive each reference net with its constant (a precision reference source)."""
    for pin, volts in rig.references.items():
        crate.signals.set_analog(reference_net(pin), volts)


def joint_nets(rig: RigSpec) -> list[JointNets]:
    return [JointNets(j.name, **{sig: j.net(sig) for sig in j.wiring}) for j in rig.joints]


@dataclass
class EmulatedRig:
    """Everything of one emulated rig, assembled and wired. It is the runners' plant boundary
    (:class:`servo.boundary.PlantBoundary`): the crate's simulated clock, the harness's publish
    and exchange, and the plant's true state."""

    rig: RigSpec
    crate: Crate
    plant: Plant | None
    link: PlantLink
    harness: Harness
    io: JointIO
    params: list[JointParams]  #: the plant's own parameters: for reports and tests, never the controller
    seed: int

    @property
    def period_ns(self) -> int:
        return round(1e9 / self.rig.servo_rate_hz)

    # --- servo.boundary.PlantBoundary -------------------------------------------------------
    @property
    def joints(self) -> list[str]:
        return [j.name for j in self.rig.joints]

    @property
    def period_s(self) -> float:
        return self.rig.period_s

    @property
    def computation_delay_s(self) -> float:
        return self.rig.computation_delay_s

    @property
    def answer_lag_ticks(self) -> int:
        """Ticks the plant's answers may lag the commands beyond lockstep timing: a free-running
        plant node steps on its own clock and answers 1-2 periods late (0: lockstep, in-process)."""
        lag = getattr(self.link, "answer_lag_ticks", None)  # a link that knows its own (unit bus)
        if lag is not None:
            return int(lag)
        return 2 if getattr(self.link, "free_running", False) else 0

    @property
    def sample_clock(self) -> Callable[[], float | None] | None:
        """:meth:`sample_time_s` where the plant free-runs (the loop's cross-checks then use the
        answers' plant time); ``None`` in lockstep: one period per tick."""
        return self.sample_time_s if getattr(self.link, "free_running", False) else None

    def sample_time_s(self) -> float | None:
        """The plant's time (s) of the values the sensors hold now: the step a free-running plant
        answered with, in periods (``None``: lockstep, one period per tick). The servo loop's
        cross-checks integrate over it (:attr:`servo.loop.ServoLoop.sample_clock`)."""
        step = self.link.answer_step
        return None if step is None else step * self.rig.period_s

    def advance_to(self, t_ns: int) -> None:
        self.crate.advance_to(t_ns)

    def sense(self, tick: int) -> None:
        self.harness.publish()
        if self.grasp is not None:
            self.grasp.publish()

    def exchange(self, tick: int) -> None:
        late_ns = self.crate.clock.now_ns - (tick * self.period_ns + round(self.rig.computation_delay_s * 1e9))
        if late_ns > 0:
            # The tick's bus cycles ran past the instant its command takes effect (tick 0 of a
            # big crate: the start-up reads precede it). The command then takes effect late, once
            # the outputs written have settled -- not never: let the boards' settling run first.
            # A controller that is on time (every unit controller) never gets here, so a late
            # single controller's plant sees what the units' plant sees (docs/melmalec.md).
            self.late_exchanges += 1
            self.crate.advance_to(self.crate.clock.now_ns + self._settle_ns())
        if self.grasp is not None:
            self.grasp.before_period()
        try:
            self.harness.step(self.rig.period_s, self.rig.computation_delay_s)
        except PlantLinkError as e:
            raise PlantBoundaryError(e.cause, str(e)) from e

    def truth(self) -> dict[str, np.ndarray] | None:
        return self.harness.last.truth if self.harness.last is not None else None

    #: exchanges made after their instant (see :meth:`exchange`), for the reports
    late_exchanges: int = 0
    #: the hand's world (objects, their weight, the tactile switches; vmehil.rig_setup.hand_world)
    grasp: GraspWorld | None = None

    def _settle_ns(self) -> int:
        """The longest output settling time of the crate's boards (a DAC's), ns."""
        return max((int(getattr(b, "settling_time_ns", 0)) for b in self.crate.boards.values()), default=0)

    def close(self) -> None:
        self.link.close()


def build_emulated_rig(rig: str | Path | RigSpec | None = None, *, seed: int = 0,
                       link: PlantLink | None = None, initial_deg: list[float] | None = None,
                       calibration: Any = None) -> EmulatedRig:
    """Build crate, boards, plant (in-process unless ``link`` is given), harness and drivers.
    ``calibration``: a calibration store, or the path of a calibration file (loaded and
    identity-checked against the rig and the boards; a missing file gives nominal values and a
    :class:`~vmehil.calibration.store.CalibrationMissingWarning`)."""
    spec = rig if isinstance(rig, RigSpec) else load_rig(resolve_rig(rig))
    crate = build_crate(wired_crate_table(spec), seed=seed)
    publish_references(crate, spec)
    params = plant_params_from_config(spec.table, foreign_keys=NON_PLANT_JOINT_KEYS).joints
    if [p.name for p in params] != [j.name for j in spec.joints]:
        raise CliError(f"rig {spec.name}: plant joints and servo joints differ")
    plant = None
    if link is None:
        plant = Plant.from_config(spec.table, seed=seed, foreign_keys=NON_PLANT_JOINT_KEYS)
        if initial_deg is not None:
            plant.reset(np.radians(np.asarray(initial_deg, float)))
        link = InProcessLink(plant)
    harness = Harness(crate.signals, joint_nets(spec), link,
                      watchdog_net=WATCHDOG_NET if spec.watchdog is not None else None)
    _couple_hbridge_noise(crate, spec)
    if isinstance(calibration, str | Path):
        calibration = load_store_or_nominal(calibration, spec, bus=crate)
    # The drivers scale with the rig file's nominal values, never the plant's (servo.nominal).
    io = JointIO(crate, spec, nominal_scaling(rig_nominal(spec)), calibration=calibration)
    system = EmulatedRig(spec, crate, plant, link, harness, io, params, seed)
    # Power-up: the plant runs one servo period with the rack's power-up outputs (DACs at 0 V,
    # amplifiers disabled) so that the sensor nets hold real readings when the loop starts.
    harness.pending = link.exchange(harness.collect(), spec.period_s, 0.0)
    harness.publish()
    return system


def _couple_hbridge_noise(crate: Crate, spec: RigSpec) -> None:
    """H-bridge switching noise couples into the ADC conversions while a bridge is driving
    (the JPL paper's grounding lesson). The level is set per rig: ``[rig] hbridge_noise_v``.
    It reaches every board of the crate, or, on a rig of units (``[[rig.unit]]``), only the
    boards of the unit that drives the bridge: each unit's electronics are its own, so a unit
    controller with only its own boards sees what the single controller's crate sees
    (docs/melmalec.md)."""
    level = spec.table.table("rig", {}).get_float("hbridge_noise_v", 0.0, min=0.0)
    if level <= 0.0:
        return
    bridges = [j for j in spec.joints if "pwm" in j.wiring]
    if not bridges:
        return
    units = rig_units(spec)
    reach: dict[str, list[str]] = {}  # board → the PWM nets of the bridges whose noise reaches it
    for j in bridges:
        boards = next((u.boards for u in units if j.index in u.indices), tuple(crate.boards))
        for b in boards:
            reach.setdefault(b, []).append(j.net("pwm"))
    analog = crate.signals.analog  # read directly: called at every ADC conversion (20-50 per tick)

    def noise_of(nets: list[str]) -> Callable[[], float]:
        def noise() -> float:
            for n in nets:
                if analog.get(n, 0.0) > 0.0:
                    return level
            return 0.0
        return noise

    for name, nets in reach.items():
        board = crate.boards.get(name)
        switching = getattr(board, "add_switching_noise", None)  # the source as data (a board of lanes rebuilds it)
        if switching is not None:
            switching(nets, level)
            continue
        add = getattr(board, "add_noise_source", None)
        if add is not None:
            add(noise_of(nets))
