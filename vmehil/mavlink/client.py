"""A minimal pymavlink ground-station side for tests and scripts: heartbeat, parameter
requests, PARAM_SET, arm/disarm, and a message collector. Loopback UDP (``udpout``) only.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import vmehil.mavlink  # noqa: F401  (MAVLINK20=1 before pymavlink)
from vmehil.mavlink.endpoint import _mavutil


class Client:
    """Talks to an endpoint listening on ``127.0.0.1:port`` (system 255, component 190)."""

    def __init__(self, port: int, key: bytes | None = None, sysid: int = 255, compid: int = 190) -> None:
        mavutil = _mavutil()
        self.ml = mavutil.mavlink
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=sysid,
                                               source_component=compid)
        if key is not None:
            self.conn.setup_signing(key, sign_outgoing=True)
        self.inbox: list[Any] = []

    def hello(self) -> None:
        self.conn.mav.heartbeat_send(self.ml.MAV_TYPE_GCS, self.ml.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def request_list(self, target: tuple[int, int] = (1, 1)) -> None:
        self.conn.mav.param_request_list_send(*target)

    def read(self, name: str = "", index: int = -1, target: tuple[int, int] = (1, 1)) -> None:
        self.conn.mav.param_request_read_send(*target, name.encode(), index)

    def set(self, name: str, value: float, target: tuple[int, int] = (1, 1)) -> None:
        self.conn.mav.param_set_send(*target, name.encode(), value, self.ml.MAV_PARAM_TYPE_REAL32)

    def arm(self, on: bool = True, target: tuple[int, int] = (1, 1)) -> None:
        self.conn.mav.command_long_send(*target, self.ml.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1.0 if on else 0.0,
                                        0, 0, 0, 0, 0, 0)

    def pump(self) -> None:
        while True:
            m = self.conn.recv_msg()
            if m is None:
                return
            if m.get_type() != "BAD_DATA":
                self.inbox.append(m)

    def of(self, mtype: str) -> list[Any]:
        return [m for m in self.inbox if m.get_type() == mtype]

    def wait(self, cond: Callable[[], Any], step: Callable[[], None], timeout_s: float = 5.0) -> Any:
        """Call ``step`` (e.g. one loop tick) and pump until ``cond()`` is truthy; bounded in time."""
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            step()
            self.pump()
            r = cond()
            if r:
                return r
            time.sleep(0.0005)
        raise TimeoutError("no answer from the endpoint within the time limit")

    def close(self) -> None:
        self.conn.close()
