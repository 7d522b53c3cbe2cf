"""Rig files: the crate, the plant, the wiring and the servo settings of one robot.

A rig file is TOML with these top-level tables (presets: ``emulators/presets/*.toml``)::

    [rig]        name, description, servo_rate_hz (125), computation_delay_s (0..1 period)
    [crate]      boards (see emulators.crate_file)
    [plant]      plant-wide settings (see docs/plant.md)
    [[joint]]    one per joint: name, amplifier ("linear" | "hbridge"), plant subtables,
                 [joint.wiring] and [joint.servo]

``[joint.wiring]`` names board pins as ``"board:channel"`` (ADC/DAC/decoder channel numbers)
or ``"board:PA0"`` (PIO lines)::

    amp_command = "dac0:0"   amp_enable = "pio0:PA0"   amp_fault = "pio0:PB0"
    amp_reset = "pio0:PC0"   pot = "adc0:0"            tach = "adc0:8"
    imon = "adc1:0"          encoder = "quad0:0"
    pwm = "pio0:PWM"         direction = "pio0:PA6"    brake = "pio0:PA7"   # H-bridge joints
    holding_brake = "pio1:PA0"                         # a spring-applied holding brake's line

``brake`` is an H-bridge's dynamic brake (the winding shorted); ``holding_brake`` the line of a
spring-applied, power-released holding brake on the joint (energised = released, low = holding):
the drivers raise it only once the enabled amplifier carries the joint's load and drop it with
the enables on every stop (:class:`servo.io.JointIO`).

Each wired signal becomes the net ``<joint>.<signal>`` between the boards and the plant.

Rig-level calibration wiring (used by ``vmehil calibrate adc|dac``)::

    [rig.references]           # precision reference voltages wired to ADC inputs (pin = volts)
    "adc1:12" = 5.000
    "adc1:13" = 0.0
    [rig.loopback]             # DAC outputs wired back into ADC inputs (DAC pin = ADC pin)
    "dac0:6" = "adc1:14"
    "dac0:7" = "adc1:15"

Reference pins carry the net ``ref.<board>.<channel>``, loopback pairs the net
``loop.<dac board>.<channel>`` (see :func:`reference_net`, :func:`loopback_net`).

Rig-level amplifier enable watchdog (optional; without it the amplifiers have none)::

    [rig.watchdog]
    line = "pio0:PB7"          # a free PIO line: the charge pump the drivers toggle every tick
    timeout_s = 0.05           # the amplifiers drop their enables this long after its last edge

One line serves every amplifier of the rig (it feeds their common enable chain, as one charge
pump does on a real rack), so keeping it alive costs one PIO write per tick however many
joints and PIO boards there are. The line carries the net ``rig.watchdog``
(:data:`WATCHDOG_NET`); ``timeout_s`` is the amplifiers' (read by the plant too) and must
exceed one servo period.

Rig-level digital read-back (optional; for a PIO board that cannot read its outputs' wires, the
VMIVME-2536: docs/boards/vmivme2536.md)::

    [rig.readback]             # an output line wired back into a free input of the same board
    "dio0:OUT0" = "dio0:IN16"

The input then carries the output's net, and the board's driver (``loopback=``) reads the wire
there: a stop's read-back of a stuck-high enable sees it high.

``[joint.servo]``: ``position = "pot" | "encoder"``, ``velocity = "tach" | "encoder"``,
``gains = {kp, kpi, kv, kvi}``, ``switch_off = {...}``, ``max_velocity_deg_s``,
``torque_limit_nm`` (default: the nominal current limit · Kt · N), ``following_error_limit_deg``,
``controller = {objects = [...]}``.

``[joint.limits]``: the joint's soft limits, ``min_deg`` / ``max_deg`` (:mod:`servo.settings`).

``[joint.servo.nominal]``: the controller's own datasheet/nominal figures of the joint — sensor
gradients and zeros, encoder counts per joint revolution, gear ratio, Kt, amplifier gain, current
monitor and limit, H-bridge supply/R/Ke/PWM period, inertia at the joint (SI; the keys and which
ones a joint must give: :mod:`servo.nominal`). The drivers' sensor scaling, the normalizing chain
and the default torque limit come from these alone, never from the plant subtables: a study may
perturb the plant and the controller does not learn of it.

The plant reads the same ``[[joint]]`` tables and is told which keys are the servo side's
(:data:`SERVO_JOINT_KEYS`) rather than knowing them.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from pathlib import Path

from hal.board_types import BOARD_TYPES, board_role
from hal.config import ConfigError, ConfigTable, load_toml
from hal.pio.pio_regs import ALL_LINES
from servo.errors import ServoError

ANALOG_INPUTS = ("pot", "tach", "imon")
DIGITAL_OUTPUTS = ("amp_enable", "amp_reset", "direction", "brake", "holding_brake")
DIGITAL_INPUTS = ("amp_fault", "tactile_left", "tactile_right")  # tactile: the hand's finger switches (docs/hand.md)
WIRING_KEYS = ("amp_command", "encoder", "pwm", *ANALOG_INPUTS, *DIGITAL_OUTPUTS, *DIGITAL_INPUTS)
#: The keys of a ``[[joint]]`` table that only the servo side reads (``name`` and ``amplifier`` are
#: shared with the plant, whose subtables sit beside these).
SERVO_JOINT_KEYS = ("wiring", "servo", "limits", "controller")


class NoSuchJointError(ServoError, ValueError):
    """A joint number the rig does not have (``--joint 9`` on a 7-joint rig): bad input."""


@dataclass(frozen=True)
class Pin:
    """A board pin: board name and channel number or line name (``"PA0"``, ``"PWM"``)."""

    board: str
    channel: int | str

    @property
    def index(self) -> int:
        if not isinstance(self.channel, int):
            raise TypeError(f"{self.board}:{self.channel} is a line, not a channel number")
        return self.channel

    def __str__(self) -> str:
        return f"{self.board}:{self.channel}"


@dataclass
class JointSpec:
    """One joint of a rig (the plant parameters stay in ``table`` for the plant to read)."""

    index: int
    name: str
    amplifier: str
    wiring: dict[str, Pin]
    servo: ConfigTable
    table: ConfigTable

    def net(self, signal: str) -> str:
        """The net name that carries ``signal`` of this joint (``"j1.pot"``)."""
        return f"{self.name}.{signal}"


@dataclass(frozen=True)
class WatchdogSpec:
    """The amplifiers' enable watchdog: the PIO line the drivers toggle and its timeout (s)."""

    line: Pin
    timeout_s: float


WATCHDOG_NET = "rig.watchdog"  #: the net of the watchdog line


@dataclass
class RigSpec:
    """A parsed rig file."""

    name: str
    path: Path
    table: ConfigTable
    servo_rate_hz: float
    computation_delay_s: float
    joints: list[JointSpec] = field(default_factory=list)
    description: str = ""
    references: dict[Pin, float] = field(default_factory=dict)  #: ADC pin → reference volts
    loopback: dict[Pin, Pin] = field(default_factory=dict)  #: DAC pin → ADC pin it is wired to
    watchdog: WatchdogSpec | None = None  #: the amplifiers' enable watchdog (None: not wired)
    readback: dict[Pin, Pin] = field(default_factory=dict)  #: PIO output line → input it is wired back to

    @property
    def period_s(self) -> float:
        return 1.0 / self.servo_rate_hz

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    def joint(self, number: int) -> JointSpec:
        """Joint by 1-based number, as the papers number links."""
        if not 1 <= number <= len(self.joints):
            raise NoSuchJointError(f"rig {self.name} has joints 1..{len(self.joints)}; there is no joint {number}")
        return self.joints[number - 1]


def parse_pin(cfg: ConfigTable, key: str) -> Pin:
    text = cfg.get_str(key)
    board, sep, chan = text.partition(":")
    if not sep or not board or not chan:
        raise cfg.error(key, 'a pin "board:channel" such as "adc0:3" or "pio0:PA0"', text)
    return Pin(board, int(chan) if chan.isdigit() else chan.upper())


def load_rig(path: str | Path) -> RigSpec:
    """Parse a rig file (a preset path from :func:`emulators.presets.resolve_rig` or any path)."""
    return rig_from_table(load_toml(path), path)


def rig_from_table(table: ConfigTable, path: str | Path) -> RigSpec:
    """Parse a rig file's table already read (``path``: where it came from; errors name it).
    A unit controller parses its unit's part of the rig file this way (:mod:`servo.joint_groups`)."""
    rig = table.table("rig", {})
    period_hz = rig.get_float("servo_rate_hz", 125.0, min=1.0, max=10_000.0)
    delay = rig.get_float("computation_delay_s", 0.001, min=0.0)
    if delay > 1.0 / period_hz:
        raise rig.error("computation_delay_s", f"a delay of at most one servo period ({1 / period_hz} s)", delay)
    spec = RigSpec(
        name=rig.get_str("name", Path(path).stem),
        path=Path(path),
        table=table,
        servo_rate_hz=period_hz,
        computation_delay_s=delay,
        description=rig.get_str("description", ""),
    )
    names: set[str] = set()
    for i, jt in enumerate(table.tables("joint", [])):
        name = jt.get_str("name")
        if name in names:
            raise jt.error("name", "a joint name not used before", name)
        names.add(name)
        amp = jt.get_str("amplifier", "linear", choices=("linear", "hbridge"))
        wt = jt.table("wiring", {})
        wiring = {k: parse_pin(wt, k) for k in wt.keys() if k in WIRING_KEYS}
        for k in wt.keys():
            if k not in WIRING_KEYS:
                raise wt.error(k, "a wiring key (" + ", ".join(WIRING_KEYS) + ")", "unknown key")
        if amp == "linear" and "amp_command" not in wiring:
            raise wt.error("amp_command", 'the DAC pin driving the amplifier (e.g. "dac0:0")')
        servo = jt.table("servo", {})
        spec.joints.append(JointSpec(i, name, amp, wiring, servo, jt))
    if not spec.joints:
        raise ConfigError(str(path), "joint", "at least one [[joint]] table")
    _check_boards(table)
    _check_wiring(spec)
    _parse_calibration_wiring(spec, rig)
    spec.watchdog = _parse_watchdog(spec, rig)
    spec.readback = _parse_readback(spec, rig)
    return spec


# --- wiring checks: refuse a rig that would move the wrong joint, before anything moves ----------
#: which board role (hal.board_types) each wired signal must be on, and how its pin is named
_SIGNAL_BOARD = {"amp_command": "dac", "pot": "adc", "tach": "adc", "imon": "adc", "encoder": "quad",
                 "pwm": "pio", **{k: "pio" for k in (*DIGITAL_OUTPUTS, *DIGITAL_INPUTS)}}
#: the roles whose pins are numbered channels (the count is the board type's driver's ``CHANNELS``)
_CHANNEL_ROLES = ("adc", "dac", "quad")


def _board_roles(table: ConfigTable) -> dict[str, str | None]:
    """``[crate]``'s boards: name → role of its type (None: a type the driver side does not know)."""
    return {b.get_str("name"): board_role(b.get_str("type")) for b in table.table("crate", {}).tables("board", [])}


def crate_boards(rig: RigSpec, kind: str) -> list[ConfigTable]:
    """``[crate]``'s boards of role ``kind`` (hal.board_types: the vision link ``"bit3"`` is the
    reference card and the SBS 617) or of type ``kind`` exactly, in the file's order: the one way
    to find a rig's board by role."""
    return [b for b in rig.table.table("crate", {}).tables("board", [])
            if b.get_str("type") == kind or board_role(b.get_str("type")) == kind]


def _pio_lines(type_name: str) -> tuple[str, ...]:
    """The pin names of a board of role ``pio``: its driver's ``LINES`` (the reference PIO's
    PA0..PC7 when it declares none)."""
    lines = getattr(BOARD_TYPES[type_name].load_driver(), "LINES", ALL_LINES)
    return tuple(lines)


def _pio_lines_text(type_name: str) -> str:
    """What a wiring error expects of a line of this board (the reference PIO's text as shipped)."""
    lines = _pio_lines(type_name)
    if lines == tuple(ALL_LINES):
        return "a PIO line PA0..PC7"
    groups: dict[str, list[str]] = {}
    for name in lines:
        groups.setdefault(name.rstrip("0123456789"), []).append(name)
    return f"a line of the {type_name} board (" + ", ".join(f"{g[0]}..{g[-1]}" for g in groups.values()) + ")"


def _check_boards(table: ConfigTable) -> None:
    """Board names and slots of ``[crate]`` are unique (the crate itself refuses overlapping
    windows when it is built)."""
    names: dict[str, str] = {}
    slots: dict[int, str] = {}
    for b in table.table("crate", {}).tables("board", []):
        name = b.get_str("name")
        if name in names:
            raise b.error("name", f"a board name not used before ({name!r} is {names[name]})", name)
        names[name] = b.key("name")
        if "slot" in b:
            slot = b.get_int("slot", min=1, max=21)
            if slot in slots:
                raise b.error("slot", f"a free slot (slot {slot} holds {slots[slot]})", slot)
            slots[slot] = name


def _check_wiring(spec: RigSpec) -> None:
    """Every joint pin names a board of the right type in ``[crate]``, a channel or line that the
    board has, and no pin carries two signals (j2's pot on j1's ADC pin would servo j1 on j2's
    angle)."""
    types = {b.get_str("name"): b.get_str("type") for b in spec.table.table("crate", {}).tables("board", [])}
    roles = _board_roles(spec.table)
    used: dict[tuple[str, int | str], str] = {}
    for j in spec.joints:
        wt = j.table.table("wiring", {})
        for sig, pin in j.wiring.items():
            want = _SIGNAL_BOARD[sig]
            got = types.get(pin.board)
            if got is None:
                raise wt.error(sig, f"a pin of a board in [crate] (no board named {pin.board!r})", str(pin))
            if roles[pin.board] != want:
                raise wt.error(sig, f"a pin of a {want} board ({pin.board!r} is a {got} board)", str(pin))
            if want in _CHANNEL_ROLES:
                n = BOARD_TYPES[got].channels() or 0
                if not isinstance(pin.channel, int) or not 0 <= pin.channel < n:
                    raise wt.error(sig, f"a {want} channel 0..{n - 1}", str(pin))
            elif sig == "pwm":
                if pin.channel != "PWM":
                    raise wt.error(sig, f'the PIO\'s PWM output ("{pin.board}:PWM")', str(pin))
                if not hasattr(BOARD_TYPES[got].load_driver(), "set_pwm"):  # e.g. the VMIVME-2536
                    raise wt.error(sig, f"the PWM output of a PIO board with a PWM timer ({got} has none)", str(pin))
            elif str(pin.channel) not in _pio_lines(got):
                raise wt.error(sig, _pio_lines_text(got), str(pin))
            where = f"{j.name}.{sig}"
            key = (pin.board, pin.channel)
            if key in used:
                raise wt.error(sig, f"a free pin ({pin} already carries {used[key]})", str(pin))
            used[key] = where


# --- rig-level calibration wiring: references and DAC → ADC loopback ------------------------------
def reference_net(pin: Pin) -> str:
    """Net name of a reference input (``ref.adc1.12``)."""
    return f"ref.{pin.board}.{pin.channel}"


def loopback_net(dac_pin: Pin) -> str:
    """Net name of a DAC → ADC loopback pair (``loop.dac0.6``)."""
    return f"loop.{dac_pin.board}.{dac_pin.channel}"


def _parse_calibration_wiring(spec: RigSpec, rig: ConfigTable) -> None:
    types = _board_roles(spec.table)
    used = {(p.board, p.channel): f"{j.name}.{sig}" for j in spec.joints for sig, p in j.wiring.items()}

    def pin(cfg: ConfigTable, key: str, text: str, kind: str) -> Pin:
        board, sep, chan = text.partition(":")
        if not sep or not chan.isdigit() or types.get(board) != kind:
            raise cfg.error(key, f'a {kind} pin "board:channel" of a {kind} board in [crate]', text)
        p = Pin(board, int(chan))
        if (p.board, p.channel) in used:
            raise cfg.error(key, f"a free pin ({p} already carries {used[(p.board, p.channel)]})", text)
        used[(p.board, p.channel)] = key
        return p

    refs = rig.table("references", {})
    for key in refs.keys():
        spec.references[pin(refs, key, key, "adc")] = refs.get_float(key, min=-10.0, max=10.0)
    loops = rig.table("loopback", {})
    for key in loops.keys():
        spec.loopback[pin(loops, key, key, "dac")] = pin(loops, key, loops.get_str(key), "adc")


def _parse_watchdog(spec: RigSpec, rig: ConfigTable) -> WatchdogSpec | None:
    if "watchdog" not in rig:
        return None
    wd = rig.table("watchdog")
    wd.check_unknown({"line", "timeout_s"})
    types = _board_roles(spec.table)
    text = wd.get_str("line")
    line = parse_pin(wd, "line")
    kinds = {b.get_str("name"): b.get_str("type") for b in spec.table.table("crate", {}).tables("board", [])}
    if types.get(line.board) != "pio" or str(line.channel) not in _pio_lines(kinds[line.board]):
        raise wd.error("line", 'a PIO line "board:PA0".."board:PC7" of a pio board in [crate]', text)
    for j in spec.joints:
        for sig, p in j.wiring.items():
            if p == line:
                raise wd.error("line", f"a free PIO line ({line} already carries {j.net(sig)})", text)
    timeout = wd.get_float("timeout_s", min=1e-3, max=10.0)
    if not timeout > spec.period_s:
        raise wd.error("timeout_s", f"more than one servo period ({spec.period_s:g} s): the line has one "
                                    "edge per tick", timeout)
    return WatchdogSpec(line, timeout)


def _parse_readback(spec: RigSpec, rig: ConfigTable) -> dict[Pin, Pin]:
    """``[rig.readback]``: each wired output line of a PIO board whose driver takes ``loopback``
    → a free input line of the same board."""
    if "readback" not in rig:
        return {}
    rb = rig.table("readback")
    kinds = {b.get_str("name"): b.get_str("type") for b in spec.table.table("crate", {}).tables("board", [])}
    outputs = {p: f"{j.name}.{sig}" for j in spec.joints for sig, p in j.wiring.items() if sig in DIGITAL_OUTPUTS}
    if spec.watchdog is not None:
        outputs[spec.watchdog.line] = WATCHDOG_NET
    used = {p for j in spec.joints for p in j.wiring.values()} | set(outputs)
    out: dict[Pin, Pin] = {}
    for key in rb.keys():
        src = parse_pin(ConfigTable({"k": key}, rb.source, rb.prefix), "k")
        dst = parse_pin(rb, key)
        if src not in outputs:
            raise rb.error(key, "a PIO output line that carries a joint's digital output or the watchdog", key)
        kind = kinds[src.board]
        if "loopback" not in inspect.signature(BOARD_TYPES[kind].load_driver()).parameters:
            raise rb.error(key, f"a line of a board that reads back through an input ({kind} does not)", key)
        if dst.board != src.board or str(dst.channel) not in _pio_lines(kind):
            raise rb.error(key, f"a line of {src.board} ({_pio_lines_text(kind)})", str(dst))
        if dst in used:
            raise rb.error(key, f"a free line ({dst} is in use)", str(dst))
        used.add(dst)
        out[src] = dst
    return out
