"""The one loopback check behind `--live` and `--mavlink` (the network rule: nothing beyond this
machine unless the user says so)."""

from __future__ import annotations

import pytest

from vmehil.mavlink.endpoint import MavlinkError, check_url
from vmehil.option_groups.cli_types import is_loopback
from vmehil.option_groups.scope_options import parse_live


@pytest.mark.parametrize("host", ["127.0.0.1", "127.8.9.10", "::1", "localhost"])
def test_loopback_hosts_are_loopback(host: str) -> None:
    assert is_loopback(host)


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "10.0.0.1", "192.168.1.2", "8.8.8.8", "example.com",
                                  "localhost.example.com", "", "127.0.0.1.nip.io"])
def test_other_hosts_and_names_are_not(host: str) -> None:
    assert not is_loopback(host)


def test_live_and_mavlink_refuse_a_remote_host_unless_allowed() -> None:
    with pytest.raises(Exception, match="not a loopback address"):
        parse_live("0.0.0.0:8765")
    assert parse_live("0.0.0.0:8765", allow_remote=True) == ("0.0.0.0", 8765)
    with pytest.raises(MavlinkError, match="not a loopback address"):
        check_url("udpin:0.0.0.0:14550")
    assert check_url("udpin:127.0.0.1:14550") == ("udpin", "127.0.0.1", 14550)
