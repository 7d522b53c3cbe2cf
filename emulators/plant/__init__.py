"""The joint plant: amplifier power stages, DC motors, Harmonic Drives, links and sensors.

See ``docs/plant.md``. Public API::

    from emulators.plant import Plant, PlantCommand, PlantSensors, PlantParams, load_plant
"""

from emulators.plant.encoder import encoder_events
from emulators.plant.params import (
    AMP_HBRIDGE,
    AMP_LINEAR,
    EncoderParams,
    FrictionParams,
    GearParams,
    HBridgeParams,
    HoldingBrakeParams,
    JointParams,
    LinearAmpParams,
    LinkParams,
    MotorParams,
    PlantParams,
    PotParams,
    TachParams,
    plant_params_from_config,
)
from emulators.plant.plant import Plant, PlantCommand, PlantSensors
from emulators.plant.rig_plants import load_plant, load_plant_params

__all__ = [
    "AMP_HBRIDGE",
    "AMP_LINEAR",
    "EncoderParams",
    "FrictionParams",
    "GearParams",
    "HBridgeParams",
    "HoldingBrakeParams",
    "JointParams",
    "LinearAmpParams",
    "LinkParams",
    "MotorParams",
    "Plant",
    "PlantCommand",
    "PlantParams",
    "PlantSensors",
    "PotParams",
    "TachParams",
    "encoder_events",
    "load_plant",
    "load_plant_params",
    "plant_params_from_config",
]
