"""``vmehil crate``: inspect and poke an emulated crate, like ``halcmd`` for driver authors.

Examples::

    vmehil crate list                          # boards of the default rig's crate
    vmehil crate read A24 0x200000 --width 16
    vmehil crate write A16 0x0000 0x0001 --width 16
    vmehil crate list --json                   # options before or after the action
    vmehil crate demo                          # build, probe every board, print the map
    echo "write A24 0x200000 0xBEEF; read A24 0x200000; counters" | vmehil crate shell
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from dataclasses import dataclass
from typing import Any

from emulators.board_types import BOARD_TYPES
from emulators.crate import Crate
from emulators.crate_file import load_crate
from emulators.presets import resolve_rig
from hal.board_types import BOARD_TYPES as HAL_BOARD_TYPES
from hal.vme.errors import BusError, VmeError
from hal.vme.types import AddressSpace, Width
from vmehil.errors import CliError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("crate", help="list, probe, read and write an emulated VME crate")
    _add_common(p, defaults=True)
    # the same options after the action (`crate list --json` as well as `crate --json list`);
    # given there, they win
    common = argparse.ArgumentParser(add_help=False)
    _add_common(common, defaults=False)
    csub = p.add_subparsers(dest="crate_cmd", metavar="ACTION")
    csub.required = True
    csub.add_parser("list", parents=[common], help="list the boards and their windows")
    csub.add_parser("demo", parents=[common], help="build the crate, probe every board, print the map and counters")
    csub.add_parser("types", parents=[common], help="list the board types a crate file can use")
    csub.add_parser("counters", parents=[common], help="probe every board, then print the access counters")
    r = csub.add_parser("read", parents=[common], help="read one value: read A24 0x200000 --width 16")
    r.add_argument("space")
    r.add_argument("address", type=_int)
    r.add_argument("--width", default="16", help="8, 16 or 32 (or D8/D16/D32)")
    w = csub.add_parser("write", parents=[common], help="write one value: write A24 0x200000 0xBEEF --width 16")
    w.add_argument("space")
    w.add_argument("address", type=_int)
    w.add_argument("value", type=_int)
    w.add_argument("--width", default="16")
    csub.add_parser("shell", parents=[common], help="read commands (read/write/list/counters/time) from stdin")
    p.set_defaults(func=run, options=CrateOptions.from_args)


def _add_common(p: argparse.ArgumentParser, *, defaults: bool) -> None:
    """``--rig``, ``--json``, ``--bus``: on ``crate`` with their defaults, and after the action
    with none (argparse.SUPPRESS), so that an action's parser only sets what was given there."""
    def default(value: Any) -> Any:
        return value if defaults else argparse.SUPPRESS

    p.add_argument("--rig", metavar="NAME|PATH", default=default(None),
                   help="rig preset name or crate/rig TOML path (default jpl-arm)")
    p.add_argument("--json", action="store_true", default=default(False), help="print machine-readable JSON")
    p.add_argument("--bus", default=default("emulated"),
                   help="emulated (default) or vme_user[:DIR]: a real crate through Linux's /dev/bus/vme "
                        "(list, read, write, shell; docs/vme-user.md)")


def _int(text: str) -> int:
    return int(text, 0)


@dataclass(frozen=True)
class CrateOptions:
    """``vmehil crate``'s options: the action and, for ``read``/``write``, its operands."""

    action: str
    rig: str | None = None
    json: bool = False
    bus: str = "emulated"
    space: str | None = None
    address: int | None = None
    value: int | None = None
    width: str = "16"

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> CrateOptions:
        # space, address, value and --width belong to the read/write actions' parsers only
        return cls(action=args.crate_cmd, rig=args.rig, json=args.json, bus=args.bus,
                   space=getattr(args, "space", None), address=getattr(args, "address", None),
                   value=getattr(args, "value", None), width=getattr(args, "width", "16"))

    def location(self) -> tuple[str, int, Width]:
        """``read``/``write``: the address space, address and width (their parsers require the first two)."""
        if self.space is None or self.address is None:
            raise CliError(f"crate {self.action}: give the address space and the address")
        return self.space, self.address, Width.parse(self.width)

    def write_value(self) -> int:
        """``write``: the value (its parser requires it)."""
        if self.value is None:
            raise CliError(f"crate {self.action}: give the value to write")
        return self.value


def run(opts: CrateOptions) -> int:
    if opts.bus != "emulated":
        return _run_real(opts)
    path = resolve_rig(opts.rig)
    crate = _load(path)
    cmd = opts.action
    if cmd == "types":
        _emit(opts, BOARD_TYPES.names(), lambda v: "\n".join(v))
    elif cmd == "list":
        _emit(opts, with_board_metadata(crate.describe(), _file_types(path)), _table)
    elif cmd in ("demo", "counters"):
        probes = probe_all(crate)
        if cmd == "demo":
            out = {"crate": crate.name, "boards": crate.describe(), "probes": probes,
                   "counters": crate.counter_snapshot(), "time_us": crate.now() * 1e6}
            _emit(opts, out, _demo_text)
        else:
            _emit(opts, crate.counter_snapshot(), lambda c: "\n".join(f"{k:24s} {v}" for k, v in c.items()))
    elif cmd == "read":
        space, address, width = opts.location()
        value = crate.read(address, space=space, width=width)
        _emit(opts, {"value": value}, lambda d: f"0x{d['value']:0{int(width) * 2}X}  ({d['value']})")
    elif cmd == "write":
        space, address, width = opts.location()
        crate.write(address, opts.write_value(), space=space, width=width)
        _emit(opts, {"ok": True}, lambda d: "ok")
    elif cmd == "shell":
        return shell(crate, sys.stdin, sys.stdout)
    return 0


def _run_real(opts: CrateOptions) -> int:
    """The same actions on a real bus: ``list`` shows the rig file's boards with the dry pass
    (ID and status reads) and the master windows; reads and writes go to the hardware."""
    from servo.rig import load_rig
    from vmehil.rig_setup.real_bus import dry_pass, open_bus

    cmd = opts.action
    if cmd not in ("list", "read", "write", "shell"):
        print(f"vmehil crate {cmd}: emulated crates only (on a real bus: list, read, write, shell)", file=sys.stderr)
        return 2
    with open_bus(opts.bus) as bus:
        if cmd == "list":
            checks = [c.as_dict() for c in dry_pass(bus, load_rig(resolve_rig(opts.rig)))]
            _emit(opts, {"boards": checks, "windows": bus.describe()},
                  lambda d: _table(d["boards"]) + "\n\n" + _table(d["windows"]))
            return 0 if all(c["ok"] for c in checks) else 1
        if cmd == "read":
            space, address, width = opts.location()
            value = bus.read(address, space=space, width=width)
            _emit(opts, {"value": value}, lambda d: f"0x{d['value']:0{int(width) * 2}X}  ({d['value']})")
        elif cmd == "write":
            space, address, width = opts.location()
            bus.write(address, opts.write_value(), space=space, width=width)
            _emit(opts, {"ok": True}, lambda d: "ok")
        else:
            return shell(bus, sys.stdin, sys.stdout)  # type: ignore[arg-type]
    return 0


def _load(path) -> Crate:
    """A crate file, or a rig file's crate with the joints' wiring (pins → nets) applied."""
    from hal.config import load_toml

    if "joint" not in load_toml(path):
        return load_crate(path)
    from emulators.crate_file import build_crate
    from servo.rig import load_rig
    from vmehil.rig_setup.system import wired_crate_table

    return build_crate(wired_crate_table(load_rig(path)))


def _file_types(path) -> dict[str, str]:
    """The crate file's boards: name → the board type it names (an emulator's own ``TYPE`` may be
    another's: a plug-in type built on a reference board's emulator)."""
    from hal.config import load_toml

    return {b.get_str("name"): b.get_str("type") for b in load_toml(path).table("crate").tables("board", [])}


def with_board_metadata(rows: list[dict[str, Any]], types: dict[str, str]) -> list[dict[str, Any]]:
    """Each board's ``vendor``, ``model`` and ``document`` from its type's entry in
    :data:`hal.board_types.BOARD_TYPES` (``types``: board name → type; a card's window,
    ``bit3-window``, is its card's); None for a type only the emulators know."""
    out = []
    for r in rows:
        owner = r["card"] if "card" in r else r["name"]
        bt = HAL_BOARD_TYPES.get(types.get(owner, r["type"]))
        meta: dict[str, str | None] = {"vendor": None, "model": None, "document": None}
        if bt is not None:
            meta.update(bt.metadata())
        out.append({**r, **meta})
    return out


def probe_all(crate: Crate) -> list[dict[str, Any]]:
    """Read the first readable location of every board; report OK or the bus error."""
    results = []
    for s in crate.slots():
        b = s.board
        regmap = getattr(b, "REGMAP", None)
        offset, width = 0, Width.D16
        if regmap is not None:
            reg = next((r for r in sorted(regmap.registers, key=lambda r: r.offset) if r.access.readable), None)
            if reg is not None:
                offset, width = reg.offset, reg.width
        try:
            value = crate.read(s.base + offset, space=s.space, width=width)
            results.append({"board": b.name, "address": f"0x{s.base + offset:X}", "width": width.name,
                            "ok": True, "value": f"0x{value:X}"})
        except BusError as e:
            results.append({"board": b.name, "address": f"0x{s.base + offset:X}", "width": width.name,
                            "ok": False, "error": str(e)})
    return results


def shell(crate: Crate, stdin, stdout) -> int:
    """A tiny command interpreter: ``read SPACE ADDR [WIDTH]``, ``write SPACE ADDR VALUE [WIDTH]``,
    ``list``, ``counters``, ``time``, ``delay US``; ``;`` separates commands on a line."""
    status = 0
    for line in stdin:
        for part in line.split(";"):
            words = shlex.split(part)
            if not words:
                continue
            try:
                stdout.write(_shell_one(crate, words) + "\n")
            except (VmeError, ValueError, IndexError) as e:
                stdout.write(f"error: {e}\n")
                status = 1
    return status


def _shell_one(crate: Crate, words: list[str]) -> str:
    op = words[0].lower()
    if op == "read":
        width = Width.parse(words[3] if len(words) > 3 else "16")
        v = crate.read(int(words[2], 0), space=AddressSpace.parse(words[1]), width=width)
        return f"0x{v:0{int(width) * 2}X}"
    if op == "write":
        width = Width.parse(words[4] if len(words) > 4 else "16")
        crate.write(int(words[2], 0), int(words[3], 0), space=AddressSpace.parse(words[1]), width=width)
        return "ok"
    if op == "list":
        return _table(crate.describe())
    if op == "counters":
        if not hasattr(crate, "counter_snapshot"):
            raise CliError("no access counters on a real bus")
        return "\n".join(f"{k} {v}" for k, v in crate.counter_snapshot().items())
    if op == "time":
        return f"{crate.now() * 1e6:.3f} us"
    if op == "delay":
        crate.delay(float(words[1]) * 1e-6)
        return "ok"
    raise CliError(f"unknown command {op!r} (read, write, list, counters, time, delay)")


def _emit(opts: CrateOptions, data: Any, text) -> None:
    print(json.dumps(data, indent=2) if opts.json else text(data))


_TEXT_COLUMNS = ("slot", "name", "space", "base", "end", "type", "vendor", "model", "document", "id", "wired",
                 "ok", "detail", "window", "layout", "am", "setting")


def _table(rows: list[dict[str, Any]]) -> str:
    """Boards as a text table: the common columns; a board's wiring as the number of wired
    pins (``--json`` gives every detail)."""
    if not rows:
        return "(no boards)"
    rows = [{**r, "wired": _wired(r)} for r in rows]
    cols = [c for c in _TEXT_COLUMNS if any(r.get(c) not in (None, "") for r in rows)]
    widths = {c: max(len(c), *(len(str(r.get(c, ""))) for r in rows)) for c in cols}
    head = "  ".join(c.ljust(widths[c]) for c in cols)
    lines = [head, "  ".join("-" * widths[c] for c in cols)]
    lines += ["  ".join(str(r.get(c, "")).ljust(widths[c]) for c in cols) for r in rows]
    return "\n".join(lines)


def _wired(row: dict[str, Any]) -> str:
    for key in ("wired", "lines", "channels"):
        v = row.get(key)
        if isinstance(v, int):
            return str(v)
        if isinstance(v, dict | list):
            return str(sum(1 for x in (v.values() if isinstance(v, dict) else v) if x))
    return ""


def _demo_text(d: dict[str, Any]) -> str:
    out = [f"crate {d['crate']}: {len(d['boards'])} boards", "", _table(d["boards"]), "", "probe:"]
    for p in d["probes"]:
        status = f"OK  {p['value']}" if p["ok"] else f"BERR {p['error']}"
        out.append(f"  {p['board']:12s} {p['width']} @ {p['address']:>10s}  {status}")
    out += ["", f"simulated bus time: {d['time_us']:.2f} us", "counters:"]
    out += [f"  {k:24s} {v}" for k, v in d["counters"].items()]
    return "\n".join(out)
