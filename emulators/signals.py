"""The rack's connector panel: named nets between the boards and the rest of the rig.

Board pins (an ADC input, a DAC output, a PIO line, a decoder's A/B/Z input) are wired to
named nets by the rig's wiring table. The harness that couples the electronics to the plant
writes sensor nets and reads command nets once per servo period, in-process or over CAN; the
boards never know which.

Units: analog nets in volts; digital nets as logic levels (``True`` = high); quadrature nets
carry :class:`QuadratureEvents` summaries of what the decoder's input sampler saw.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.lanes import stack


@dataclass(frozen=True)
class QuadratureEvents:
    """What a quadrature decoder's input sampler saw during one interval.

    In lane mode (batched lockstep, :mod:`hal.lanes`) one object carries B instances' events
    (:func:`emulators.plant.lanes.lane_events`): ``counts``, ``illegal`` and ``phase`` are int64
    arrays of shape (B,) and ``index_offsets`` is a tuple of B tuples (lane b's offsets); a
    lane-mode board takes them.

    Attributes:
        counts: net valid x4 transitions (+ = A leads B), as the sampler decoded them; counts
            lost to illegal transitions are *not* included.
        illegal: number of samples in which A and B both changed (direction unknown).
        index_offsets: for each index pulse seen, the decoded x4 count offset from the start
            of the interval at which it occurred (the board latches ``count + offset``).
        phase: the quadrature state (0..3, Gray order 00,01,11,10) at the end of the interval.
    """

    counts: int = 0
    illegal: int = 0
    index_offsets: tuple[int, ...] = ()
    phase: int = 0


Listener = Callable[[str, Any], None]


class Signals:
    """Named analog, digital and quadrature nets with change listeners."""

    def __init__(self) -> None:
        self.analog: dict[str, float] = {}
        self.digital: dict[str, bool] = {}
        self._listeners: dict[str, list[Listener]] = defaultdict(list)

    @classmethod
    def from_lanes(cls, lanes: Sequence[Signals]) -> Signals:
        """The nets of B instances (lane order) as one panel: each net's values stacked
        (:func:`hal.lanes.stack`: a plain value where every lane holds the same, else a lane
        array). No listener is carried over: the lane boards subscribe again when installed."""
        s = cls()
        first = lanes[0]
        for attr in ("analog", "digital"):
            nets = getattr(first, attr)
            for other in lanes[1:]:
                if getattr(other, attr).keys() != nets.keys():
                    raise NotImplementedError(f"the instances' {attr} nets differ")
            getattr(s, attr).update({net: stack([getattr(x, attr)[net] for x in lanes]) for net in nets})
        return s

    def subscribe(self, net: str, listener: Listener) -> None:
        """Call ``listener(net, value)`` whenever ``net`` is set or published."""
        self._listeners[net].append(listener)

    def _notify(self, net: str, value: Any) -> None:
        for cb in self._listeners.get(net, ()):
            cb(net, value)

    def set_analog(self, net: str, volts: float) -> None:
        # a lane array (batched lockstep, hal.lanes) is kept as float64 lanes
        self.analog[net] = float(volts) if type(volts) is not np.ndarray else volts.astype(float)
        listeners = self._listeners.get(net)  # most analog nets have none (the ADC samples them)
        if listeners:
            for cb in listeners:
                cb(net, volts)

    def listened(self) -> dict[str, list[Listener]]:
        """The nets' listeners (read-only use: a net without any may be absent). A writer of
        many nets per tick sets ``analog`` directly where a net has no listener, as
        :meth:`set_analog` does, and calls :meth:`set_analog` where it has."""
        return self._listeners

    def get_analog(self, net: str, default: float = 0.0) -> float:
        return self.analog.get(net, default)

    def set_digital(self, net: str, level: bool) -> None:
        if type(level) is np.ndarray:
            self._set_digital_lanes(net, level)
            return
        level = bool(level)
        old = self.digital.get(net)
        self.digital[net] = level
        if old is not level:  # bools are singletons: a change (or a new net, or a lane array before)
            if type(old) is np.ndarray and not (old != level).any():
                return  # every lane held this level already
            self._notify(net, level)

    def _set_digital_lanes(self, net: str, level: np.ndarray) -> None:
        """:meth:`set_digital` of a lane array of levels: the listeners hear of it when any lane
        changed (with the lanes' levels)."""
        lv = level.astype(bool)
        old = self.digital.get(net)
        if old is None:
            changed = True
        elif (type(old) is np.ndarray and old.shape == lv.shape) or type(old) is bool:
            changed = np.count_nonzero(lv != old) != 0  # what array_equal says, without its overhead
        else:
            changed = not np.array_equal(np.broadcast_to(old, lv.shape), lv)
        self.digital[net] = lv  # type: ignore[assignment]
        if changed:
            self._notify(net, lv)

    def get_digital(self, net: str, default: bool = False) -> bool:
        return self.digital.get(net, default)

    def publish_quadrature(self, net: str, events: QuadratureEvents) -> None:
        """Deliver one interval's encoder events to the decoder channel wired to ``net``."""
        self._notify(net, events)
