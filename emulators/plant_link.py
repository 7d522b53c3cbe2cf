"""The link to the plant: where the plant runs (:class:`PlantLink`), how a failing link is reported
(:class:`PlantLinkError` and its causes) and the wire resolution both links share
(:class:`ExchangeCodec`). Its own module so that the links (in-process in :mod:`emulators.harness`,
CAN in :mod:`emulators.can.can_plant_link`) and the harness import it, and not each other.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

from emulators.errors import EmulatorError
from emulators.plant import PlantCommand, PlantSensors


class ExchangeCodec:
    """Quantizes the exchanged values to the resolution of the wire encoding.

    This base class is the identity (raw plant values). The default codec of every link is
    :func:`emulators.harness.default_codec`: the CAN message set's quantization (scale, offset and range of each
    DBC signal, :class:`emulators.can.codec.DbcExchangeCodec`), so in-process runs and lockstep
    runs over CAN see bit-identical values.
    """

    def command(self, cmd: PlantCommand) -> PlantCommand:
        return cmd

    def sensors(self, s: PlantSensors) -> PlantSensors:
        return s


class PlantLinkError(EmulatorError, RuntimeError):
    """The link to the plant failed; the runner turns it into a safe stop with ``cause``."""

    cause = "plant_link"


class StaleDataError(PlantLinkError):
    """No fresh sensor data from the plant within the allowed number of ticks."""

    cause = "stale_sensor"


class PlantLostError(StaleDataError):
    """The plant node fell silent (no answer and no heartbeat within the timeout)."""

    cause = "plant_lost"


class AmplifiersLatchedError(PlantLinkError):
    """The plant node latched amplifiers off on its own (its enable watchdog or its command
    timeout): the controller's commands came too late or stopped, and no current reaches them."""

    cause = "amplifiers_latched"


class PlantRestartedError(PlantLinkError):
    """The plant node restarted (new boot identifier): its state no longer matches the loop's."""

    cause = "plant_restarted"


class PlantLink(ABC):
    """Where the plant runs. ``exchange`` advances it exactly one servo period (lockstep)."""

    names: list[str]
    #: the plant's step (its time in periods) whose values the last exchange returned, where it
    #: is not one step per exchange (a free-running plant: answers skip or repeat steps); ``None``:
    #: lockstep, exchange ``k`` returns step ``k``
    answer_step: int | None = None

    @abstractmethod
    def exchange(self, cmd: PlantCommand, period_s: float, delay_s: float) -> PlantSensors: ...

    def close(self) -> None:  # noqa: B027 - optional hook, not abstract
        """Release transports (no-op in-process)."""
