"""Stay: hold a position (done from the start)."""

from __future__ import annotations

import numpy as np

from servo.trajectory.base import Sample


class Stay:
    """Hold ``position`` (rad) for ``duration`` s (``inf`` = forever); ``done`` is always True."""

    def __init__(self, position: np.ndarray, duration: float = float("inf")) -> None:
        self.start = np.asarray(position, float).copy()
        self.end = self.start
        self.duration = float(duration)
        self._zeros = np.zeros_like(self.start)

    def sample(self, t: float) -> Sample:
        return Sample(self.start.copy(), self._zeros.copy(), self._zeros.copy(), True)
