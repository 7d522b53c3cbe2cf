"""The plant's compiled period kernel (numba), and the choice between it and the numpy path.

:func:`emulators.plant.numba_kernel.period_kernel` integrates one servo period of every joint in
one call: the substeps (amplifier current loop and limits, H-bridge, exact stick/slip with zero-crossing capture,
flexspline, gravity, hard stops, tachometer), the slow amplifier faults, the encoder's
quadrature events and the sensor outputs. It is the same physics as the numpy path of
:class:`emulators.plant.Plant` (``plant.py``, ``amplifier.py``, ``friction.py``,
``encoder.py``), written per joint and per substep with scalars so that a compiler can keep a
joint's state in registers: the joints do not interact inside a period, so the kernel loops
joints outside and substeps inside.

What stays in Python (``Plant._step_compiled``): the enable watchdog's events (they cut the period
into at most three segments, passed in as ``seg_start``/``seg_cmd``/``seg_enable``), the noise
draws from the seeded numpy generators (passed in as arrays, so the streams are numpy's in both
paths), the injected faults, and building the ``PlantSensors``.

Choice (``VMEHIL_PLANT_KERNEL``): ``numba`` (default) or ``numpy`` (the vectorised reference
path). Numba compiles the kernel once, with an explicit signature, and keeps the
machine code in its on-disk cache (``cache=True``: ``__pycache__`` beside this file, or
``NUMBA_CACHE_DIR``); :func:`warm_up` loads or compiles it when a plant is built, before any
loop, and says on stderr when it had to compile and how long it took (a cache load is logged at
INFO). Because the signature is
explicit the dispatcher can never compile again later (a call with other types raises), so no
compile can happen inside a real-time loop.

Numerics: the kernel evaluates the same expressions in the same order as the numpy path, but
``exp``/``sin``/``cos``/``log1p`` come from the C library here and from numpy's SIMD loops there,
which may differ in the last bit; the linear amplifier's loop uses one form of the first-order
update (numpy's all-linear fast path another, equal in exact arithmetic). The two paths agree to
round-off per step (tests/emulators/plant/test_kernel.py); over many periods stick/slip
decisions taken at round-off distance from a threshold can make trajectories drift apart, so
long runs agree in their statistics (the paper's figures), not bit for bit. Each path alone is
deterministic per seed.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from typing import Any

ENV = "VMEHIL_PLANT_KERNEL"
KERNELS = ("numba", "numpy")

_compiled: Any = None
_report: str | None = None
_missing = False


def choice(requested: str | None = None) -> str:
    """The kernel to use: ``requested``, else ``$VMEHIL_PLANT_KERNEL``, else ``numba``."""
    name = (requested or os.environ.get(ENV) or "numba").strip().lower()
    if name not in KERNELS:
        raise ValueError(f"{ENV}={name!r}: expected one of {', '.join(KERNELS)}")
    return name


def compiled_kernel() -> Any:
    """The compiled period kernel (:func:`emulators.plant.numba_kernel.period_kernel`), loaded from
    numba's on-disk cache or compiled on the first call in a process (reported on stderr, with its
    seconds, when it had to compile)."""
    global _compiled, _report
    if _compiled is not None:
        return _compiled
    t0 = time.perf_counter()
    from emulators.plant import numba_kernel

    dt = time.perf_counter() - t0
    disp = numba_kernel.period_kernel
    stats = disp.stats
    if stats.cache_misses:
        _report = (f"plant kernel: compiled by numba {numba_kernel.numba.__version__} in {dt:.1f} s, "
                   f"cached on disk in {stats.cache_path}")
        print(_report, file=sys.stderr, flush=True)
    else:
        _report = f"plant kernel: numba, loaded from its on-disk cache in {dt:.2f} s"
        logging.getLogger(__name__).info(_report)
    _compiled = disp
    return disp


def kernel_for(requested: str | None = None) -> tuple[str, Any]:
    """``(name, compiled kernel or None)`` for a new plant: the compiled one unless the numpy path
    is chosen, or numba cannot be imported (then the numpy path, said once on stderr)."""
    global _missing
    name = choice(requested)
    if name == "numpy":
        return name, None
    try:
        return name, compiled_kernel()
    except ImportError as e:
        if not _missing:
            _missing = True
            print(f"plant kernel: numba unavailable ({e}); using the numpy path", file=sys.stderr, flush=True)
        return "numpy", None


def warm_up() -> str:
    """Make the compiled kernel ready now (before any loop starts); returns what it did."""
    compiled_kernel()
    assert _report is not None
    return _report


def report() -> str | None:
    """What :func:`warm_up` did in this process (``None``: not yet)."""
    return _report
