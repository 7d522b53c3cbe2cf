"""Joint sensors: wire-wound potentiometer, joint tachometer, motor encoder position, noise.

All functions are vectorised over joints and take SI inputs; outputs are volts (analog
sensors, as an ADC would see them) or x4 counts (encoder, as a float position).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from emulators.rng import rng_for


class NoiseStreams:
    """One seeded standard-normal stream per (joint, source), drawn in blocks.

    Each stream is ``rng_for(seed, "plant", joint_name, source)``, so adding a joint or a
    source never changes another stream; :meth:`draw` returns one value per joint.
    """

    BLOCK = 512

    def __init__(self, seed: int, joint_names: list[str], source: str) -> None:
        self._gens = [rng_for(seed, "plant", name, source) for name in joint_names]
        self._buf = np.empty((len(joint_names), self.BLOCK))
        self._pos = self.BLOCK

    @classmethod
    def from_lanes(cls, streams: Sequence[NoiseStreams]) -> NoiseStreams:
        """One stream set of B stacked plants (lane mode): every joint of every lane keeps its own
        generator (the scalar stream's object), lane-major, and draws from it exactly as the
        scalar one would (the buffers are copied; a refill takes one block from each generator,
        as the scalar refill does). The lanes must stand at the same place in their blocks (they
        drew as often): else ``NotImplementedError``."""
        if any(s._pos != streams[0]._pos or s.BLOCK != cls.BLOCK for s in streams):
            raise NotImplementedError("plant noise streams at different places cannot run in lanes")
        out = cls.__new__(cls)
        out._gens = [g for s in streams for g in s._gens]
        out._buf = np.concatenate([s._buf for s in streams], axis=0)
        out._pos = streams[0]._pos
        return out

    def draw(self) -> np.ndarray:
        if self._pos >= self.BLOCK:
            for k, g in enumerate(self._gens):
                self._buf[k] = g.standard_normal(self.BLOCK)
            self._pos = 0
        v = self._buf[:, self._pos].copy()
        self._pos += 1
        return v


@dataclass
class PotArrays:
    """Potentiometer parameters per joint (see :class:`emulators.plant.params.PotParams`)."""

    span: np.ndarray
    center: np.ndarray
    v_low: np.ndarray
    v_high: np.ndarray
    bow: np.ndarray
    periodic: np.ndarray
    cycles: np.ndarray
    noise: np.ndarray

    def fraction(self, theta_joint: np.ndarray) -> np.ndarray:
        """Wiper position as a fraction of the element, non-linearity included (0..1-ish)."""
        x = np.clip((theta_joint - self.center) / self.span + 0.5, 0.0, 1.0)
        return x + self.bow * 4.0 * x * (1.0 - x) + self.periodic * np.sin(2.0 * math.pi * self.cycles * x)

    def volts(self, theta_joint: np.ndarray) -> np.ndarray:
        """Noise-free wiper voltage (V)."""
        return self.v_low + (self.v_high - self.v_low) * self.fraction(theta_joint)

    def nonlinearity_rad(self, theta_joint: np.ndarray) -> np.ndarray:
        """Angle error of an ideal linear reading of the wiper (rad); for tests and reports."""
        x = np.clip((theta_joint - self.center) / self.span + 0.5, 0.0, 1.0)
        return (self.fraction(theta_joint) - x) * self.span


@dataclass
class TachArrays:
    """Joint tachometer parameters per joint (see :class:`emulators.plant.params.TachParams`)."""

    present: np.ndarray
    gradient: np.ndarray
    brush_drop: np.ndarray
    ripple: np.ndarray
    cycles: np.ndarray
    tau: np.ndarray
    offset: np.ndarray
    noise: np.ndarray

    def generator_volts(self, omega_joint: np.ndarray, theta_joint: np.ndarray) -> np.ndarray:
        """Terminal voltage before filtering: the emf less the brush-contact drop (V).

        A DC tach generator's brushes conduct through a thin oxide/graphite film whose contact
        drop is roughly constant once conducting; below it the output stays at zero. The result
        is a dead zone of ``brush_drop/gradient`` rad/s around zero speed.
        """
        emf = self.gradient * omega_joint * (1.0 + self.ripple * np.sin(self.cycles * theta_joint))
        out = np.sign(emf) * np.maximum(np.abs(emf) - self.brush_drop, 0.0)
        return np.where(self.present, out, 0.0)

    @property
    def dead_band_rad_s(self) -> np.ndarray:
        """Joint speed below which the tach reads zero (rad/s)."""
        return self.brush_drop / self.gradient


def encoder_x4(theta_motor: np.ndarray, counts_x4_per_rev: np.ndarray) -> np.ndarray:
    """Motor angle (rad) → x4 encoder position (float counts; integer part = decoded count)."""
    return theta_motor * (counts_x4_per_rev / (2.0 * math.pi))
