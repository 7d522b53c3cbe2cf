"""`make test`'s two pytest processes (tests/pair.py): every test file that binds a UDP port or
joins the CAN multicast groups is in the network group (else two such tests could run at once
and read each other's frames), and test paths among the arguments mean one plain run."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.pair import NETWORK_GROUP, ROOT, TO_EVEN_OUT, _names_paths

#: what a test that uses a UDP port or a multicast group says in its source
SOCKET_USE = re.compile(r"udp_multicast|free_udp_port|CAN_TRANSPORTS|private_multicast_namespace|MavlinkEndpoint\(")


def _in_group(path: Path) -> bool:
    rel = path.relative_to(ROOT).as_posix()
    return any(rel == p or rel.startswith(p + "/") for p in (*NETWORK_GROUP, *TO_EVEN_OUT))


def test_every_test_file_that_uses_a_udp_port_or_a_multicast_group_runs_in_the_network_group() -> None:
    users = [p for p in sorted((ROOT / "tests").rglob("test_*.py"))
             if p.name != "test_pair.py" and SOCKET_USE.search(p.read_text(encoding="utf-8"))]
    assert users  # the pattern still finds the known ones
    outside = [p.relative_to(ROOT).as_posix() for p in users if not _in_group(p)]
    assert outside == [], f"add these to tests/pair.py NETWORK_GROUP: {outside}"


def test_every_path_of_the_groups_exists() -> None:
    assert [p for p in (*NETWORK_GROUP, *TO_EVEN_OUT) if not (ROOT / p).exists()] == []


@pytest.mark.parametrize(("args", "paths"), [
    (["-q"], False),
    (["-q", "-m", "not slow"], False),
    (["-k", "tests"], False),  # an option's value, not a path
    (["tests/hal"], True),
    (["-q", "tests/vmehil/servo_on_rig/test_watchdog_cross_checks.py::test_x"], True),
])
def test_test_paths_among_the_arguments_mean_one_plain_run(args, paths) -> None:
    assert _names_paths(args) is paths
