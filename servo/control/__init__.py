"""Control law, normalizing chain and control objects (pure numpy; drivers are wired in by the runners).

See docs/control.md.
"""

from servo.control.errors import ControlError, GainError, GainRejected, GainSyntaxError
from servo.control.gains import (
    DEFAULT_GAINS,
    GAIN_NAMES,
    GAIN_UNITS,
    Gains,
    format_gains,
    gain_items,
    parse_gains,
)
from servo.control.law import (
    DEFAULT_PERIOD_S,
    LawState,
    PidLaw,
    SwitchEvent,
    SwitchOffConfig,
)
from servo.control.linear import (
    closed_loop_poly,
    continuous_poles,
    sampled_loop_matrix,
    sampled_loop_ss,
    simulate_sampled_loop,
)
from servo.control.normalize import NormalizingChain, normalizing_chain, per_joint, unit_chain
from servo.control.objects import (
    BUILTIN_CONTROL_OBJECTS,
    CONTROL_OBJECTS,
    BaseControlObject,
    ControlContext,
    Controller,
    ControlObject,
    ControlOutput,
    FrictionComp,
    GravityComp,
    PidObject,
    SwitchableController,
    TorqueLimit,
    build_controller,
)

__all__ = [
    "BUILTIN_CONTROL_OBJECTS",
    "CONTROL_OBJECTS",
    "DEFAULT_GAINS",
    "DEFAULT_PERIOD_S",
    "GAIN_NAMES",
    "GAIN_UNITS",
    "BaseControlObject",
    "ControlContext",
    "ControlError",
    "ControlObject",
    "ControlOutput",
    "Controller",
    "FrictionComp",
    "GainError",
    "GainRejected",
    "GainSyntaxError",
    "Gains",
    "GravityComp",
    "LawState",
    "NormalizingChain",
    "PidLaw",
    "PidObject",
    "SwitchEvent",
    "SwitchOffConfig",
    "SwitchableController",
    "TorqueLimit",
    "build_controller",
    "closed_loop_poly",
    "continuous_poles",
    "format_gains",
    "gain_items",
    "normalizing_chain",
    "parse_gains",
    "per_joint",
    "sampled_loop_matrix",
    "sampled_loop_ss",
    "simulate_sampled_loop",
    "unit_chain",
]
