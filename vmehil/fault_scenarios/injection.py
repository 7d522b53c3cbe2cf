"""Named faults of a run: the catalogue behind ``vmehil run --fault`` / ``--faults`` and the fault
matrix (docs/faults.md, "Fault injection").

A fault of the catalogue (:data:`CATALOGUE`) names *what* fails in the rig's terms — a joint's
pot, a joint's amplifier enable line, a board, the CAN link — and maps it, through the rig's
wiring, to *which* emulator part and pin gets which of its named faults
(:class:`emulators.faults.FaultInjectable`): ``pot_frozen:joint=j1`` is the plant's
``pot_frozen`` fault of joint j1, ``enable_stuck_low:joint=j2`` the PIO board's ``line_stuck``
on the pin j2's ``amp_enable`` is wired to.

:func:`parse_fault_spec` reads ``NAME[@T][:key=value,...]``; :func:`load_scenario` a TOML file::

    [[fault]]
    name = "pot_frozen"
    at_s = 0.8                 # simulated time (default 0)
    params = { joint = "j1" }

:class:`FaultSchedule` injects each fault at the start of the first tick at or after its time
(plant-side sensor faults show from the next sensor sample on: the one of that tick was taken
before) and :func:`stop_report` says how the run ended: the stop's cause, ticks after the first
fault, the true error (|target − true angle|) at the stop.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hal.board_types import board_role
from hal.config import ConfigError, load_toml
from servo.rig import RigSpec, crate_boards
from vmehil.errors import CliError, VmehilError

_REQUIRED = object()


@dataclass(frozen=True)
class Param:
    """One parameter of a catalogue fault."""

    name: str
    kind: type
    default: Any
    help: str
    minimum: float | None = None  #: the smallest value that means something (a count, an rms)
    maximum: float | None = None

    @property
    def required(self) -> bool:
        return self.default is _REQUIRED

    def usage(self) -> str:
        if self.required:
            return f"{self.name}=… (required)"
        return f"{self.name}={self.default!r}" if isinstance(self.default, str) else f"{self.name}={self.default:g}"


@dataclass(frozen=True)
class Injection:
    """A catalogue fault resolved on a built rig: the emulator part, its fault and parameters."""

    target: Any  # an emulators.faults.FaultInjectable
    fault: str
    params: dict[str, Any]
    where: str  #: e.g. "plant j1", "pio0:PA0", "dac0:0"


@dataclass
class FaultContext:
    """What a fault may be injected into: the built rig, its loop, and the run's seed."""

    system: Any  # vmehil.rig_setup.system.EmulatedRig
    loop: Any  # servo.loop.ServoLoop
    seed: int = 0

    @property
    def rig(self) -> RigSpec:
        return self.system.rig

    def plant(self, what: str) -> Any:
        """The plant: in this process, or in a plant node thread of this process."""
        if self.system.plant is not None:
            return self.system.plant
        node = self.can_node(what)
        return node.plant

    def can_link(self, what: str) -> Any:
        link = self.system.link
        if not hasattr(link, "ep"):
            raise CliError(f"{what} needs the plant over CAN (--plant can)")
        return link

    def can_node(self, what: str) -> Any:
        runner = getattr(self.can_link(what), "node", None)
        if runner is None:
            raise CliError(f"{what} needs the plant node in this process; this run talks to an external "
                             "`vmehil plant-node` (stop that process to see the loop's answer to a dead node, or leave "
                             "--interface out: on virtual the node runs in this process)")
        return runner.node

    def board_of_type(self, kind: str, what: str) -> Any:
        # a role names every board type of it (the vision link: "bit3" and "sbs617")
        boards = crate_boards(self.rig, kind)
        if not boards:
            raise CliError(f"{what}: rig {self.rig.name} has no {kind} board")
        return self.system.crate.board(boards[0].get_str("name"))

    def joint(self, joint: str, what: str):
        names = [j.name for j in self.rig.joints]
        if joint not in names:
            raise CliError(f"{what}: rig {self.rig.name} has no joint {joint!r} (joints: {', '.join(names)})")
        return self.rig.joints[names.index(joint)]

    def pin(self, joint: str, signal: str, what: str):
        j = self.joint(joint, what)
        if signal not in j.wiring:
            raise CliError(f"{what}: joint {joint} has no {signal} wired")
        return j.wiring[signal]


Resolver = Callable[[FaultContext, "FaultType", dict[str, Any]], Injection]


@dataclass(frozen=True)
class FaultType:
    """A fault of the catalogue: what fails (``part``), and how it is found on a built rig
    (``resolve``): the emulator part, which of its named faults (``emulator_fault``) and the
    parameters; ``signal`` is the joint's wiring signal it needs (checked before the run)."""

    name: str
    part: str
    description: str
    params: tuple[Param, ...]
    resolve: Resolver
    emulator_fault: str
    signal: str | None = None
    fixed: tuple[tuple[str, Any], ...] = ()  #: emulator parameters the fault always has
    needs: str = ""  #: the run option it needs ("--plant can", "--vision inprocess"), for the listing
    #: the crate board type the fault acts on (checked against the rig before anything is built);
    #: None: not a board's fault, or any board (board_removed)
    board_type: str | None = None

    def param(self, name: str) -> Param | None:
        return next((p for p in self.params if p.name == name), None)

    def injection(self, target: Any, params: dict[str, Any], where: str) -> Injection:
        return Injection(target, self.emulator_fault, {**params, **dict(self.fixed)}, where)


def _joint(help: str = "the joint (its name in the rig)") -> Param:
    return Param("joint", str, _REQUIRED, help)


def _on_plant(ctx: FaultContext, kind: FaultType, p: dict[str, Any]) -> Injection:
    """A joint's sensor or amplifier fault on the plant side (``joint`` names it to the plant)."""
    if kind.signal:
        ctx.pin(p["joint"], kind.signal, kind.name)
    else:
        ctx.joint(p["joint"], kind.name)
    return kind.injection(ctx.plant(kind.name), dict(p), f"plant {p['joint']}")


def on_the_plant(kind: FaultType) -> bool:
    """Whether ``kind`` strikes the plant (its sensors and amplifiers as the plant models them),
    not a board of the crate: a unit controller, which has its boards only, cannot take it."""
    return kind.resolve is _on_plant


def _tach_rail(ctx: FaultContext, kind: FaultType, p: dict[str, Any]) -> Injection:
    volts = math.copysign(10.0, float(p["sign"]))  # the ADC's full scale: shorted to a supply rail
    return _on_plant(ctx, kind, {"joint": p["joint"], "volts": volts})


def _on_pin(ctx: FaultContext, kind: FaultType, p: dict[str, Any]) -> Injection:
    """A fault of the board pin the joint's ``signal`` is wired to (channel or PIO line)."""
    assert kind.signal is not None
    pin = ctx.pin(p["joint"], kind.signal, kind.name)
    key = "line" if isinstance(pin.channel, str) else "channel"
    extra = {k: v for k, v in p.items() if k != "joint"}
    return kind.injection(ctx.system.crate.board(pin.board), {key: pin.channel, **extra}, str(pin))


def _adc_noise(ctx: FaultContext, kind: FaultType, p: dict[str, Any]) -> Injection:
    if p["board"]:
        return kind.injection(ctx.system.crate.board(p["board"]), {"rms_v": p["rms_v"]}, f"{p['board']} (all channels)")
    if not p["joint"]:
        raise CliError("adc_noise: give joint=… (with signal=pot|tach|imon) or board=…")
    pin = ctx.pin(p["joint"], p["signal"], kind.name)
    return kind.injection(ctx.system.crate.board(pin.board), {"rms_v": p["rms_v"], "channels": [pin.index]}, str(pin))


def _on_board(ctx: FaultContext, kind: FaultType, p: dict[str, Any]) -> Injection:
    return kind.injection(ctx.system.crate.board(p["board"]), {}, p["board"])


def _on_can_endpoint(ctx: FaultContext, kind: FaultType, p: dict[str, Any]) -> Injection:
    return kind.injection(ctx.can_link(kind.name).ep, {**p, "seed": ctx.seed}, "controller CAN endpoint")


def _on_can_node(ctx: FaultContext, kind: FaultType, p: dict[str, Any]) -> Injection:
    return kind.injection(ctx.can_node(kind.name), {}, "plant node")


def _on_bit3(ctx: FaultContext, kind: FaultType, p: dict[str, Any]) -> Injection:
    board = ctx.board_of_type("bit3", kind.name)
    return kind.injection(board, {}, board.name)


def _on_vision(ctx: FaultContext, kind: FaultType, p: dict[str, Any]) -> Injection:
    vision = getattr(getattr(ctx.loop, "vision", None), "vision", None)
    if vision is None:
        raise CliError(f"{kind.name} needs the vision system in this process (--vision inprocess)")
    return kind.injection(vision, {}, "vision system")


_VOLTS_HELD = "the volts held (default: where the wiper is when the fault strikes)"
_POT, _TACH = "plant: a joint's potentiometer", "plant: a joint's tachometer"
_ENABLE, _ENCODER = "PIO board: a joint's amplifier enable", "decoder board: a joint's encoder"
#: the latest a fault may be scheduled (s of simulated time: a day, as `--duration`'s bound)
MAX_FAULT_TIME_S = 86400.0

CATALOGUE: dict[str, FaultType] = {f.name: f for f in (
    FaultType("pot_open", _POT, "the wiper lifts off the element; the floating ADC input goes to the rail",
              (_joint(), Param("volts", float, 10.0, "where the input floats to")), _on_plant, "pot_open", "pot"),
    FaultType("pot_frozen", _POT, "the pot's shaft coupling slips: the reading stays while the joint moves",
              (_joint(), Param("volts", float, math.nan, _VOLTS_HELD)), _on_plant, "pot_frozen", "pot"),
    FaultType("tach_stuck", _TACH, "the tach output is held (open lead, lifted brushes)",
              (_joint(), Param("volts", float, 0.0, "the volts held")), _on_plant, "tach_stuck", "tach"),
    FaultType("tach_rail", _TACH, "the tach output is shorted to a supply rail (±10 V at the ADC)",
              (_joint(), Param("sign", float, 1.0, "+1 or −1: which rail")), _tach_rail, "tach_stuck", "tach"),
    FaultType("adc_noise", "ADC board", "a burst of extra Gaussian noise on one joint's input or a whole board",
              (Param("joint", str, "", "the joint (or board=…)"), Param("signal", str, "pot", "pot, tach or imon"),
               Param("board", str, "", "a whole ADC board instead of one input"),
               Param("rms_v", float, 0.05, "extra noise, V rms", minimum=0.0)), _adc_noise, "noise_burst",
              board_type="adc"),
    FaultType("dac_dead", "DAC board: a joint's amplifier command", "the output channel is stuck whatever is "
              "written", (_joint(), Param("volts", float, 0.0, "the volts it is stuck at")), _on_pin,
              "dead_channel", "amp_command", board_type="dac"),
    FaultType("enable_stuck_low", _ENABLE, "the enable pin is held low (amplifier off)", (_joint(),), _on_pin,
              "line_stuck", "amp_enable", (("level", False),), board_type="pio"),
    FaultType("enable_stuck_high", _ENABLE, "the enable pin is held high (the safe stop cannot disable the "
              "amplifier)", (_joint(),), _on_pin, "line_stuck", "amp_enable", (("level", True),), board_type="pio"),
    FaultType("amp_fault", "plant: a joint's amplifier", "the amplifier trips (output off, fault line asserted)",
              (_joint(),), _on_plant, "amp_fault"),
    FaultType("amp_fault_line", "PIO board: a joint's amplifier fault input", "the fault input pin is held "
              "asserted (the amplifier itself is fine)", (_joint(),), _on_pin, "line_stuck", "amp_fault",
              (("level", True),), board_type="pio"),
    FaultType("encoder_missed", _ENCODER, "the next N counts are lost",
              (_joint(), Param("counts", int, 1_000_000, "counts lost", minimum=0)), _on_pin, "missed_counts",
              "encoder", board_type="quad"),
    FaultType("encoder_glitch", _ENCODER, "noise edges: extra counts and illegal transitions",
              (_joint(), Param("counts", int, 200, "extra counts per interval", minimum=0),
               Param("illegal", int, 1, "illegal transitions per interval", minimum=0),
               Param("intervals", int, 1, "servo periods it lasts", minimum=1)), _on_pin, "glitch", "encoder",
              board_type="quad"),
    FaultType("board_removed", "a VME board", "the board is pulled from the crate: every access ends in BERR",
              (Param("board", str, _REQUIRED, "the board's name in [crate]"),), _on_board, "removed"),
    FaultType("can_frame_loss", "CAN bus (controller side)", "a percentage of the frames is lost",
              (Param("percent", float, 10.0, "frames lost, %", minimum=0.0, maximum=100.0),
               Param("direction", str, "both", "both, rx or tx")),
              _on_can_endpoint, "frame_loss", needs="--plant can"),
    FaultType("can_frame_delay", "CAN bus (controller side)", "a percentage of the received frames arrives late",
              (Param("ms", float, 20.0, "delay, ms of wall time", minimum=0.0),
               Param("percent", float, 100.0, "frames delayed, %", minimum=0.0, maximum=100.0)),
              _on_can_endpoint, "frame_delay", needs="--plant can"),
    FaultType("can_node_death", "CAN plant node", "the plant node dies: no answers, no heartbeats", (),
              _on_can_node, "dead", needs="--plant can, the node in this process"),
    FaultType("bit3_link_down", "BIT3 card", "the BIT3 cable is unplugged: window cycles end in BERR", (),
              _on_bit3, "link_down", needs="--vision to matter"),
    FaultType("vision_death", "vision system", "the vision process dies: no heartbeat, no commands", (),
              _on_vision, "dead", needs="--vision inprocess"),
)}


# --- a scheduled fault --------------------------------------------------------------------------
@dataclass
class ScheduledFault:
    """One fault of a scenario: its catalogue type, time and parameters (defaults filled in)."""

    kind: FaultType
    at_s: float
    params: dict[str, Any]
    source: str  #: where it was given (the --fault text, or "file.toml: fault[2]")
    injection: Injection | None = None
    tick: int | None = None

    def as_dict(self) -> dict[str, Any]:
        params = {k: v for k, v in self.params.items() if not (isinstance(v, float) and math.isnan(v)) and v != ""}
        out: dict[str, Any] = {"name": self.kind.name, "at_s": self.at_s, "params": params, "source": self.source}
        if self.injection is not None:
            out.update(tick=self.tick, target=self.injection.where, emulator_fault=self.injection.fault)
        return out


class FaultSpecError(VmehilError, ValueError):
    """A fault given wrongly: ``key`` is ``name``, ``at_s`` or the parameter concerned."""

    def __init__(self, source: str, key: str, expected: str, got: Any = None) -> None:
        self.key, self.expected, self.got = key, expected, got
        super().__init__(f"{source}: {key}: expected {expected}" + ("" if got is None else f", got {got!r}"))


def _coerce(kind: FaultType, key: str, value: Any, where: str) -> Any:
    p = kind.param(key)
    if p is None:
        known = ", ".join(q.name for q in kind.params) or "none"
        raise FaultSpecError(where, key, f"a parameter of {kind.name} (its parameters: {known})", key)
    if p.kind is str:
        return str(value)
    number = "an integer" if p.kind is int else "a finite number"
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or (
            p.kind is int and float(value) != int(value)):
        raise FaultSpecError(where, key, number, value)
    if (p.minimum is not None and value < p.minimum) or (p.maximum is not None and value > p.maximum):
        bounds = (f">= {p.minimum:g}" if p.maximum is None else f"in [{p.minimum:g}, {p.maximum:g}]"
                  if p.minimum is not None else f"<= {p.maximum:g}")
        raise FaultSpecError(where, key, f"{number} {bounds}", value)
    return p.kind(value)


def make_fault(name: str, at_s: float, params: Mapping[str, Any], source: str) -> ScheduledFault:
    """A :class:`ScheduledFault` from a name, a time and raw parameters (checked, defaults filled)."""
    kind = CATALOGUE.get(name)
    if kind is None:
        raise FaultSpecError(source, "name", "a fault of `vmehil run --fault list`", name)
    if not math.isfinite(at_s) or not 0 <= at_s <= MAX_FAULT_TIME_S:
        raise FaultSpecError(source, "at_s", f"a time in seconds in [0, {MAX_FAULT_TIME_S:g}]", at_s)
    values = {k: _coerce(kind, k, v, source) for k, v in params.items()}
    for p in kind.params:
        if p.name not in values:
            if p.required:
                raise FaultSpecError(source, p.name, f"a value ({kind.name} needs {p.name}: {p.help})")
            values[p.name] = p.default
    return ScheduledFault(kind, float(at_s), values, source)


def _scalar(text: str) -> Any:
    t = text.strip()
    for conv in (int, float):
        try:
            return conv(t)
        except ValueError:
            pass
    return t


def parse_fault_spec(text: str) -> ScheduledFault:
    """``NAME[@T][:key=value,...]`` (T in seconds of simulated time, default 0)."""
    where = f"--fault {text}"
    head, _, rest = text.partition(":")
    name, at, t = head.partition("@")
    at_s = 0.0
    if at:
        try:
            at_s = float(t)
        except ValueError:
            raise FaultSpecError(where, "@T", "seconds of simulated time", t) from None
    params: dict[str, Any] = {}
    for part in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = part.partition("=")
        if not eq or not key.strip():
            raise FaultSpecError(where, "parameters", "key=value", part)
        if key.strip() in params:  # joint=j1,joint=j2: which one was meant?
            raise FaultSpecError(where, key.strip(), "one value (the key is given twice)", value)
        params[key.strip()] = _scalar(value)
    return make_fault(name.strip(), at_s, params, where)


def load_scenario(path: str | Path) -> list[ScheduledFault]:
    """A TOML scenario file: ``[[fault]]`` tables with ``name``, ``at_s`` (default 0), ``params``.
    Errors name the file and the key."""
    table = load_toml(path)
    faults = []
    for ft in table.tables("fault", []):
        name = ft.get_str("name")
        at_s = ft.get_float("at_s", 0.0, min=0.0)
        params = ft.table("params", {})
        ft.check_unknown({"name", "at_s", "params"})
        try:
            faults.append(make_fault(name, at_s, params.data, f"{table.source}: {ft.prefix}"))
        except FaultSpecError as e:
            key = ft.key(e.key) if e.key in ("name", "at_s") else params.key(e.key)
            raise ConfigError(table.source, key, e.expected, e.got) from None
    if not faults:
        raise ConfigError(table.source, "fault", "at least one [[fault]] table")
    return faults


def check_rig(faults: list[ScheduledFault], rig: RigSpec) -> None:
    """Refuse joints, signals and boards the rig does not have, and a fault on a board of another
    type (``adc_noise`` on a decoder's encoder, on a DAC board), before anything is built (it was
    found at injection, after the rig was armed)."""
    joints = [j.name for j in rig.joints]
    types = {b.get_str("name"): b.get_str("type") for b in rig.table.table("crate", {}).tables("board", [])}
    for f in faults:
        joint, board = f.params.get("joint"), f.params.get("board")
        if joint and joint not in joints:
            raise CliError(f"{f.source}: rig {rig.name} has no joint {joint!r} (joints: {', '.join(joints)})")
        signal = f.kind.signal or (f.params.get("signal") if joint else None)
        if joint and signal and signal not in rig.joints[joints.index(joint)].wiring:
            raise CliError(f"{f.source}: joint {joint} of rig {rig.name} has no {signal} wired")
        if board and board not in types:
            raise CliError(f"{f.source}: rig {rig.name} has no board {board!r} (boards: {', '.join(types)})")
        target = board or (rig.joints[joints.index(joint)].wiring[signal].board if joint and signal else None)
        # by role (hal.board_types): a VMIVME-2536 takes the PIO's line faults as the reference PIO does
        if f.kind.board_type is not None and target is not None and \
                board_role(types.get(target, "")) != f.kind.board_type:
            what = f"{joint}'s {signal} is on" if not board else "it names"
            raise CliError(f"{f.source}: {f.kind.name} acts on a board of type {f.kind.board_type!r}; {what} "
                           f"{target} (type {types.get(target)!r})")


# --- the schedule ------------------------------------------------------------------------------
@dataclass
class FaultSchedule:
    """Injects a scenario's faults into a built rig at their ticks (see the module docstring)."""

    faults: list[ScheduledFault]
    context: FaultContext
    pending: list[ScheduledFault] = field(default_factory=list)

    def __post_init__(self) -> None:
        rate = self.context.rig.servo_rate_hz
        for f in self.faults:
            f.tick = math.ceil(round(f.at_s * rate, 9))
            f.injection = f.kind.resolve(self.context, f.kind, f.params)  # resolve all first: errors before the run
        self.pending = sorted(self.faults, key=lambda f: f.tick or 0)

    def attach(self, runner: Any) -> None:
        """Inject what is due at tick 0 now and the rest from the runner's after-tick hook."""
        self._inject_due(self.context.loop.tick_count)
        runner.after_tick.append(lambda loop: self._inject_due(loop.tick_count))

    def _inject_due(self, tick: int) -> None:
        while self.pending and (self.pending[0].tick or 0) <= tick:
            f = self.pending.pop(0)
            inj = f.injection
            assert inj is not None
            inj.target.inject(inj.fault, **{k: v for k, v in inj.params.items()
                                            if not (isinstance(v, float) and math.isnan(v))})
            self.context.loop.note("fault", f"injected {f.kind.name} ({inj.where})")

    @property
    def first_tick(self) -> int | None:
        return first_tick(self.faults)

    @property
    def joint(self) -> str | None:
        """The joint the first joint fault names (where its true error is measured), if any."""
        return first_joint(self.faults)


def first_tick(faults: list[ScheduledFault]) -> int | None:
    """The tick of the earliest scheduled fault (None: none scheduled yet)."""
    return min((f.tick for f in faults if f.tick is not None), default=None)


def first_joint(faults: list[ScheduledFault]) -> str | None:
    """The joint the first joint fault names (where its true error is measured), if any."""
    return next((f.params["joint"] for f in faults if f.params.get("joint")), None)


def announcement(f: ScheduledFault) -> str:
    """The line a run prints for a scheduled fault: what, when, and where it strikes."""
    inj = f.injection
    return f"fault: {f.kind.name} at {f.at_s:g} s (tick {f.tick}) → {inj.where if inj else '?'}"


def stop_report(loop: Any, first_tick: int | None, joint: str | None = None) -> dict[str, Any]:
    """How the run ended: the stop (or none), ticks after the first fault, and the true error
    |θd − θ_true| (degrees) of ``joint`` (default: the stopped joint, else the worst) at the stop
    (``true_error_deg``) and at worst between the first fault and the stop or the end of the run
    (``max_true_error_deg``). After a stop the joints coast (gravity joints sag: the plant has no
    brakes), so the figures end at the stop. A figure that is not known (no target yet: a fault at
    tick 0 stops before the first one) is left out, never NaN."""
    rec = loop.recorder.trimmed() if loop.recorder is not None else {}
    fault = loop.fault
    out: dict[str, Any] = {"stopped": fault is not None}
    if fault is not None:
        out.update(fault.as_dict())
        out["ticks_after_fault"] = None if first_tick is None else fault.tick - first_tick
    if not rec or rec["t"].size == 0:
        return out
    theta_d = rec["theta_d"].copy()
    for k in range(1, theta_d.shape[0]):  # the stop tick may have no target: the last one holds
        theta_d[k] = np.where(np.isnan(theta_d[k]), theta_d[k - 1], theta_d[k])
    err = np.degrees(np.abs(theta_d - rec["theta_true"]))
    k0 = first_tick or 0
    k1 = min(fault.tick if fault is not None else err.shape[0] - 1, err.shape[0] - 1)
    if k0 > k1:
        return out
    window = err[k0:k1 + 1]
    known = np.isfinite(window)
    name = joint or (fault.joint if fault is not None else None)
    if name in loop.names:
        i: int | None = loop.names.index(name)
    elif known.any():  # the worst joint among those with a known error
        i = int(np.argmax(np.where(known, window, -np.inf).max(axis=0)))
    else:  # no joint's error is known (a fault at tick 0 stops before the first target)
        i = None
    if i is not None and known[:, i].any():
        out["error_joint"] = loop.names[i]
        if fault is not None and np.isfinite(err[k1, i]):
            out["true_error_deg"] = float(err[k1, i])
        out["max_true_error_deg"] = float(window[known[:, i], i].max())
    # how far the arm really went from where it was when the fault struck, to the stop (or the
    # end): the largest true movement of any joint — what a fault costs, free of the pot's bow
    # that the error against the target carries (≈ 1° uncalibrated)
    moved = np.degrees(np.abs(rec["theta_true"][k0:k1 + 1] - rec["theta_true"][k0]))
    seen = np.isfinite(moved)
    if seen.any():
        worst = int(np.argmax(np.where(seen, moved, -np.inf).max(axis=0)))
        out["movement_joint"] = loop.names[worst]
        out["true_movement_deg"] = float(moved[seen[:, worst], worst].max())
    return out


def catalogue_text() -> str:
    """``vmehil run --fault list``: every fault with its description and parameters."""
    lines = ["faults (vmehil run --fault NAME[@T][:key=value,...], T in s of simulated time):", ""]
    for f in CATALOGUE.values():
        needs = f"  [needs {f.needs}]" if f.needs else ""
        lines.append(f"{f.name}  —  {f.part}: {f.description}{needs}")
        for p in f.params:
            lines.append(f"    {p.usage():28s} {p.help}")
    return "\n".join(lines)
