"""The calibration store: one TOML file per rig, written atomically, loaded with identity checks.

Layout (see ``docs/calibration.md`` for a full example)::

    [calibration]
    format = "vmehil-calibration"   # refuses any other file
    format_version = 1
    rig = "jpl-arm"                 # the rig the file belongs to (refused for another rig)
    crate = "jpl-rack"
    written = "2025-01-01T12:00:00Z"

    [board.adc1]                    # one table per calibrated board
    type = "adc"                    # identity: type, base address, space and ID register
    base = 24832
    space = "A16"
    board_id = 44310                # 0xAD16
    procedure = "adc"               # who wrote it, which version, when
    procedure_version = 1
    date = "2025-01-01T12:00:00Z"
    offset_v = [...]                # one per channel (ADC 16, DAC 8): reading = gain·true + offset_v
    gain = [...]
    measured = [12, 13, 14, 15]     # channels actually measured (others: nominal 0 / 1)

    [joint.j1.pot]                  # per joint, per procedure
    procedure = "pot"
    procedure_version = 1
    date = "..."
    volts = [...]                   # piecewise-linear table (nine points)
    angles_rad = [...]

Rules: a procedure's result replaces only its own tables (the rest of the file is carried
over); the file is written with temp + fsync + rename and the previous file (if any) kept as
``<name>.prev`` (:func:`vmehil.writers.files.write_atomic_keeping_previous`), so a failed or interrupted procedure
leaves the old calibration in force. Loading checks the format, the rig name and every
board's identity against the rig's ``[crate]``; any mismatch raises
:class:`CalibrationFileError` saying what differs and what to do.
"""

from __future__ import annotations

import datetime as _dt
import itertools
import math
import os
import tomllib
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from hal.adc_dac.calibration import Calibration, CalibrationError
from hal.board_types import BOARD_TYPES
from hal.config import ConfigError, read_limited
from hal.vme.registers import Register
from servo.rig import RigSpec
from vmehil.errors import VmehilError
from vmehil.writers.files import PREVIOUS_SUFFIX, write_atomic_keeping_previous

FORMAT = "vmehil-calibration"
FORMAT_VERSION = 1
ENV_DIR = "VMEHIL_CALIBRATION_DIR"

#: the roles (hal.board_types) whose boards carry a per-channel offset/gain calibration
CALIBRATED_ROLES = ("adc", "dac")


def board_channels(board_type: str) -> int | None:
    """The channel count of a board type of a calibrated role (its driver's ``CHANNELS``); None
    for any other type."""
    bt = BOARD_TYPES.get(board_type)
    return bt.channels() if bt is not None and bt.role in CALIBRATED_ROLES else None


def board_id_register(board_type: str) -> Register | None:
    """The ID register of a board type of a calibrated role (its reset value is the ID, checked
    on load when a bus is given); None when the type has none."""
    bt = BOARD_TYPES.get(board_type)
    return bt.id_register() if bt is not None and bt.role in CALIBRATED_ROLES else None
_BOARD_COEFF_KEYS = {"offset_v", "gain"}
_META_KEYS = {"procedure", "procedure_version", "date"}


class CalibrationMissingWarning(UserWarning):
    """No calibration file: the drivers run on nominal (datasheet) values."""


def load_store_or_nominal(path: str | Path, rig: RigSpec, *, bus: Any = None) -> CalibrationStore | None:
    """:func:`load_store`, or ``None`` with a :class:`CalibrationMissingWarning` when the file
    does not exist (the drivers then run on nominal values). A file for another rig or board
    raises :class:`CalibrationFileError`."""
    try:
        return load_store(path, rig, bus=bus)
    except FileNotFoundError:
        warnings.warn(f"no calibration file {path}: drivers use nominal values "
                      f"(run `vmehil calibrate all --auto --rig {rig.name}`)", CalibrationMissingWarning, stacklevel=3)
        return None


class CalibrationFileError(VmehilError, ValueError):
    """A calibration file cannot be used: malformed, another format, another rig or board."""

    def __init__(self, path: str | Path, reason: str) -> None:
        self.path = str(path)
        self.reason = reason
        super().__init__(f"calibration file {path}: {reason}")


def utc_now() -> str:
    """ISO-8601 UTC timestamp, second resolution (the ``date`` field)."""
    return _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")


def default_store_path(rig: RigSpec | str) -> Path:
    """``$VMEHIL_CALIBRATION_DIR/<rig>.toml``, or ``./calibration/<rig>.toml`` when unset."""
    name = rig.name if isinstance(rig, RigSpec) else str(rig)
    return Path(os.environ.get(ENV_DIR, "calibration")) / f"{name}.toml"


@dataclass(frozen=True)
class BoardIdentity:
    """What makes a board entry belong to a board: type, base address, space (and ID register)."""

    name: str
    type: str
    base: int
    space: str

    @property
    def board_id(self) -> int | None:
        reg = board_id_register(self.type)
        return reg.reset if reg is not None else None


def rig_boards(rig: RigSpec) -> dict[str, BoardIdentity]:
    """The identities of the boards in the rig's ``[crate]``."""
    out: dict[str, BoardIdentity] = {}
    crate = rig.table.table("crate", {})
    for b in crate.tables("board", []):
        ident = BoardIdentity(b.get_str("name"), b.get_str("type"), b.get_int("base"), b.get_str("space").upper())
        out[ident.name] = ident
    return out


def crate_name(rig: RigSpec) -> str:
    return rig.table.table("crate", {}).get_str("name", "crate")


@dataclass
class BoardCal:
    """One board's stored calibration (ADC or DAC): coefficients plus provenance."""

    identity: BoardIdentity
    calibration: Calibration
    procedure: str
    procedure_version: int
    date: str
    measured: tuple[int, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)

    def to_toml(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "type": self.identity.type, "base": self.identity.base, "space": self.identity.space,
        }
        if self.identity.board_id is not None:
            d["board_id"] = self.identity.board_id
        d.update(procedure=self.procedure, procedure_version=self.procedure_version, date=self.date)
        d.update(self.calibration.to_dict())
        d["measured"] = list(self.measured)
        d.update(self.extra)
        return d


@dataclass
class JointCal:
    """One procedure's result for one joint (``pot``, ``encoder``, ``amplifier``, ``friction`` ...)."""

    procedure: str
    procedure_version: int
    date: str
    values: dict[str, Any]

    def to_toml(self) -> dict[str, Any]:
        return {"procedure": self.procedure, "procedure_version": self.procedure_version, "date": self.date,
                **self.values}


@dataclass
class CalibrationStore:
    """The whole calibration of one rig (what one TOML file holds)."""

    rig: str
    crate: str
    boards: dict[str, BoardCal] = field(default_factory=dict)
    joints: dict[str, dict[str, JointCal]] = field(default_factory=dict)
    written: str = ""
    path: Path | None = None
    #: where the last :meth:`save` kept the file it replaced; None if it replaced none (or no save yet)
    previous: Path | None = field(default=None, compare=False)

    @classmethod
    def empty(cls, rig: RigSpec) -> CalibrationStore:
        return cls(rig.name, crate_name(rig))

    # --- access ---------------------------------------------------------------------------
    def board_calibration(self, board: str) -> Calibration | None:
        bc = self.boards.get(board)
        return bc.calibration if bc is not None else None

    def joint_entry(self, joint: str, procedure: str) -> JointCal | None:
        return self.joints.get(joint, {}).get(procedure)

    def set_board(self, cal: BoardCal) -> None:
        self.boards[cal.identity.name] = cal

    def set_joint(self, joint: str, cal: JointCal) -> None:
        self.joints.setdefault(joint, {})[cal.procedure] = cal

    def merged(self, other: CalibrationStore) -> CalibrationStore:
        """A copy of ``self`` with every board and joint entry of ``other`` replacing its own."""
        out = CalibrationStore(self.rig, self.crate, dict(self.boards),
                               {j: dict(p) for j, p in self.joints.items()}, self.written, self.path)
        for b in other.boards.values():
            out.set_board(b)
        for j, procs in other.joints.items():
            for cal in procs.values():
                out.set_joint(j, cal)
        return out

    # --- serialisation --------------------------------------------------------------------
    def to_toml(self) -> str:
        doc: dict[str, Any] = {
            "calibration": {"format": FORMAT, "format_version": FORMAT_VERSION, "rig": self.rig,
                            "crate": self.crate, "written": self.written or utc_now()},
        }
        if self.boards:
            doc["board"] = {name: self.boards[name].to_toml() for name in sorted(self.boards)}
        if self.joints:
            doc["joint"] = {j: {p: c.to_toml() for p, c in sorted(procs.items())}
                            for j, procs in sorted(self.joints.items())}
        return tomli_w.dumps(_finite(doc, ""))

    def save(self, path: str | Path) -> Path:
        """Write atomically (temp + fsync + rename), keeping the file it replaces (if any) as
        ``.prev``; :attr:`previous` then says where (None: there was no file to keep)."""
        self.written = utc_now()
        text = self.to_toml()
        done = write_atomic_keeping_previous(path, text)
        self.path, self.previous = done.path, done.previous
        return done.path


def _finite(obj: Any, where: str) -> Any:
    """Refuse NaN/inf before writing (TOML could hold them, but a calibration must not)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        raise ValueError(f"calibration value {where} is {obj}; refusing to write a non-finite coefficient")
    if isinstance(obj, dict):
        return {k: _finite(v, f"{where}.{k}" if where else k) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if hasattr(obj, "item") and callable(obj.item):  # numpy scalar
        return _finite(obj.item(), where)
    return obj


def load_store(path: str | Path, rig: RigSpec, *, bus: Any = None) -> CalibrationStore:
    """Read and check a calibration file for ``rig``.

    Checks: TOML syntax; ``[calibration] format``/``format_version``; ``rig`` equals the rig's
    name; every ``[board.X]`` names a board of the rig's ``[crate]`` with the same type, base and
    space (and, when ``bus`` is given, the board's ID register reads the stored ``board_id``);
    coefficient lists have one finite value per channel and positive gains; every
    ``[joint.X]`` names a joint of the rig.

    Raises:
        FileNotFoundError: no file (callers decide: nominal values with a warning).
        CalibrationFileError: anything else; the message says why and what to do.
    """
    p = Path(path)
    try:
        raw = read_limited(p, what="a calibration file")
    except ConfigError as e:
        raise CalibrationFileError(p, e.expected) from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        prev = p.with_name(p.name + PREVIOUS_SUFFIX)
        fix = f"restore {prev.name} or re-run the calibration" if prev.exists() else "re-run the calibration"
        raise CalibrationFileError(p, f"not valid TOML ({e}); {fix}") from None
    head = data.get("calibration")
    if not isinstance(head, dict) or head.get("format") != FORMAT:
        raise CalibrationFileError(p, f"not a vmehil calibration file ([calibration] format = {FORMAT!r} missing)")
    version = head.get("format_version")
    if version != FORMAT_VERSION:
        raise CalibrationFileError(
            p, f"format_version {version!r} is not supported (this vmehil reads {FORMAT_VERSION}); "
               "re-run the calibration")
    file_rig = head.get("rig")
    if file_rig != rig.name:
        raise CalibrationFileError(
            p, f"written for rig {file_rig!r}, but this rig is {rig.name!r}; use that rig's file or re-calibrate "
               f"(vmehil calibrate all --auto --rig {rig.name})")
    file_crate = head.get("crate")
    if file_crate != crate_name(rig):
        raise CalibrationFileError(
            p, f"written for crate {file_crate!r}, but rig {rig.name} has crate {crate_name(rig)!r}; re-calibrate")
    unknown = set(data) - {"calibration", "board", "joint"}
    if unknown:
        raise CalibrationFileError(p, f"unknown top-level tables {sorted(unknown)}")
    store = CalibrationStore(rig.name, crate_name(rig), written=str(head.get("written", "")), path=p)
    idents = rig_boards(rig)
    for name, entry in _tables(p, data, "board").items():
        store.set_board(_load_board(p, name, entry, idents, bus))
    joints = {j.name for j in rig.joints}
    for jname, procs in _tables(p, data, "joint").items():
        if jname not in joints:
            raise CalibrationFileError(
                p, f"[joint.{jname}]: rig {rig.name} has no joint {jname!r} (joints: {', '.join(sorted(joints))})")
        if not isinstance(procs, dict):
            raise CalibrationFileError(p, f"[joint.{jname}] must be a table of procedure tables")
        for proc, entry in procs.items():
            if not isinstance(entry, dict):
                raise CalibrationFileError(p, f"[joint.{jname}.{proc}] must be a table")
            meta = _meta(p, f"joint.{jname}.{proc}", entry)
            if meta[0] != proc:
                raise CalibrationFileError(p, f"[joint.{jname}.{proc}] says procedure = {meta[0]!r}")
            values = {k: v for k, v in entry.items() if k not in _META_KEYS}
            _check_joint_values(p, f"joint.{jname}.{proc}", proc, values)
            store.set_joint(jname, JointCal(meta[0], meta[1], meta[2], values))
    return store


# Physical ranges a measured coefficient must fall in: far wider than any real error, so that
# only a corrupted or hand-mangled file (a gain of 1e-300, counts of 0) is refused.
BOARD_GAIN_RANGE = (0.5, 2.0)  #: a converter's gain error beyond ±50 %/−100 % is a broken board
BOARD_OFFSET_LIMIT_V = 1.0
AMP_GAIN_RANGE_A_PER_V = (1e-3, 1e3)
AMP_OFFSET_LIMIT_A = 100.0
ENCODER_COUNTS_RANGE = (1.0, 1e10)  #: x4 counts per joint revolution
POT_VOLTS_LIMIT_V = 10.5  #: an ADC input range and a little

#: the keys each procedure's joint entry must have (the ones the drivers apply)
JOINT_KEYS = {"pot": ("volts", "angles_rad"), "encoder": ("counts_per_joint_rev",),
              "amplifier": ("gain_a_per_v", "offset_a"), "home": ("index_angle_rad", "offset_counts")}


def _number(p: Path, where: str, key: str, v: Any, lo: float, hi: float, *, absolute: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise CalibrationFileError(p, f"[{where}] {key} = {v!r}: expected a finite number; re-run the calibration")
    x = abs(v) if absolute else v
    if not lo <= x <= hi:
        what = f"|{key}|" if absolute else key
        raise CalibrationFileError(p, f"[{where}] {key} = {v!r}: expected {lo:g} <= {what} <= {hi:g}; "
                                      "re-run the calibration")
    return float(v)


def _check_joint_values(p: Path, where: str, proc: str, values: Mapping[str, Any]) -> None:
    """Every value a driver applies is present, finite and physically possible; pot tables are
    strictly monotonic (else the angle of a voltage is ambiguous)."""
    for key in JOINT_KEYS.get(proc, ()):
        if key not in values:
            raise CalibrationFileError(p, f"[{where}] has no {key}; re-run the calibration ({proc})")
    if proc == "pot":
        volts, angles = values["volts"], values["angles_rad"]
        for key, seq in (("volts", volts), ("angles_rad", angles)):
            if not isinstance(seq, list) or len(seq) < 2:
                raise CalibrationFileError(p, f"[{where}] {key}: expected a list of at least two numbers")
        if len(volts) != len(angles):
            raise CalibrationFileError(p, f"[{where}] volts has {len(volts)} entries, angles_rad {len(angles)}")
        v = [_number(p, where, f"volts[{i}]", x, 0.0, POT_VOLTS_LIMIT_V, absolute=True) for i, x in enumerate(volts)]
        a = [_number(p, where, f"angles_rad[{i}]", x, 0.0, 4 * math.pi, absolute=True) for i, x in enumerate(angles)]
        for key, seq in (("volts", v), ("angles_rad", a)):
            steps = [b - c for c, b in itertools.pairwise(seq)]
            if not (all(d > 0 for d in steps) or all(d < 0 for d in steps)):
                raise CalibrationFileError(p, f"[{where}] {key} is not strictly monotonic; re-run the calibration")
    elif proc == "encoder":
        _number(p, where, "counts_per_joint_rev", values["counts_per_joint_rev"], *ENCODER_COUNTS_RANGE,
                absolute=True)
    elif proc == "home":  # a record (never applied at start): finite, a joint angle within two turns
        _number(p, where, "index_angle_rad", values["index_angle_rad"], 0.0, 4 * math.pi, absolute=True)
        _number(p, where, "offset_counts", values["offset_counts"], 0.0, 1e15, absolute=True)
    elif proc == "amplifier":
        _number(p, where, "gain_a_per_v", values["gain_a_per_v"], *AMP_GAIN_RANGE_A_PER_V, absolute=True)
        _number(p, where, "offset_a", values["offset_a"], 0.0, AMP_OFFSET_LIMIT_A, absolute=True)


def _tables(p: Path, data: Mapping[str, Any], key: str) -> dict[str, Any]:
    t = data.get(key, {})
    if not isinstance(t, dict):
        raise CalibrationFileError(p, f"[{key}] must be a table")
    return t


def _meta(p: Path, where: str, entry: Mapping[str, Any]) -> tuple[str, int, str]:
    proc, ver, date = entry.get("procedure"), entry.get("procedure_version"), entry.get("date")
    if not isinstance(proc, str) or not isinstance(ver, int) or not isinstance(date, str):
        raise CalibrationFileError(p, f"[{where}] needs procedure (string), procedure_version (integer) and date")
    return proc, ver, date


def _load_board(p: Path, name: str, entry: Any, idents: dict[str, BoardIdentity], bus: Any) -> BoardCal:
    where = f"[board.{name}]"
    if not isinstance(entry, dict):
        raise CalibrationFileError(p, f"{where} must be a table")
    ident = idents.get(name)
    if ident is None:
        raise CalibrationFileError(
            p, f"{where}: the rig's crate has no board {name!r} (boards: {', '.join(sorted(idents))}); "
               "the file is for another rack — re-calibrate")
    for key, want in (("type", ident.type), ("base", ident.base), ("space", ident.space)):
        got = entry.get(key)
        if isinstance(got, str) and key == "space":
            got = got.upper()
        if got != want:
            shown = (lambda v: f"0x{v:X}" if isinstance(v, int) else repr(v)) if key == "base" else repr
            raise CalibrationFileError(
                p, f"{where} {key} = {shown(got)} but the rig's {name} has {key} {shown(want)}: this calibration is "
                   "for another board; re-calibrate the board")
    channels = board_channels(ident.type)
    if channels is None:
        raise CalibrationFileError(p, f"{where}: boards of type {ident.type!r} carry no per-channel calibration")
    id_reg = board_id_register(ident.type)
    if entry.get("board_id") != ident.board_id:
        expected = "no board_id (the type has no ID register)" if id_reg is None else f"0x{id_reg.reset:04X}"
        raise CalibrationFileError(
            p, f"{where} board_id = {entry.get('board_id')!r}, expected {expected} for a {ident.type}")
    if bus is not None and id_reg is not None:
        read = bus.read(ident.base + id_reg.offset, space=ident.space, width=id_reg.width)
        if read != id_reg.reset:
            raise CalibrationFileError(
                p, f"{where}: the board at 0x{ident.base:X} answers ID 0x{read:04X}, not 0x{id_reg.reset:04X}")
    meta = _meta(p, f"board.{name}", entry)
    coeffs = {k: entry[k] for k in _BOARD_COEFF_KEYS if k in entry}
    try:
        cal = Calibration.from_dict(coeffs, channels=channels)
    except CalibrationError as e:
        raise CalibrationFileError(p, f"{where}: {e}") from None
    for ch, (off, gain) in enumerate(zip(cal.offset_v, cal.gain, strict=True)):
        _number(p, f"board.{name}", f"gain[{ch}]", gain, *BOARD_GAIN_RANGE)
        _number(p, f"board.{name}", f"offset_v[{ch}]", off, 0.0, BOARD_OFFSET_LIMIT_V, absolute=True)
    measured = entry.get("measured", [])
    if not isinstance(measured, list) or not all(isinstance(c, int) for c in measured):
        raise CalibrationFileError(p, f"{where} measured must be a list of channel numbers")
    extra = {k: v for k, v in entry.items()
             if k not in _BOARD_COEFF_KEYS | _META_KEYS | {"type", "base", "space", "board_id", "measured"}}
    return BoardCal(ident, cal, meta[0], meta[1], meta[2], tuple(measured), extra)
