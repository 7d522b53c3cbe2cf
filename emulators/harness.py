"""The harness: one explicit exchange per servo period between the electronics and the plant.

The boards see only nets (:class:`emulators.signals.Signals`). Once per servo period the
harness reads the command nets (amplifier command volts, enables, PWM, direction, brake,
holding-brake lines, fault reset, and the rig's amplifier enable-watchdog line) into a :class:`PlantCommand`, hands
it to a :class:`PlantLink` — a function call in-process, frames on CAN for the plant node — and
publishes the returned :class:`PlantSensors` (pot, tach and current-monitor volts at the next
sampling instant, the encoder's quadrature events during the period, fault lines) on the sensor
nets at the start of the next tick. Both links pass values through the same
:class:`ExchangeCodec`, so the two modes give the same results by construction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from emulators.plant import Plant, PlantCommand, PlantSensors
from emulators.plant_link import (
    ExchangeCodec,
    PlantLink,
    PlantLinkError,
    PlantLostError,
    PlantRestartedError,
    StaleDataError,
)
from emulators.signals import QuadratureEvents, Signals

# The link's types stay importable from here: the harness's users name them with it.
__all__ = ["ExchangeCodec", "Harness", "InProcessLink", "JointNets", "PlantLink", "PlantLinkError", "PlantLostError",
           "PlantRestartedError", "StaleDataError", "default_codec"]


def default_codec() -> ExchangeCodec:
    """The CAN message set's quantization (the DBC is read once per process)."""
    from emulators.can.codec import DbcExchangeCodec

    return DbcExchangeCodec()  # type: ignore[return-value]


class InProcessLink(PlantLink):
    """The embedded default: the plant is a Python object in this process."""

    def __init__(self, plant: Plant, codec: ExchangeCodec | None = None) -> None:
        self.plant = plant
        self.codec = codec or default_codec()
        self.names = list(plant.names)

    def exchange(self, cmd: PlantCommand, period_s: float, delay_s: float) -> PlantSensors:
        return self.codec.sensors(self.plant.step_period(self.codec.command(cmd), period_s, delay_s))


@dataclass(frozen=True)
class JointNets:
    """Which nets of a joint are wired (``None`` = not wired)."""

    name: str
    amp_command: str | None = None
    amp_enable: str | None = None
    amp_reset: str | None = None
    amp_fault: str | None = None
    pwm: str | None = None
    direction: str | None = None
    brake: str | None = None
    holding_brake: str | None = None
    pot: str | None = None
    tach: str | None = None
    imon: str | None = None
    encoder: str | None = None
    tactile_left: str | None = None  # the fingers' tactile switches: driven by emulators.grasp, not the plant
    tactile_right: str | None = None


class Harness:
    """Couples a crate's :class:`Signals` to a :class:`PlantLink`, once per servo period.

    ``watchdog_net``: the net of the amplifiers' enable-watchdog line (``None``: not wired; the
    command then carries the line low, which a plant without a watchdog ignores).
    """

    def __init__(self, signals: Signals, joints: Sequence[JointNets], link: PlantLink,
                 watchdog_net: str | None = None) -> None:
        self.signals = signals
        self.joints = list(joints)
        self.link = link
        self.watchdog_net = watchdog_net
        self.n = len(self.joints)
        self.pending: PlantSensors | None = None
        self.last: PlantSensors | None = None
        self.exchanges = 0

    def _wiring(self) -> tuple[tuple, tuple]:
        """The joints' nets as flat tuples, built once (``joints`` is fixed after construction)."""
        w = self.__dict__.get("_wired")
        if w is None:
            cmd = tuple((j.amp_command, j.amp_enable, j.amp_reset, j.pwm, j.direction, j.brake, j.holding_brake)
                        for j in self.joints)
            sens = tuple((i, j.pot, j.tach, j.imon, j.amp_fault, j.encoder) for i, j in enumerate(self.joints)
                         if j.pot or j.tach or j.imon or j.amp_fault or j.encoder)
            w = self.__dict__["_wired"] = (cmd, sens)
        return w  # type: ignore[no-any-return]

    def collect(self) -> PlantCommand:
        """Read the command nets into a :class:`PlantCommand`."""
        s = self.signals
        analog, digital = s.analog, s.digital
        cmd_v, enable, reset, duty, direction, brake, holding = [], [], [], [], [], [], []
        for command, en, rst, pwm, dirn, brk, hold in self._wiring()[0]:
            cmd_v.append(analog.get(command, 0.0) if command else 0.0)
            # An unwired enable is tied high on the amplifier (always enabled).
            enable.append(digital.get(en, False) if en else True)
            reset.append(digital.get(rst, False) if rst else False)
            duty.append(analog.get(pwm, 0.0) if pwm else 0.0)
            direction.append(digital.get(dirn, False) if dirn else False)
            brake.append(digital.get(brk, False) if brk else False)
            # An unwired holding-brake line is low: a plant brake nobody wired never releases.
            holding.append(digital.get(hold, False) if hold else False)
        watchdog = s.get_digital(self.watchdog_net) if self.watchdog_net else False
        return PlantCommand(
            amp_command_v=np.array(cmd_v, dtype=float), amp_enable=np.array(enable, dtype=bool),
            fault_reset=np.array(reset, dtype=bool), pwm_duty=np.array(duty, dtype=float),
            pwm_direction=np.array(direction, dtype=bool), brake=np.array(brake, dtype=bool),
            watchdog_line=watchdog, holding_brake=np.array(holding, dtype=bool),
        )

    def step(self, period_s: float, delay_s: float) -> PlantSensors:
        """Exchange once: send the commands, advance the plant one period, keep its answer."""
        self.pending = self.link.exchange(self.collect(), period_s, delay_s)
        self.exchanges += 1
        return self.pending

    def publish(self) -> None:
        """Put the last answer on the sensor nets (call at the start of the next tick)."""
        sensors = self.pending
        if sensors is None:
            return
        s = self.signals
        # one conversion per array (the same Python floats and bools as indexing each element)
        pot = np.asarray(sensors.pot_v, dtype=float).tolist()
        tach = np.asarray(sensors.tach_v, dtype=float).tolist()
        imon = np.asarray(sensors.imon_v, dtype=float).tolist()
        fault = np.asarray(sensors.amp_fault, dtype=bool).tolist()
        encoder = sensors.encoder
        # s.set_analog inline for nets nobody listens to (most: the ADC samples them), in the same
        # order; the values are Python floats already (tolist)
        analog, listened = s.analog, s.listened()
        for i, pot_net, tach_net, imon_net, fault_net, enc_net in self._wiring()[1]:
            for net, volts in ((pot_net, pot[i]), (tach_net, tach[i]), (imon_net, imon[i])):
                if not net:
                    continue
                if listened.get(net):
                    s.set_analog(net, volts)
                else:
                    analog[net] = volts
            if fault_net:
                s.set_digital(fault_net, fault[i])
            if enc_net:
                ev = encoder[i]
                if isinstance(ev, QuadratureEvents):
                    s.publish_quadrature(enc_net, ev)
        self.last = sensors
        self.pending = None
