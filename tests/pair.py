"""`make test`'s pytest as two processes, one per core: ``python -m tests.pair [pytest args]``.

Most of the suite's wall time is one process: mypy (beside it) ends after ~40 s, and the second
core then idles while the tests wait on subprocesses, sockets and timeouts one after another.
Two pytest processes share the work instead:

* the *network group* — every test that binds a UDP port or joins the CAN multicast groups
  (udp_multicast on ports 43113/43114, MAVLink on ports picked free, unit and plant-node
  processes) — runs in one process, so no two of them ever share a port or a group at once
  (Linux hands a group's datagrams to every socket bound to the port: two runs side by side
  would read each other's frames);
* everything else runs in the other, beside it — but for a few long tests that use no port
  (:data:`TO_EVEN_OUT`), which join the network group's process to even the two out.

Each process is a plain pytest run of its part (same arguments, same conftest); the network
group's output is printed after the other's, and the exit status is the first failure's. With
test paths among the arguments there is nothing to split: one pytest runs them.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: the tests that use UDP ports or the CAN multicast groups (see the module docstring); a new
#: test file that opens a socket belongs here
NETWORK_GROUP = (
    "tests/emulators/can",
    "tests/fuzz/test_mavlink.py",
    "tests/vmehil/mavlink",
    "tests/vmehil/commands/test_extras.py",
    "tests/vmehil/commands/test_tune_can.py",
    "tests/vmehil/test_can_first_hour.py",
    "tests/vmehil/test_can_system.py",
    "tests/vmehil/test_gain_guard_entry_points.py",
    "tests/vmehil/test_live.py",
    "tests/vmehil/test_units_options.py",
    "tests/vmehil/test_units_plant_node.py",
    "tests/vmehil/test_units_processes.py",
    "tests/vmehil/test_units_remote.py",
    "tests/vmehil/test_units_sessions.py",
)
#: long tests without ports run in the network group's process: measured at 10:28 UTC (idle
#: machine), the network group took 206 s and the rest 303 s; these two files are ~50 s of it
TO_EVEN_OUT = (
    "tests/vmehil/commands/test_tune_sweep_engines.py",
    "tests/vmehil/test_reproduce.py",
)


def _names_paths(args: list[str]) -> bool:
    """Whether ``args`` name tests to run (a path, or a node id), not only options."""
    skip = False
    for a in args:
        if skip:
            skip = False
            continue
        if a in ("-m", "-k", "-p", "-c", "-o", "--durations", "--rootdir", "--basetemp"):
            skip = True  # the next argument is the option's value
            continue
        if not a.startswith("-") and (ROOT / a.split("::")[0]).exists():
            return True
    return False


def main(args: list[str]) -> int:
    pytest = [sys.executable, "-m", "pytest", *args]
    if _names_paths(args):
        return subprocess.call(pytest)
    group = [p for p in (*NETWORK_GROUP, *TO_EVEN_OUT) if (ROOT / p).exists()]
    with tempfile.TemporaryFile("w+") as log:
        net = subprocess.Popen([*pytest, *group], stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
        try:
            rest = subprocess.call([*pytest, *(f"--ignore={p}" for p in group)], cwd=ROOT)
        finally:
            net_status = net.wait()
            log.seek(0)
            print(f"\n--- the network group and {len(TO_EVEN_OUT)} long files, run beside the rest ---", flush=True)
            sys.stdout.write(log.read())
            sys.stdout.flush()
    return rest or net_status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
