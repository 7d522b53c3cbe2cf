"""Alias of :mod:`hal.shm`: the protocol's memory is plain shared bytes, not part of the driver.

Import ``Memory`` and ``BufferMemory`` from ``hal.shm``.
"""

from hal.shm import BufferMemory, Memory

__all__ = ["BufferMemory", "Memory"]
