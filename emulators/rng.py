"""Seeded, named random streams: each noise source gets its own stream derived from the run's
seed and a stable name, so adding a board does not change another board's noise."""

from __future__ import annotations

import zlib

import numpy as np


def rng_for(seed: int, *names: str) -> np.random.Generator:
    """A ``numpy`` generator for ``seed`` and a stable name path (``rng_for(7, "adc0", "noise")``)."""
    keys = [int(seed) & 0xFFFFFFFF] + [zlib.crc32(n.encode()) for n in names]
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(keys)))
