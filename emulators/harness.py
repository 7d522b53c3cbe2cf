"""The harness: one explicit exchange per servo period between the electronics and the plant.

The boards see only nets (:class:`emulators.signals.Signals`). Once per servo period the
harness reads the command nets (amplifier command volts, enables, PWM, direction, brake,
fault reset, and the rig's amplifier enable-watchdog line) into a :class:`PlantCommand`, hands
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
    pot: str | None = None
    tach: str | None = None
    imon: str | None = None
    encoder: str | None = None


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

    def collect(self) -> PlantCommand:
        """Read the command nets into a :class:`PlantCommand`."""
        s = self.signals
        n = self.n
        cmd_v = np.zeros(n)
        enable = np.zeros(n, bool)
        reset = np.zeros(n, bool)
        duty = np.zeros(n)
        direction = np.zeros(n, bool)
        brake = np.zeros(n, bool)
        for i, j in enumerate(self.joints):
            if j.amp_command:
                cmd_v[i] = s.get_analog(j.amp_command)
            # An unwired enable is tied high on the amplifier (always enabled).
            enable[i] = s.get_digital(j.amp_enable) if j.amp_enable else True
            if j.amp_reset:
                reset[i] = s.get_digital(j.amp_reset)
            if j.pwm:
                duty[i] = s.get_analog(j.pwm)
            if j.direction:
                direction[i] = s.get_digital(j.direction)
            if j.brake:
                brake[i] = s.get_digital(j.brake)
        watchdog = s.get_digital(self.watchdog_net) if self.watchdog_net else False
        return PlantCommand(
            amp_command_v=cmd_v, amp_enable=enable, fault_reset=reset,
            pwm_duty=duty, pwm_direction=direction, brake=brake, watchdog_line=watchdog,
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
        for i, j in enumerate(self.joints):
            if j.pot:
                s.set_analog(j.pot, float(sensors.pot_v[i]))
            if j.tach:
                s.set_analog(j.tach, float(sensors.tach_v[i]))
            if j.imon:
                s.set_analog(j.imon, float(sensors.imon_v[i]))
            if j.amp_fault:
                s.set_digital(j.amp_fault, bool(sensors.amp_fault[i]))
            if j.encoder:
                ev = sensors.encoder[i]
                if isinstance(ev, QuadratureEvents):
                    s.publish_quadrature(j.encoder, ev)
        self.last = sensors
        self.pending = None
