"""A pot calibration for homing tests without the pot procedure's 30 s of moves: a table from the
plant's own noise-free pot model at nine angles over each joint's travel — what a perfect
``calibrate pot --auto`` measures. Homing needs the pots calibrated (the pot chooses the index).

No tests here; the homing tests import it as ``tests.support.homing``.
"""

from __future__ import annotations

import numpy as np

from vmehil.calibration.store import CalibrationStore, JointCal
from vmehil.rig_setup.system import EmulatedRig


def plant_pot_store(system: EmulatedRig, joints: list[int]) -> CalibrationStore:
    """A store with a ``pot`` entry per joint in ``joints`` (0-based)."""
    store = CalibrationStore.empty(system.rig)
    assert system.plant is not None
    pot = system.plant.pot
    for i in joints:
        p = system.params[i]
        angles = np.linspace(p.link.lower_stop_rad + 0.05, p.link.upper_stop_rad - 0.05, 9)
        full = np.zeros((9, system.rig.n_joints))
        full[:, i] = angles
        volts = [float(pot.volts(row)[i]) for row in full]
        store.set_joint(system.rig.joints[i].name, JointCal("pot", 1, "2026-01-01T00:00:00Z",
                                                            {"volts": volts, "angles_rad": angles.tolist()}))
    return store
