"""The console's atomic commands, with typed parameters shared by the line protocol and the
compound-command language.

Every command runs in the loop's thread at a tick boundary (the server hands it over with
:meth:`servo.loop.ServoLoop.submit`), so it sees and changes the loop between two ticks, never
during one. A command returns an :class:`Outcome`: reply lines, the text of its ``OK`` line, and —
for motions and pauses — when it is *complete* (a compound sequence waits for that before its next
statement; the console line replies at once).

Angles at this edge are degrees (the operator's unit); inside, everything is SI.
"""

from __future__ import annotations

import math
import os
import stat
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from hal.si import deg_to_rad, rad_to_deg
from servo.control.errors import ControlError
from servo.control.gains import GAIN_NAMES
from servo.gain_guard import GainRejected, check_gain_change, check_gain_set
from servo.named_controllers import DEFAULT_CONTROLLER, use_controller
from vmehil.console import hand as fingers
from vmehil.console.protocol import (
    ARGS,
    COLLISION,
    FILE,
    GAIN,
    INTERNAL,
    NOT_HOMED,
    STATE,
    UNAVAILABLE,
    VALUE,
    Arg,
    ConsoleError,
    Value,
    kv,
    type_name,
)

# parameter types: the (DM)² four, plus "joint" (an int 1..n or a joint name, or "all") and
# "joints" (the same, or a vector of joint numbers: 1,3)
STRING, INT, FLOAT, VECTOR, JOINT, JOINTS = "string", "int", "float", "vector", "joint", "joints"
ACCEPTS: dict[str, tuple[str, ...]] = {
    STRING: ("string",),
    INT: ("int",),
    FLOAT: ("float", "int"),
    VECTOR: ("vector",),
    JOINT: ("int", "string"),
    JOINTS: ("int", "string", "vector"),
}
REQUIRED: Any = object()
MAX_LOG_LINES = 200


@dataclass(frozen=True)
class Param:
    """A typed parameter: ``type`` is one of string, int, float, vector, joint; ``default`` is
    :data:`REQUIRED` for a required one; ``per_joint`` vectors must have one value per joint."""

    name: str
    type: str
    default: Any = REQUIRED
    per_joint: bool = False

    def usage(self) -> str:
        text = f"{self.name}:{self.type}"
        if self.default is REQUIRED:
            return text
        return f"[{text}={'-' if self.default is None else self.default}]"


@dataclass(frozen=True)
class Typed:
    """A value known only by its type (a compound parameter reference, checked at load time);
    ``length`` for vectors when known."""

    type: str
    length: int | None = None


@dataclass
class Outcome:
    """What a command did: reply ``lines`` (with their DATA/INFO prefix), the text after ``OK
    <name>``, and when it is complete: ``until(loop)`` true, or after ``pause_ticks`` ticks."""

    lines: list[str] = field(default_factory=list)
    ok: str = ""
    until: Callable[[Any], bool] | None = None
    pause_ticks: int = 0
    #: the reply goes on later: a job handed to ``Session.defer`` sends its further lines and
    #: the end line (``OK``/``ERR``); the console sends only ``lines`` now
    deferred: bool = False


# The compound-command language (vmehil.console.compound) is built on the atoms; the atoms see its
# library and executor only through these protocols, so this module does not import it.
class CompoundCommand(Protocol):
    """A loaded compound command as the atoms list it (:class:`vmehil.console.compound.CompoundDef`)."""

    name: str

    @property
    def params(self) -> tuple[Param, ...]: ...

    @property
    def where(self) -> str: ...

    def usage(self) -> str: ...


class CompoundRunner(Protocol):
    """The running compound commands as the atoms control them (:class:`vmehil.console.compound.Executor`)."""

    @property
    def active(self) -> Mapping[int, Any]: ...

    def active_ids(self) -> list[int]: ...

    def cancel(self, inv_id: int, reason: str) -> int: ...

    def cancel_all(self, reason: str) -> int: ...


@dataclass
class Session:
    """What commands act on: the ``loop`` (a :class:`servo.loop.ServoLoop` or an object with the
    same attributes), the computation ``delay`` in periods (for gain checks), the compound
    ``library`` and ``executor``, optional host hooks (``shutdown``, ``calibrate``), and the
    console's ``defer`` (jobs between ticks, e.g. a calibration)."""

    loop: Any
    delay: float = 0.0
    library: Mapping[str, CompoundCommand] | None = None
    executor: CompoundRunner | None = None
    shutdown: Callable[[], None] | None = None
    #: ``calibrate(session, args, command="calibrate")`` (``home J`` passes ``command="home"``)
    calibrate: Callable[..., Outcome] | None = None
    source: str = "console"
    #: run ``job(send)`` between two ticks, in the thread that owns the rig (set by the console);
    #: ``send(lines)`` writes reply lines. At most one job waits at a time.
    defer: Callable[[Callable[[Callable[[list[str]], None]], None]], None] | None = None

    @property
    def n(self) -> int:
        return int(self.loop.n)

    @property
    def names(self) -> list[str]:
        return list(self.loop.names)


#: What carries out an atomic command: ``(session, bound arguments) -> Outcome``.
AtomHandler = Callable[[Session, dict[str, Any]], Outcome]


@dataclass(frozen=True)
class Atom:
    """An atomic command: typed ``params`` and ``run(session, bound_args)``; ``on_line`` /
    ``in_files``: where it may be used; ``varargs``: arguments are passed unchecked."""

    name: str
    params: tuple[Param, ...]
    run: AtomHandler
    summary: str
    on_line: bool = True
    in_files: bool = True
    varargs: bool = False

    def usage(self) -> str:
        return " ".join([self.name, *(p.usage() for p in self.params)] + (["..."] if self.varargs else []))


def atom(name: str, params: tuple[Param, ...], summary: str, **flags: Any) -> Callable[[AtomHandler], Atom]:
    """Decorator: the function becomes the :class:`Atom` ``name`` (listed in :data:`ATOMS`)."""
    def deco(fn: AtomHandler) -> Atom:
        return Atom(name, params, fn, summary, **flags)
    return deco


# ---- argument binding (shared with the compound loader) ------------------------------------------------
def resolve_joint(value: Value, names: list[str] | None) -> int | None:
    """``"all"`` → None; an int 1..n or a joint name → the joint index (0-based)."""
    if isinstance(value, str) and value.lower() == "all":
        return None
    if names is None:
        return 0
    if isinstance(value, int) and not isinstance(value, bool):
        if 1 <= value <= len(names):
            return value - 1
        raise ConsoleError(VALUE, f"joint {value} does not exist: joints are 1..{len(names)} ({', '.join(names)})")
    if isinstance(value, str):
        for i, nm in enumerate(names):
            if nm.lower() == value.lower():
                return i
    raise ConsoleError(VALUE, f"no joint {value!r}: use 1..{len(names)}, {', '.join(names)} or all")


def _a(word: str) -> str:
    return ("an " if word[0] in "aeiou" else "a ") + word


def check_arg(cmd: str, p: Param, value: Value | Typed, n_joints: int | None, names: list[str] | None) -> Any:
    """Type-check (and convert) one argument; :class:`ConsoleError` ARGS/VALUE naming it."""
    vtype = value.type if isinstance(value, Typed) else type_name(value)
    if vtype not in ACCEPTS[p.type]:
        raise ConsoleError(ARGS, f"{cmd}: {p.name} must be {_a(p.type)}, got {_a(vtype)}"
                                 + (f" ({value!r})" if not isinstance(value, Typed) else ""))
    length = value.length if isinstance(value, Typed) else (len(value) if isinstance(value, tuple) else None)
    if p.per_joint and n_joints is not None and length is not None and length != n_joints:
        raise ConsoleError(VALUE, f"{cmd}: {p.name} needs {n_joints} values (one per joint), got {length}")
    if isinstance(value, Typed):
        return value
    if p.type == FLOAT:
        return float(value)  # type: ignore[arg-type]
    if p.type == JOINT:
        if names is None:
            return value
        return resolve_joint(value, names)
    if p.type == JOINTS:
        return resolve_joints(value, names)
    return value


def resolve_joints(value: Value, names: list[str] | None) -> list[int] | None:
    """``"all"`` → None; a joint (number or name) → [its index]; a vector of joint numbers (``1,3``)
    → their indices, each once, in the order given."""
    if not isinstance(value, tuple):
        one = resolve_joint(value, names)
        return None if one is None else [one]
    out: list[int] = []
    for v in value:
        if not (isinstance(v, int | float) and float(v).is_integer()):
            raise ConsoleError(VALUE, f"joint {v!r} in {','.join(map(str, value))}: joints are numbers 1..n")
        j = resolve_joint(int(v), names)
        if j is not None and j not in out:
            out.append(j)
    return out


def bind(cmd: str, params: tuple[Param, ...], args: Sequence[tuple[str | None, Value | Typed]],
         n_joints: int | None = None, names: list[str] | None = None) -> dict[str, Any]:
    """Match positional and keyword ``args`` to ``params``; :class:`ConsoleError` ARGS on a missing,
    unknown, repeated or ill-typed argument."""
    out: dict[str, Any] = {}
    positional = [v for k, v in args if k is None]
    if len(positional) > len(params):
        raise ConsoleError(ARGS, f"{cmd} takes at most {len(params)} argument(s), got {len(positional)}; "
                                 f"usage: {' '.join([cmd, *(p.usage() for p in params)])}")
    by_name = {p.name: p for p in params}
    for p, v in zip(params, positional, strict=False):
        out[p.name] = check_arg(cmd, p, v, n_joints, names)
    for k, v in args:
        if k is None:
            continue
        if k not in by_name:
            raise ConsoleError(ARGS, f"{cmd} has no argument {k!r}; it takes "
                                     f"{', '.join(by_name) or 'no arguments'}")
        if k in out:
            raise ConsoleError(ARGS, f"{cmd}: {k} given twice")
        out[k] = check_arg(cmd, by_name[k], v, n_joints, names)
    for p in params:
        if p.name not in out:
            if p.default is REQUIRED:
                raise ConsoleError(ARGS, f"{cmd}: missing {p.name} ({p.type}); usage: "
                                         f"{' '.join([cmd, *(q.usage() for q in params)])}")
            out[p.name] = (resolve_joint(p.default, names) if p.type == JOINT and names is not None
                           else resolve_joints(p.default, names) if p.type == JOINTS else p.default)
    return out


# ---- helpers --------------------------------------------------------------------------------------------
def _deg(x: float) -> float:
    return float(rad_to_deg(x))


def loop_state(loop: Any) -> str:
    if loop.fault is not None:
        return "fault"
    if getattr(loop, "stopping", None) is not None:
        return "stopping"  # a category-1 stop under way: decelerating, then brakes, then power off
    return "running" if loop.enabled else "stopped"


#: the stops the reader runs ahead of the queue
URGENT_STOPS = ("stop", "estop")


def stop_event(loop: Any) -> str:
    """``EVT stop category=N cause=… excursion_deg=j1:…,j2:…`` for the loop's last stop."""
    st = loop.stop_summary()
    exc = st.get("excursion_deg") or {}
    moved = ",".join(f"{name}:{'nan' if v is None else f'{v:.3f}'}" for name, v in exc.items())
    return kv("EVT", "stop", category=st.get("category"), cause=st.get("cause") or "-", excursion_deg=moved or "-")


def _law(loop: Any):
    law = loop.law
    if law is None:
        raise ConsoleError(STATE, "the active controller has no pid law: gains and modes cannot be changed")
    return law


def _plan_context(loop: Any):
    ctx = getattr(loop, "plan_context", None)
    if ctx is None:
        from servo.trajectory import JointLimits, PlanContext

        ctx = PlanContext(JointLimits.make(loop.n, math.radians(30.0)))
    return ctx


def hold_position(loop: Any) -> np.ndarray:
    """Where the joints are commanded to be now (rad): the held target, or the last θd mid-motion."""
    seq = loop.sequencer
    if seq.finished:
        return np.asarray(seq.current.end, float).copy()
    last = loop.last.get("theta_d") if loop.last else None
    if last is not None and np.all(np.isfinite(last)):
        return np.asarray(last, float).copy()
    return np.asarray(seq.current.start, float).copy()


def _require_running(loop: Any) -> None:
    if loop.fault is not None:
        f = loop.fault
        raise ConsoleError(STATE, f"the loop is stopped by a fault ({f.cause}"
                                  f"{' on ' + f.joint if f.joint else ''}): check status, then enable")
    st = getattr(loop, "stopping", None)
    if st is not None:
        raise ConsoleError(STATE, f"the loop is stopping ({st.cause}, category 1: decelerating, then brakes and "
                                  "power off): wait for it, then enable")
    if not loop.enabled:
        raise ConsoleError(STATE, "the amplifiers are not enabled: enable first")


def _require_idle(loop: Any) -> None:
    seq = loop.sequencer
    if not seq.finished:
        left = len(seq.moves) - max(seq.index, 0)
        raise ConsoleError(STATE, f"a motion is running ({left} move(s) left): wait for it to end, or stay to "
                                  "hold the present target first")


def homed_word(loop: Any, joint: int) -> str:
    """``yes``/``no`` for a joint that can be homed, ``exempt`` for one that needs none (a continuous
    joint: no pot to choose the index); ``-`` for a loop whose drivers do not say."""
    io = loop.io
    homeable, homed = getattr(io, "homeable", None), getattr(io, "homed", None)
    if homeable is None or homed is None:
        return "-"
    return "exempt" if not homeable[joint] else ("yes" if homed[joint] else "no")


def not_homed(loop: Any) -> list[str]:
    """The joints a rig that requires homing (``[servo] require_homing``) still waits for."""
    if not getattr(loop, "require_homing", False):
        return []
    return [loop.names[i] for i in range(loop.n) if homed_word(loop, i) == "no"]


def _require_homed(loop: Any) -> None:
    missing = not_homed(loop)
    if missing:
        raise ConsoleError(NOT_HOMED, f"the rig requires homing before moves and {', '.join(missing)} "
                                      f"{'is' if len(missing) == 1 else 'are'} not homed: home all (or home J) first")


def _refused(e: Any) -> ConsoleError:
    """A move the soft limits or the scene refuse (:class:`servo.trajectory.MotionRefused`) as the
    console says it: ``ERR LIMIT|COLLISION|REACH`` and the first refusal (``and N more``)."""
    return ConsoleError(e.code, str(e))


def _dry_run(moves: list[Any], start: np.ndarray, ctx: Any) -> float:
    """Plan every move on a throw-away sequencer (errors now, not inside a tick); total duration s."""
    from servo.trajectory import MotionRefused, Sequencer, TrajectoryError

    seq = Sequencer(list(moves), start, ctx)
    t = 0.0
    try:
        seq.sample(0.0)
        guard = 0
        while not seq.finished and guard < 100_000:
            t += max(seq.current.duration, 1e-3)
            seq.sample(t)
            guard += 1
    except MotionRefused as e:
        raise _refused(e) from None
    except (TrajectoryError, ValueError) as e:
        raise ConsoleError(VALUE, f"cannot plan the motion: {e}") from None
    if not seq.finished:
        raise ConsoleError(VALUE, "the motion does not end (an endless hold?); give every wait a duration")
    return float(seq.total_duration or 0.0)


def plan_off_loop(moves: list[Any], loop: Any) -> Any:
    """In the preparer thread: a :class:`~servo.trajectory.Sequencer` of ``moves`` planned from
    where the loop holds now — a guess, read beside the running loop; :func:`start_motion` takes it
    only when the loop still holds exactly there with the same limits, else plans again. So a long
    path (thousands of LSPB vias, tenths of a second) is planned off the loop's thread. ``None``
    when the guess cannot be made."""
    from servo.trajectory import Sequencer

    try:
        return Sequencer(list(moves), hold_position(loop), _plan_context(loop))
    except Exception:  # a torn read of the running loop's state: plan in start_motion instead
        return None


def _same_limits(a: Any, b: Any) -> bool:
    if a is b:
        return True
    if (a.a_max is None) != (b.a_max is None):
        return False
    return bool(np.array_equal(a.v_max, b.v_max) and (a.a_max is None or np.array_equal(a.a_max, b.a_max)))


def start_motion(s: Session, moves: list[Any], what: str, planned: Any = None) -> Outcome:
    """Start ``moves`` from the present target at this tick; complete when they have all ended.
    ``planned``: the same moves planned off the loop (:func:`plan_off_loop`), used when it started
    where the loop holds now."""
    from servo.trajectory import MotionRefused, Sequencer

    loop = s.loop
    _require_running(loop)
    _require_idle(loop)
    _require_homed(loop)
    start = hold_position(loop)
    ctx = _plan_context(loop)

    if (planned is not None and (planned.ctx is ctx or not (planned.ctx.extras or ctx.extras))
            and np.array_equal(planned.current.start, start) and _same_limits(planned.ctx.limits, ctx.limits)):
        seq = planned
    else:
        seq = Sequencer(list(moves), start, ctx)  # plans every move ahead, once (servo.trajectory.sequencer)
    refused = seq.plan_error if isinstance(seq.plan_error, MotionRefused) else None
    if refused is None and seq is planned and ctx.bounds is not None:
        # planned off the loop: the scene may have changed since (obstacle add): checked again here
        for i, traj in enumerate(seq.planned):
            found = ctx.bounds.check_trajectory(traj, move=i)
            if found:
                refused = MotionRefused(found)
                break
    if refused is not None:  # the soft limits or the scene: refused before it starts
        loop.note(s.source, f"{what}: {refused}")
        raise _refused(refused)
    planned = [float(t.duration) for t in seq.planned]
    if seq.plan_error is None and len(planned) == len(moves) and all(map(math.isfinite, planned)):
        duration = float(sum(planned))
    else:  # a move that could not be planned ahead (its error), or an open one (vservo)
        duration = _dry_run(moves, start, ctx)
    loop.set_motion(seq)
    loop.note(s.source, f"{what} ({duration:.3f} s)")
    return Outcome(ok=kv(duration_s=duration), until=lambda lp: lp.sequencer is not seq or seq.finished)


def _speed(v: float) -> float:
    if not (math.isfinite(v) and 0.0 < v <= 1.0):
        raise ConsoleError(VALUE, f"speed {v!r} must be in (0, 1] (0.5 makes the move twice as long)")
    return v


#: no console angle is larger than a turn (1e300 was accepted and planned): a sanity bound on the
#: command, not a joint's limit
MAX_ANGLE_DEG = 360.0


def _angles(values: tuple[float, ...], what: str) -> np.ndarray:
    arr = np.asarray(values, float)
    if not np.all(np.isfinite(arr)) or np.any(np.abs(arr) > MAX_ANGLE_DEG):
        raise ConsoleError(VALUE, f"{what} must be finite angles in degrees, within ±{MAX_ANGLE_DEG:g}")
    return deg_to_rad(arr)


# ---- the commands ----------------------------------------------------------------------------------------
@atom("help", (Param("command", STRING, ""),), "list the commands, or show one command's usage", in_files=False)
def _help(s: Session, a: dict[str, Any]) -> Outcome:
    name = a["command"]
    lines = []
    if name:
        if name in ATOMS:
            c = ATOMS[name]
            lines.append(kv("DATA", "help", command=c.name, usage=c.usage(), summary=c.summary))
        elif s.library is not None and name in s.library:
            d = s.library[name]
            lines.append(kv("DATA", "help", command=d.name, usage=d.usage(), summary=f"compound command ({d.where})"))
        else:
            raise ConsoleError(VALUE, f"no command {name!r}; help lists them")
        return Outcome(lines)
    for c in ATOMS.values():
        if c.on_line:
            lines.append(kv("DATA", "help", command=c.name, usage=c.usage(), summary=c.summary))
    if s.library is not None:
        for d in s.library.values():
            lines.append(kv("DATA", "help", command=d.name, usage=d.usage(), summary=f"compound command ({d.where})"))
    lines.append("INFO angles in degrees; replies end with an OK or ERR line; see docs/console.md")
    return Outcome(lines)


@atom("status", (), "loop state and, per joint: position, target, error, current, integrators, faults")
def _status(s: Session, a: dict[str, Any]) -> Outcome:
    loop = s.loop
    last = loop.last or {}
    n = loop.n
    nan = np.full(n, np.nan)

    def col(key: str) -> np.ndarray:
        v = last.get(key)
        return np.asarray(v, float) if v is not None else nan

    theta, theta_d, current, omega = col("theta"), col("theta_d"), col("current"), col("omega")
    theta_enc = col("theta_enc")
    integrating = col("integrating")
    law = loop.law
    kp_eff = np.asarray(law.kp_eff(), float) if law is not None else nan
    seq = loop.sequencer
    motion = "idle" if seq.finished else "running"
    active = s.executor.active_ids() if s.executor is not None else []
    homed = [homed_word(loop, i) for i in range(n)]
    lines = [kv("DATA", "loop", tick=int(loop.tick_count), t_s=loop.tick_count * loop.period_s,
                state=loop_state(loop), motion=motion, compounds=len(active),
                homed="no" if "no" in homed else "yes",
                homing="required" if getattr(loop, "require_homing", False) else "optional")]
    fault = loop.fault
    for i, name in enumerate(loop.names):
        err = theta_d[i] - theta[i]
        integ = "nan" if math.isnan(integrating[i]) else ("on" if integrating[i] else "off")
        jf = fault.cause if fault is not None and fault.joint == name else "-"
        # after a stop the drivers still read (servo.loop): positions, velocities and currents as
        # measured, flagged as stopped; the target and error have no meaning then
        lines.append(kv("DATA", "joint", joint=name, pos_deg=_deg(theta[i]), target_deg=_deg(theta_d[i]),
                        err_deg=_deg(err), vel_deg_s=_deg(omega[i]), current_a=float(current[i]),
                        integrators=integ, kp_eff=float(kp_eff[i]), fault=jf, stopped=int(not loop.enabled),
                        homed=homed[i], enc_deg=_deg(theta_enc[i])))
    if fault is not None:
        lines.append(kv("DATA", "fault", cause=fault.cause, joint=fault.joint or "-", tick=fault.tick,
                        t_s=fault.time_s, detail=fault.detail))
    return Outcome(lines, kv(joints=n, state=loop_state(loop)))


@atom("move", (Param("target", VECTOR, per_joint=True), Param("speed", FLOAT, 1.0)),
      "coordinated quintic move of every joint to TARGET (degrees); speed factor in (0, 1]")
def _move(s: Session, a: dict[str, Any]) -> Outcome:
    from servo.motion import QuinticMove

    target = _angles(a["target"], "targets")
    return start_motion(s, [QuinticMove(target, None, _speed(a["speed"]))], "move to " + str(list(a["target"])))


@atom("move_rel", (Param("delta", VECTOR, per_joint=True), Param("speed", FLOAT, 1.0)),
      "coordinated quintic move by DELTA (degrees) from the present target")
def _move_rel(s: Session, a: dict[str, Any]) -> Outcome:
    from servo.motion import QuinticMove

    delta = _angles(a["delta"], "deltas")
    return start_motion(s, [QuinticMove(None, delta, _speed(a["speed"]))], "move by " + str(list(a["delta"])))


@atom("move_joint", (Param("joint", JOINT), Param("target", FLOAT), Param("speed", FLOAT, 1.0)),
      "quintic move of one joint (number 1..n or name) to TARGET degrees; the others hold")
def _move_joint(s: Session, a: dict[str, Any]) -> Outcome:
    from servo.motion import QuinticMove

    j = a["joint"]
    if j is None:
        raise ConsoleError(VALUE, "move_joint needs one joint (not all); use move for every joint")
    if not math.isfinite(a["target"]) or abs(a["target"]) > MAX_ANGLE_DEG:
        raise ConsoleError(VALUE, f"target must be a finite angle in degrees, within ±{MAX_ANGLE_DEG:g}")
    _require_running(s.loop)
    _require_idle(s.loop)
    _require_homed(s.loop)
    target = hold_position(s.loop)
    target[j] = float(deg_to_rad(a["target"]))
    return start_motion(s, [QuinticMove(target, None, _speed(a["speed"]))],
                        f"move {s.loop.names[j]} to {a['target']:g} deg")


@atom("move_to", (*(Param(k, FLOAT) for k in ("x", "y", "z")),
                   *(Param(k, FLOAT, None) for k in ("roll", "pitch", "yaw")),
                   Param("approach", FLOAT, 0.0), Param("speed", FLOAT, 1.0), Param("settle", FLOAT, 0.0)),
      "the tool to X Y Z (metres, the arm's base frame) with the hand at ROLL PITCH YAW (degrees; all three or "
      "none: the default, level and pointing outward); approach=M: straight in over the last M metres; "
      "settle=MM: then fine positioning until the tool is within MM millimetres (docs/cartesian.md)")
def _move_to(s: Session, a: dict[str, Any]) -> Outcome:
    moves = a.get("moves")
    if moves is None:  # not prepared off the loop thread (direct API use)
        moves = _move_to_moves(a)
    rpy = [a["roll"], a["pitch"], a["yaw"]]
    what = f"move_to {[a['x'], a['y'], a['z']]}" + ("" if rpy[0] is None else f" rpy {rpy}")
    return start_motion(s, moves, what, a.get("planned"))


def _move_to_moves(a: dict[str, Any]) -> list[Any]:
    """``move_to``'s one Cartesian move, its arguments checked."""
    from servo.cartesian import MAX_COORDINATE_M, CartesianMove, CartesianTarget

    xyz = [a["x"], a["y"], a["z"]]
    rpy = [a["roll"], a["pitch"], a["yaw"]]
    if not all(math.isfinite(v) and abs(v) <= MAX_COORDINATE_M for v in xyz):
        raise ConsoleError(VALUE, f"move_to: X Y Z must be finite, within ±{MAX_COORDINATE_M:g} m")
    if any(v is None for v in rpy) and not all(v is None for v in rpy):
        raise ConsoleError(ARGS, "move_to X Y Z [ROLL PITCH YAW]: the hand's orientation needs all three angles")
    if rpy[0] is not None:
        _angles(tuple(rpy), "roll, pitch, yaw")  # finite, within a turn
    approach = a["approach"]
    if not (math.isfinite(approach) and 0.0 <= approach <= MAX_COORDINATE_M):
        raise ConsoleError(VALUE, f"move_to: approach must be a distance in [0, {MAX_COORDINATE_M:g}] m")
    target = CartesianTarget.make(xyz, None if rpy[0] is None else rpy)
    settle_mm = a["settle"]
    fine = None
    if settle_mm != 0.0:  # as the motion file's settle_tolerance_mm (its default phase of 3 s)
        from servo.cartesian import MIN_SETTLE_TOLERANCE_MM
        from servo.fine_positioning import FineSettings

        if not (math.isfinite(settle_mm) and MIN_SETTLE_TOLERANCE_MM <= settle_mm <= 1000.0):
            raise ConsoleError(VALUE, f"move_to: settle must be a tolerance in [{MIN_SETTLE_TOLERANCE_MM:g}, 1000] mm "
                                      "(or 0: no fine positioning)")
        fine = FineSettings(settle_mm * 1e-3, 3.0)
    return [CartesianMove(target, approach, _speed(a["speed"]), fine=fine)]


#: the largest jog speed the console takes (°/s): a sanity bound on the command; the joint's
#: velocity limit then clamps it
MAX_JOG_DEG_S = 3600.0


@atom("jog", (Param("joint", JOINT), Param("speed_deg_s", FLOAT)),
      "jog JOINT at SPEED_DEG_S (°/s, signed; 0 stops): a velocity move with a deadman - it stops unless "
      "renewed within 0.5 s - bounded by the soft limits and the velocity limit", in_files=False)
def _jog(s: Session, a: dict[str, Any]) -> Outcome:
    from servo.jog import DEADMAN_S, jog, running_jog
    from servo.trajectory import TrajectoryError

    loop = s.loop
    j = a["joint"]
    if j is None:
        raise ConsoleError(VALUE, "jog moves one joint (not all): jog J SPEED_DEG_S")
    speed = a["speed_deg_s"]
    if not math.isfinite(speed) or abs(speed) > MAX_JOG_DEG_S:
        raise ConsoleError(VALUE, f"speed_deg_s must be a finite speed in °/s, within ±{MAX_JOG_DEG_S:g}")
    _require_running(loop)
    if running_jog(loop) is None:
        _require_idle(loop)  # a planned motion runs: it is not the jog's to interrupt
    try:
        speeds, started = jog(loop, {j: float(deg_to_rad(speed))}, hold_position(loop))
    except TrajectoryError as e:
        cur = running_jog(loop)
        if cur is not None and cur.refusal is not None:  # it stopped short of an obstacle
            raise ConsoleError(COLLISION, str(e)) from None
        raise ConsoleError(VALUE, f"cannot jog: {e}") from None
    got = _deg(speeds[j])
    if started:  # renewals (a handset sends them at 10 Hz) are not each logged
        loop.note(s.source, f"jog {loop.names[j]} at {speed:g} deg/s")
    return Outcome(ok=kv(joint=loop.names[j], speed_deg_s=round(got, 6), limited=int(abs(got - speed) > 1e-9),
                         deadman_s=DEADMAN_S, started=int(started)))


@atom("stay", (), "stop the motion: hold the present target (the amplifiers stay on)")
def _stay(s: Session, a: dict[str, Any]) -> Outcome:
    from servo.trajectory import Sequencer

    loop = s.loop
    hold = hold_position(loop)
    loop.set_motion(Sequencer([], hold, _plan_context(loop)))
    loop.note(s.source, "stay")
    return Outcome(ok=kv(target_deg=tuple(round(_deg(x), 6) for x in hold)))


def _scene_of(loop: Any) -> Any:
    """The scene the loop's moves are checked against (:mod:`servo.scene`)."""
    bounds = getattr(_plan_context(loop), "bounds", None)
    if bounds is None or bounds.arm is None or bounds.scene is None:
        raise ConsoleError(UNAVAILABLE, "obstacle: this rig's file states no [arm]: there are no links to check "
                                        "obstacles against")
    return bounds.scene


def _box_text(v: Sequence[float]) -> tuple[float, ...]:
    return tuple(round(float(x), 6) for x in v)


@atom("obstacle", (Param("action", STRING), Param("name", STRING, None),
                   *(Param(k, FLOAT, None) for k in ("x0", "y0", "z0", "x1", "y1", "z1"))),
      "the scene's obstacles (metres, the arm's base frame): add NAME X0 Y0 Z0 X1 Y1 Z1 (a box from one corner "
      "to the opposite one), remove NAME, list; later moves are checked against them")
def _obstacle(s: Session, a: dict[str, Any]) -> Outcome:
    from servo.scene import Obstacle, SceneError

    loop = s.loop
    scene = _scene_of(loop)
    action = str(a["action"]).lower()
    corners = [a[k] for k in ("x0", "y0", "z0", "x1", "y1", "z1")]
    if action == "list":
        if a["name"] is not None or any(c is not None for c in corners):
            raise ConsoleError(ARGS, "obstacle list takes no more arguments")
        lines = [kv("DATA", "obstacle", name=ob.name, min_m=_box_text(ob.min_m), max_m=_box_text(ob.max_m))
                 for ob in scene.obstacles]
        return Outcome(lines, kv(obstacles=len(scene), scene=scene.source))
    if a["name"] is None:
        raise ConsoleError(ARGS, f"obstacle {action}: give the obstacle's NAME")
    name = str(a["name"])
    try:
        if action == "remove":
            if any(c is not None for c in corners):
                raise ConsoleError(ARGS, "obstacle remove takes only the NAME")
            scene.remove(name)
            loop.note(s.source, f"obstacle {name} removed")
            return Outcome(ok=kv(name=name, obstacles=len(scene)))
        if action != "add":
            raise ConsoleError(VALUE, f"obstacle {action!r}: use add, remove or list")
        if any(c is None for c in corners):
            raise ConsoleError(ARGS, "obstacle add NAME X0 Y0 Z0 X1 Y1 Z1: six coordinates in metres")
        lo = [min(corners[i], corners[i + 3]) for i in range(3)]
        hi = [max(corners[i], corners[i + 3]) for i in range(3)]
        ob = Obstacle.make(name, lo, hi)
        scene.add(ob)
    except SceneError as e:
        raise ConsoleError(VALUE, str(e)) from None
    loop.note(s.source, f"obstacle {name} added: {list(ob.min_m)} .. {list(ob.max_m)} m")
    lines = []
    bounds = _plan_context(loop).bounds
    here = hold_position(loop)
    touching = [link for link, other in bounds.collisions_at(here) if other == name]
    if touching:  # the arm's own target is in it: every move from here is refused until it goes
        lines.append(kv("INFO", f"the arm's present target puts link {touching[0]} in {name}: moves from here are "
                                "refused until it is removed"))
    return Outcome(lines, kv(name=name, min_m=_box_text(ob.min_m), max_m=_box_text(ob.max_m), obstacles=len(scene)))


def _gain_lines(loop: Any) -> list[str]:
    law = _law(loop)
    g = getattr(law, "_pending_gains", None) or law.gains
    so = getattr(law, "_pending_switch_off", None) or law.switch_off
    kp_eff = law.kp_eff()
    return [kv("DATA", "gains", joint=name, **g.joint(i).as_dict(), kp_eff=float(kp_eff[i]),
               mode="auto" if so.enabled[i] else "integrate")
            for i, name in enumerate(loop.names)]


@atom("gains", (Param("joint", JOINT, "all"), *(Param(k, FLOAT, None) for k in GAIN_NAMES)),
      "show the gains, or set some (kp= kpi= kv= kvi=) for one joint or all; checked by servo.gain_guard")
def _gains(s: Session, a: dict[str, Any]) -> Outcome:
    loop = s.loop
    law = _law(loop)
    changes = {k: a[k] for k in GAIN_NAMES if a[k] is not None}
    if not changes:
        lines = _gain_lines(loop)
        if a["joint"] is not None:
            lines = [lines[a["joint"]]]
        return Outcome(lines)
    joint = a["joint"]
    try:
        check_gain_change(law, joint, changes, loop.period_s, s.delay)
        law.set_gains(joint=joint, **changes)
    except GainRejected as e:
        where = f"{loop.names[e.joint]}: " if e.joint is not None else ""
        shown = " ".join(f"{k}={v:g}" for k, v in changes.items())
        raise ConsoleError(GAIN, f"{shown} rejected ({where}{e.reason}); nothing was changed") from None
    except ValueError as e:  # GainError from the law itself
        raise ConsoleError(GAIN, str(e)) from None
    where = "all joints" if joint is None else loop.names[joint]
    shown = " ".join(f"{k}={v:g}" for k, v in changes.items())
    loop.note(s.source, f"gains {where}: {shown}")
    lines = _gain_lines(loop)
    if joint is not None:
        lines = [lines[joint]]
    return Outcome(lines, kv(applied_at_tick=int(loop.tick_count)))


MODES = {"auto": True, "integrate": False}


@atom("mode", (Param("mode", STRING, ""), Param("joint", JOINT, "all")),
      "show the loop mode, or set the integrator mode: auto (switch-off at rest) or integrate (always)")
def _mode(s: Session, a: dict[str, Any]) -> Outcome:
    loop = s.loop
    law = _law(loop)
    mode, joint = a["mode"], a["joint"]
    if mode:
        if mode not in MODES:
            raise ConsoleError(VALUE, f"mode {mode!r}: use auto (integrator switch-off at rest) or integrate")
        so = getattr(law, "_pending_switch_off", None) or law.switch_off
        enabled = so.enabled.copy()
        if joint is None:
            enabled[:] = MODES[mode]
        else:
            enabled[joint] = MODES[mode]
        law.set_switch_off(replace(so, enabled=enabled))
        loop.note(s.source, f"mode {mode} on {'all joints' if joint is None else loop.names[joint]}")
    so = getattr(law, "_pending_switch_off", None) or law.switch_off
    integ = law.integrating
    objects = ",".join(o.name for o in loop.controller.active.objects) if hasattr(loop, "controller") else "?"
    lines = [kv("DATA", "mode", state=loop_state(loop), controller=objects)]
    lines += [kv("DATA", "mode", joint=name, mode="auto" if so.enabled[i] else "integrate",
                 integrators="on" if integ[i] else "off")
              for i, name in enumerate(loop.names) if joint is None or i == joint]
    return Outcome(lines)


def _controller_lines(loop: Any, joint: int | list[int] | None) -> list[str]:
    choices = getattr(loop, "controllers", None)
    law = _law(loop)
    lines = []
    wanted = None if joint is None else ({joint} if isinstance(joint, int) else set(joint))
    for i, name in enumerate(loop.names):
        if wanted is not None and i not in wanted:
            continue
        pending = getattr(law, "_pending_switch", {})
        hz = float(pending[i][1]) if i in pending else float(law.filter_hz[i])  # what the next tick uses
        names = choices.names(i) if choices is not None else [DEFAULT_CONTROLLER]
        active = names[loop.active_controller[i]] if choices is not None else DEFAULT_CONTROLLER
        lines.append(kv("DATA", "controller", joint=name, active=active, index=names.index(active),
                        controllers=",".join(names), velocity_filter_hz=None if math.isnan(hz) else hz))
    return lines


@atom("controller", (Param("action", STRING, "list"), Param("name", STRING, ""), Param("joint", JOINTS, "all")),
      "list each joint's named controllers, or 'controller use NAME [JOINTS]' (a joint, 1,3 or all): switch at "
      "the next tick, bumpless, every joint named or none; gains checked by servo.gain_guard")
def _controller(s: Session, a: dict[str, Any]) -> Outcome:
    loop = s.loop
    action, name, joint = a["action"], a["name"], a["joint"]
    if isinstance(joint, int):  # one joint index, as a caller in code (MAVLink's Jn_CTRL) gives it
        joint = [joint]
    if action == "list":
        return Outcome(_controller_lines(loop, joint))
    if action != "use":
        raise ConsoleError(VALUE, f"controller {action!r}: use 'controller list' or 'controller use NAME [joint]'")
    if not name:
        raise ConsoleError(ARGS, "controller use: give the controller's name (see 'controller list')")
    choices = getattr(loop, "controllers", None)
    if choices is None:
        raise ConsoleError(UNAVAILABLE, "this loop has no named controllers (a loop built from a rig file has)")
    joints = list(range(loop.n)) if joint is None else list(joint)
    try:
        use_controller(_law(loop), choices, loop.active_controller, name, joints, loop.period_s, s.delay)
    except GainRejected as e:
        where = f"{loop.names[e.joint]}: " if e.joint is not None else ""
        raise ConsoleError(GAIN, f"controller {name} rejected ({where}{e.reason}); nothing was changed") from None
    except ControlError as e:
        raise ConsoleError(VALUE, f"{e}; nothing was changed") from None
    where = "all joints" if joint is None else ",".join(loop.names[j] for j in joint)
    loop.note(s.source, f"controller {name} on {where}")
    return Outcome(_controller_lines(loop, joint), kv(applied_at_tick=int(loop.tick_count)))


@atom("filter", (Param("joint", JOINT, "all"), Param("cutoff_hz", FLOAT, None)),
      "show the velocity filter (the alternative to KvI), or set its cutoff in Hz for one joint or all (0: off, "
      "KvI integrates the velocity error); switched bumpless at the next tick, checked by servo.gain_guard")
def _filter(s: Session, a: dict[str, Any]) -> Outcome:
    loop = s.loop
    law = _law(loop)
    joint, hz = a["joint"], a["cutoff_hz"]
    if hz is None:
        return Outcome(_controller_lines(loop, joint))
    if not (math.isfinite(hz) and hz >= 0.0) or hz >= 0.5 / loop.period_s:
        raise ConsoleError(VALUE, f"cutoff_hz {hz:g}: a number of Hz in 0 (off) .. {0.5 / loop.period_s:g} "
                                  "(the Nyquist frequency)")
    f_hz = math.nan if hz == 0.0 else float(hz)
    joints = list(range(loop.n)) if joint is None else [joint]
    g = getattr(law, "_pending_gains", None) or law.gains
    so = getattr(law, "_pending_switch_off", None) or law.switch_off
    try:
        for j in joints:
            f = law.filter_hz.copy()
            f[j] = f_hz
            check_gain_set(g, so, {}, loop.period_s, s.delay, joint=j, filter_hz=f)
    except GainRejected as e:
        where = f"{loop.names[e.joint]}: " if e.joint is not None else ""
        raise ConsoleError(GAIN, f"filter {hz:g} Hz rejected ({where}{e.reason}); nothing was changed") from None
    for j in joints:
        law.switch_joint(j, g.joint(j), f_hz)
    where = "all joints" if joint is None else loop.names[joint]
    loop.note(s.source, f"velocity filter {'off' if hz == 0 else f'{hz:g} Hz'} on {where}")
    return Outcome([], kv(applied_at_tick=int(loop.tick_count)))


@atom("stop", (), "controlled stop (category 1): decelerate, brakes, then amplifiers off; cancels compound "
      "commands")
def _stop(s: Session, a: dict[str, Any]) -> Outcome:
    loop = s.loop
    category = loop.stop("operator_stop", f"stop from the {s.source}")
    if s.executor is not None:
        s.executor.cancel_all("stopped by the operator")
    loop.note(s.source, "stop")
    return Outcome(ok=kv(state=loop_state(loop), category=int(category)))


@atom("estop", (), "emergency stop (category 0): amplifiers off and brakes at once; cancels compound commands")
def _estop(s: Session, a: dict[str, Any]) -> Outcome:
    loop = s.loop
    loop.stop("estop", f"emergency stop from the {s.source}")
    if s.executor is not None:
        s.executor.cancel_all("emergency stop by the operator")
    loop.note(s.source, "estop")
    return Outcome(ok=kv(state=loop_state(loop), category=0))


@atom("enable", (), "clear faults and enable the amplifiers, holding the joints where they are")
def _enable(s: Session, a: dict[str, Any]) -> Outcome:
    loop = s.loop
    if loop.enabled and loop.fault is None:
        return Outcome(["INFO already enabled"], kv(state=loop_state(loop)))
    previous = loop.fault
    try:
        loop.resume(hold_measured=True)
    except ValueError as e:
        raise ConsoleError(STATE, f"{e}; the loop stays stopped") from None
    except Exception as e:
        what = "enable failed" if loop.fault is not None and loop.fault is not previous else "cannot read the joints"
        raise ConsoleError(STATE, f"{what} ({type(e).__name__}: {e}); fix the cause first, the loop stays "
                                  "stopped") from None
    loop.note(s.source, "enable" + (f" (cleared fault {previous.cause})" if previous else ""))
    return Outcome(ok=kv(state=loop_state(loop), cleared=previous.cause if previous else "-"))


#: the largest motion or compound command file the console reads (a hand-written TOML is a few kB)
MAX_CONSOLE_FILE_BYTES = 1 << 20


def check_console_file(path: str, what: str) -> None:
    """Refuse anything but a regular file under :data:`MAX_CONSOLE_FILE_BYTES` before opening it:
    the reader thread that prepares ``run``/``load`` must never block (a FIFO) or read without
    end (``/dev/zero``), or ``stop`` would no longer be heard."""
    try:
        st = os.stat(path)
    except FileNotFoundError as e:
        raise ConsoleError(FILE, f"{what} {path!r} not found ({e.strerror or e})") from None
    except OSError as e:
        raise ConsoleError(FILE, f"{what} {path!r}: {e.strerror or e}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ConsoleError(FILE, f"{what} {path!r} is not a regular file")
    if st.st_size > MAX_CONSOLE_FILE_BYTES:
        raise ConsoleError(FILE, f"{what} {path!r} has {st.st_size} bytes; the limit is {MAX_CONSOLE_FILE_BYTES}")


def _prepare_run(a: dict[str, Any], n_joints: int) -> dict[str, Any]:
    from hal.config import ConfigError
    from servo.motion import load_motion

    check_console_file(a["file"], "motion file")
    try:
        motion = load_motion(a["file"], n_joints)
    except FileNotFoundError as e:
        raise ConsoleError(FILE, f"motion file {a['file']!r} not found ({e.strerror or e})") from None
    except (ConfigError, OSError, ValueError) as e:
        raise ConsoleError(FILE, f"motion file {a['file']!r}: {e}") from None
    return {**a, "motion": motion}


@atom("run", (Param("file", STRING),), "play a motion file (TOML, see docs/control.md) from the present target")
def _run(s: Session, a: dict[str, Any]) -> Outcome:
    motion = a.get("motion")
    if motion is None:  # not prepared off the loop thread (direct API use)
        motion = _prepare_run(a, s.n)["motion"]
    return start_motion(s, list(motion.moves), f"run {motion.name} ({a['file']})", a.get("planned"))


@atom("calibrate", (), "calibrate PROCEDURE [--joint N ...] [--auto]: pot, adc, dac, encoder, amplifier, friction, "
                       "all (as vmehil calibrate, on the running rig; stop aborts)", varargs=True, in_files=False)
def _calibrate(s: Session, a: dict[str, Any]) -> Outcome:
    if s.calibrate is None:
        raise ConsoleError(UNAVAILABLE, "calibrate: not available here: this console's host has no rig for it "
                                        "(vmehil console and vmehil run --console on an emulated rig offer it)")
    return s.calibrate(s, a.get("args", []))


@atom("home", (Param("joint", JOINT),), "home JOINT's encoder (or all) to the motor index its calibrated pot "
      "chooses: calibrate home --joint JOINT, as vmehil calibrate home; stop aborts", in_files=False)
def _home(s: Session, a: dict[str, Any]) -> Outcome:
    if s.calibrate is None:
        raise ConsoleError(UNAVAILABLE, "home: not available here: this console's host has no rig for it "
                                        "(vmehil console and vmehil run --console on an emulated rig offer it)")
    from vmehil.console.protocol import Arg

    joint = a["joint"]
    which = "all" if joint is None else s.loop.names[joint]
    if joint is not None and homed_word(s.loop, joint) == "exempt":
        raise ConsoleError(VALUE, f"home: {which} is exempt: it has no pot to choose an index by (a continuous "
                                  "joint, its loop closes on the encoder)")
    return s.calibrate(s, [Arg(None, "home"), Arg("joint", which)], command="home")


@atom("log", (Param("count", INT, 20),), "the last COUNT entries of the loop's change log (time, source, message)")
def _log(s: Session, a: dict[str, Any]) -> Outcome:
    count = a["count"]
    if not 1 <= count <= MAX_LOG_LINES:
        raise ConsoleError(VALUE, f"count {count} must be within 1..{MAX_LOG_LINES}")
    loop = s.loop
    # the change log and every fault of the run (a resume clears the current fault, not its
    # entry here), in time order; faults sort after a note of the same instant
    entries = [(t, 0, src, msg) for t, src, msg in loop.log]
    entries += [(f.time_s, 1, "watchdog", f"fault {f.cause}" + (f" ({f.joint})" if f.joint else "") + f": {f.detail}")
                for f in loop.faults]
    shown = sorted(entries, key=lambda e: (e[0], e[1]))[-count:]
    lines = [kv("DATA", "log", t_s=t, source=src, message=msg) for t, _, src, msg in shown]
    return Outcome(lines, kv(entries=len(lines), total=len(entries) + loop.log_dropped))


@atom("commands", (), "list the compound commands loaded from files", in_files=False)
def _commands(s: Session, a: dict[str, Any]) -> Outcome:
    lib = s.library
    lines = [kv("DATA", "command", name=d.name, usage=d.usage(), where=d.where) for d in (lib.values() if lib else [])]
    return Outcome(lines, kv(count=len(lines)))


@atom("load", (Param("file", STRING),), "load (or reload) a compound command file, replacing the loaded commands",
      in_files=False)
def _load(s: Session, a: dict[str, Any]) -> Outcome:
    # The file was read off-loop by vmehil.console.compound.prepare (load is not allowed in files).
    lib = a.get("library")
    if lib is None:
        raise ConsoleError(INTERNAL, "load: the file was not read before the command ran")
    s.library = lib
    s.loop.note(s.source, f"loaded {len(lib)} compound command(s) from {a['file']}")
    return Outcome([kv("DATA", "command", name=d.name, usage=d.usage(), where=d.where) for d in lib.values()],
                   kv(count=len(lib)))


@atom("cancel", (Param("id", INT, 0),), "cancel a running compound command (by id), or all of them (0)",
      in_files=False)
def _cancel(s: Session, a: dict[str, Any]) -> Outcome:
    if s.executor is None:
        return Outcome(ok=kv(cancelled=0))
    if a["id"] == 0:
        n = s.executor.cancel_all("cancelled by the operator")
    else:
        n = s.executor.cancel(a["id"], "cancelled by the operator")
        if n == 0:
            raise ConsoleError(VALUE, f"no running compound command with id {a['id']}")
    return Outcome(ok=kv(cancelled=n))


@atom("pause", (Param("seconds", FLOAT),), "in a compound command: wait SECONDS of loop time", on_line=False)
def _pause(s: Session, a: dict[str, Any]) -> Outcome:
    sec = a["seconds"]
    if not (math.isfinite(sec) and 0.0 <= sec <= 86400.0):
        raise ConsoleError(VALUE, f"pause {sec!r} s must be within 0..86400")
    return Outcome(ok=kv(seconds=sec), pause_ticks=round(sec / s.loop.period_s))


@atom("echo", (Param("text", STRING),), "print TEXT (an INFO line; an EVT line inside compound commands)")
def _echo(s: Session, a: dict[str, Any]) -> Outcome:
    return Outcome([f"INFO {a['text']}"])


@atom("shutdown", (), "end the session that owns the loop (vmehil console): safe stop, then exit", in_files=False)
def _shutdown(s: Session, a: dict[str, Any]) -> Outcome:
    if s.shutdown is None:
        raise ConsoleError(UNAVAILABLE, "shutdown: this loop is owned by vmehil run and ends with its --duration")
    # category 1; the session's host completes it and watches the joints 2 s before it exits
    category = s.loop.stop("operator_shutdown", f"shutdown from the {s.source}")
    if s.executor is not None:
        s.executor.cancel_all("shutdown")
    s.shutdown()
    return Outcome(ok=kv(state=loop_state(s.loop), category=int(category)))


@atom("open", (Param("amps", FLOAT, None),), "open the fingers at a fixed current (A; default 0.5)")
def _open(s: Session, a: dict[str, Any]) -> Outcome:
    lines, ok, until = fingers.finger(s.loop, "open", a["amps"], s.source, _require_running)
    return Outcome(lines, ok, until=until)


@atom("close", (Param("amps", FLOAT, None),), "close the fingers at a fixed current (A; default 0.5): they stop "
      "on an object")
def _close(s: Session, a: dict[str, Any]) -> Outcome:
    lines, ok, until = fingers.finger(s.loop, "close", a["amps"], s.source, _require_running)
    return Outcome(lines, ok, until=until)


@atom("squeeze", (Param("amps", FLOAT, None),), "squeeze the fingers at a fixed current (A; default 1.0)")
def _squeeze(s: Session, a: dict[str, Any]) -> Outcome:
    lines, ok, until = fingers.finger(s.loop, "squeeze", a["amps"], s.source, _require_running)
    return Outcome(lines, ok, until=until)


@atom("grasp", (Param("object", STRING, None),), "check the grasp: the tactile switches against the hand pot (and "
      "the OBJECT's width); ERR GRASP when they disagree")
def _grasp(s: Session, a: dict[str, Any]) -> Outcome:
    return Outcome(ok=fingers.grasp(s.loop, a["object"]))


@atom("weigh", (), "estimate the held object's mass from the joints' current monitors through the arm's Jacobian")
def _weigh(s: Session, a: dict[str, Any]) -> Outcome:
    return Outcome(ok=fingers.weigh(s.loop, s.source, _require_running))


#: The atomic commands by name, in the order of ``help``.
ATOMS: dict[str, Atom] = {a.name: a for a in (
    _help, _status, _move, _move_rel, _move_joint, _move_to, _stay, _gains, _controller, _filter, _mode, _stop,
    _estop, _enable, _run, _calibrate, _home, _jog, _log, _commands, _load, _cancel, _pause, _echo, _shutdown,
    _obstacle,
    _open, _close, _squeeze, _grasp, _weigh,
)}


def prepare(name: str, bound: dict[str, Any], n_joints: int, names: list[str], loop: Any = None) -> dict[str, Any]:
    """The off-loop phase of an atom that reads a motion file (``run``) or plans a Cartesian move
    (``move_to``); returns the arguments to run with (with ``loop``, the motion planned off the
    loop too: :func:`plan_off_loop`). ``load``
    reads its file in :func:`vmehil.console.compound.prepare`, which wraps this."""
    if name == "run":
        out = _prepare_run(bound, n_joints)
        if loop is not None:
            out["planned"] = plan_off_loop(list(out["motion"].moves), loop)
        return out
    if name == "move_to":  # a straight approach is a tabulated path (tens of ms): planned off the loop too
        out = {**bound, "moves": _move_to_moves(bound)}
        if loop is not None:
            out["planned"] = plan_off_loop(out["moves"], loop)
        return out
    return bound


def bind_request(a: Atom, args: tuple[Arg, ...] | list[Arg], n_joints: int, names: list[str]) -> dict[str, Any]:
    """Bind the arguments of a request line to atom ``a``."""
    if a.varargs:
        return {"args": list(args)}
    return bind(a.name, a.params, [(x.key, x.value) for x in args], n_joints, names)
