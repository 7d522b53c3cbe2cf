"""Live tuning and telemetry of a running servo loop over MAVLink 2 (pymavlink).

See docs/mavlink.md. ``MAVLINK20=1`` is set here, before anything imports pymavlink, so that
:mod:`pymavlink.mavutil` picks the MAVLink 2 dialect (needed for signing and PARAM_ERROR).
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"
