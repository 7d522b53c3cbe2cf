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
from hal.lanes import LaneSet, stack

# The link's types stay importable from here: the harness's users name them with it.
__all__ = ["ExchangeCodec", "Harness", "InProcessLink", "JointNets", "PlantLink", "PlantLinkError", "PlantLostError",
           "PlantRestartedError", "StaleDataError", "default_codec"]


def default_codec() -> ExchangeCodec:
    """The CAN message set's quantization (the DBC is read once per process)."""
    from emulators.can.codec import DbcExchangeCodec

    return DbcExchangeCodec()  # type: ignore[return-value]


class InProcessLink(PlantLink):
    """The embedded default: the plant is a Python object in this process.

    A stacked plant (:meth:`emulators.plant.Plant.from_lanes`) makes a link in lane mode: its
    exchange quantizes the stacked command and answer as the codec does each lane's, per
    element (:meth:`emulators.can.codec.DbcExchangeCodec.command_lanes`), and ``names`` are one
    lane's joints."""

    #: lane mode: the batch's lanes (``None``: one plant)
    lanes: LaneSet | None = None

    def __init__(self, plant: Plant, codec: ExchangeCodec | None = None) -> None:
        self.plant = plant
        self.codec = codec or default_codec()
        self.names = list(plant.names)
        lanes = getattr(plant, "lanes", None)
        if lanes is not None:
            self._lane_mode(lanes)

    def exchange(self, cmd: PlantCommand, period_s: float, delay_s: float) -> PlantSensors:
        return self.codec.sensors(self.plant.step_period(self.codec.command(cmd), period_s, delay_s))

    @classmethod
    def from_lanes(cls, links: Sequence[PlantLink], lanes: LaneSet) -> InProcessLink:
        """B in-process links (lane order, one codec) as one link to their plants stacked.
        Refused (``NotImplementedError``): another kind of link (a CAN link has no lane form),
        links of different codecs."""
        if not all(type(link) is InProcessLink for link in links):
            raise NotImplementedError("only in-process plant links run in lanes")
        ins = [link for link in links if isinstance(link, InProcessLink)]
        if any(type(link.codec) is not type(ins[0].codec) for link in ins):
            raise NotImplementedError("plant links with different codecs cannot run in lanes")
        return cls(Plant.from_lanes([link.plant for link in ins], lanes), codec=ins[0].codec)

    def _lane_mode(self, lanes: LaneSet) -> None:
        """Chosen once, at construction: the lane exchange replaces the scalar one."""
        from emulators.can.codec import DbcExchangeCodec

        codec = self.codec
        if type(codec) is not ExchangeCodec and not isinstance(codec, DbcExchangeCodec):
            raise NotImplementedError(f"the exchange codec {type(codec).__name__} has no lane form")
        self.lanes = lanes
        self.names = self.names[:getattr(self.plant, "lane_joints", len(self.names))]
        if isinstance(codec, DbcExchangeCodec):
            quantize_cmd, quantize_sensors = codec.command_lanes, codec.sensors_lanes
            step = self.plant.step_period

            def exchange(cmd: PlantCommand, period_s: float, delay_s: float) -> PlantSensors:
                return quantize_sensors(step(quantize_cmd(cmd), period_s, delay_s))  # type: ignore[no-any-return]

            self.exchange = exchange  # type: ignore[method-assign]


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

    #: lane mode (:meth:`from_lanes`): the batch's lanes (``None``: one rig)
    lanes: LaneSet | None = None

    @classmethod
    def from_lanes(cls, harnesses: Sequence[Harness], signals: Signals, link: PlantLink) -> Harness:
        """B harnesses (lane order, wired alike) as one harness of the stacked crate's nets
        (``signals``: lane values) and the stacked link (:meth:`InProcessLink.from_lanes`).
        :meth:`collect` reads each net's lane value (a scalar for every lane, or (B,)) into a
        command of B·n joints lane-major, with the dead lanes' (``lanes.alive`` false) amplifiers
        disabled at 0 V so their plants stay finite; :meth:`publish` puts each joint's sensor
        values on its nets as (B,) lane values (a fault line as one bool when every lane holds
        the same), its encoder events as one lane-mode :class:`QuadratureEvents`."""
        h0 = harnesses[0]
        lanes = getattr(link, "lanes", None)
        if lanes is None:
            raise NotImplementedError("a harness in lanes needs a link in lanes (InProcessLink.from_lanes)")
        if len(harnesses) != lanes.size:
            raise ValueError(f"{len(harnesses)} harnesses for {lanes.size} lanes")
        if any(h.joints != h0.joints or h.watchdog_net != h0.watchdog_net for h in harnesses):
            raise NotImplementedError("harnesses wired differently cannot run in lanes")
        out = cls(signals, h0.joints, link, watchdog_net=h0.watchdog_net)
        out.lanes = lanes
        for name in ("pending", "last"):
            got = [getattr(h, name) for h in harnesses]
            if any(g is not None for g in got):
                if any(g is None for g in got):
                    raise NotImplementedError(f"harnesses with and without a {name} answer cannot run in lanes")
                setattr(out, name, PlantSensors.from_lanes(got))
        out.exchanges = stack([h.exchanges for h in harnesses])
        out.collect = out._collect_lanes  # type: ignore[method-assign]
        out.publish = out._publish_lanes  # type: ignore[method-assign]
        return out

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

    # ---- lane mode (from_lanes) -------------------------------------------------------------
    def _collect_lanes(self) -> PlantCommand:
        """:meth:`collect` of B lanes: each net's lane value into column ``b`` of its joint."""
        lanes = self.lanes
        assert lanes is not None
        s = self.signals
        analog, digital = s.analog, s.digital
        B, n = lanes.size, self.n
        cmd_v = np.zeros((n, B))
        enable = np.ones((n, B), dtype=bool)  # an unwired enable is tied high on the amplifier
        reset = np.zeros((n, B), dtype=bool)
        duty = np.zeros((n, B))
        direction = np.zeros((n, B), dtype=bool)
        brake = np.zeros((n, B), dtype=bool)
        holding = np.zeros((n, B), dtype=bool)
        for j, (command, en, rst, pwm, dirn, brk, hold) in enumerate(self._wiring()[0]):
            if command:
                cmd_v[j] = analog.get(command, 0.0)
            if en:
                enable[j] = digital.get(en, False)
            if rst:
                reset[j] = digital.get(rst, False)
            if pwm:
                duty[j] = analog.get(pwm, 0.0)
            if dirn:
                direction[j] = digital.get(dirn, False)
            if brk:
                brake[j] = digital.get(brk, False)
            if hold:
                holding[j] = digital.get(hold, False)
        dead = ~lanes.alive
        if dead.any():  # lanes no longer followed: amplifiers off, so their plants stay finite
            enable[:, dead] = False
            cmd_v[:, dead] = 0.0
            duty[:, dead] = 0.0
        watchdog = s.get_digital(self.watchdog_net) if self.watchdog_net else False
        if isinstance(watchdog, np.ndarray):
            watchdog = np.array(watchdog, dtype=bool)

        def lane_major(a: np.ndarray) -> np.ndarray:
            return np.ascontiguousarray(a.T).reshape(B * n)

        return PlantCommand(
            amp_command_v=lane_major(cmd_v), amp_enable=lane_major(enable), fault_reset=lane_major(reset),
            pwm_duty=lane_major(duty), pwm_direction=lane_major(direction), brake=lane_major(brake),
            watchdog_line=watchdog, holding_brake=lane_major(holding),
        )

    def _publish_lanes(self) -> None:
        """:meth:`publish` of B lanes: each joint's (B,) values on its nets."""
        sensors = self.pending
        if sensors is None:
            return
        lanes = self.lanes
        assert lanes is not None
        s = self.signals
        B, n = lanes.size, self.n

        def per_joint(a: np.ndarray, dtype: type) -> np.ndarray:  # (n, B): row j is joint j's lane vector
            return np.ascontiguousarray(np.asarray(a, dtype=dtype).reshape(B, n).T)

        pot, tach, imon = per_joint(sensors.pot_v, float), per_joint(sensors.tach_v, float), per_joint(
            sensors.imon_v, float)
        fault = per_joint(sensors.amp_fault, bool)
        encoder = sensors.encoder
        analog, listened = s.analog, s.listened()
        for i, pot_net, tach_net, imon_net, fault_net, enc_net in self._wiring()[1]:
            for net, volts in ((pot_net, pot[i]), (tach_net, tach[i]), (imon_net, imon[i])):
                if not net:
                    continue
                if listened.get(net):
                    s.set_analog(net, volts)  # type: ignore[arg-type]
                else:
                    analog[net] = volts  # type: ignore[assignment]
            if fault_net:
                f = fault[i]
                level = f if f.any() and not f.all() else bool(f[0])  # hal.lanes.stack: one bool when alike
                s.set_digital(fault_net, level)  # type: ignore[arg-type]
            if enc_net:
                s.publish_quadrature(enc_net, encoder[i])
        self.last = sensors
        self.pending = None
