"""Quadrature decoder board: register map (:mod:`hal.quadrature.quad_regs`) and driver
(:mod:`hal.quadrature.quad`)."""

from hal.quadrature.quad import (
    ChannelReading,
    ChannelStatus,
    CountJumpError,
    IllegalTransitionError,
    IndexMismatchError,
    IndexNotSeenError,
    QuadratureDriver,
    QuadratureError,
    TrackingLostError,
)
from hal.quadrature.quad_regs import QUAD_REGS

__all__ = [
    "QUAD_REGS",
    "ChannelReading",
    "ChannelStatus",
    "CountJumpError",
    "IllegalTransitionError",
    "IndexMismatchError",
    "IndexNotSeenError",
    "QuadratureDriver",
    "QuadratureError",
    "TrackingLostError",
]
