"""``calibrate`` on the console: the calibration procedures of ``vmehil calibrate`` run on the rig
the live loop drives, with the live loop as the procedures' servo loop.

    calibrate PROCEDURE [--joint N ...] [--auto]      PROCEDURE: pot adc dac encoder amplifier friction all
    (also joint=N, auto=1)

How it runs (see docs/console.md, "calibrate"):

1. At a tick boundary (the console's pump) the request is checked: a known procedure, joints
   1..n, ``--auto`` where a procedure would prompt for angles, the loop running, no motion and no
   compound command running, no other calibration — else ``ERR ARGS/VALUE/STATE`` and nothing
   happened. The loop is put on a hold of its present target and a job is handed to the console.
2. The job runs between two ticks in the thread that ticks the loop (the loop does not tick
   meanwhile except through the procedures): :func:`vmehil.calibration.procedure_runner.run_procedures`
   with a :class:`CalibrationContext` on the same crate and drivers, and a :class:`LoopPositioner`
   that moves the joints with the *live* :class:`~servo.loop.ServoLoop` (its gains, watchdog,
   recorder and tick count). Progress and the procedures' remarks stream as ``INFO`` lines.
3. At the end: one ``DATA calibration`` line per check, and ``OK calibrate`` (all passed, file
   written atomically and put in force in the drivers) or ``ERR`` (``VALUE``: a check failed,
   ``STATE``: the procedure stopped — a fault, ``stop``, missing wiring). Whenever no file was
   written the drivers are put back exactly as they were before.

``stop`` during a calibration reaches the loop at its next tick (the procedures' ticks drain the
loop's inbox), safe-stops it and so aborts the procedure; the loop then stays stopped until
``enable``. Other commands wait in the console's queue until the calibration has ended.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from servo.trajectory.sequencer import Sequencer
from vmehil.calibration.procedures import ALL, procedures_in_order
from vmehil.calibration.store import CalibrationStore
from vmehil.console.commands import (
    Outcome,
    Session,
    _plan_context,
    _require_idle,
    _require_running,
    hold_position,
    resolve_joint,
)
from vmehil.console.protocol import ARGS, FILE, STATE, VALUE, Arg, ConsoleError, kv
from vmehil.rig_setup.emulated_calibration import EmulatedFixture, EmulatedPositioner
from vmehil.rig_setup.system import EmulatedRig

#: procedures that ask the operator for reference angles unless ``--auto`` (the console cannot prompt)
PROMPTING = ("pot",)
PROGRESS_STEP = 0.1  # an INFO progress line at most every 10 % of a step


@dataclass(frozen=True)
class CalibrationRequest:
    """A checked ``calibrate`` request: ``procedure`` as typed, the procedure ``names`` to run,
    ``joints`` (0-based, None = all) and ``auto``."""

    procedure: str
    names: tuple[str, ...]
    joints: tuple[int, ...] | None
    auto: bool
    #: the console command whose reply this is (``calibrate``; ``home`` for ``home J``)
    command: str = "calibrate"


def parse_request(args: list[Arg], names: list[str]) -> CalibrationRequest:
    """``PROCEDURE [--joint N ...] [--auto]`` (or ``joint=N``, ``auto=1``) → a request;
    :class:`ConsoleError` ARGS/VALUE naming what is wrong."""
    from vmehil.calibration.procedure_runner import resolve_procedure_names

    choices = f"{ALL}, {', '.join(p.name for p in procedures_in_order())}"
    usage = "usage: calibrate PROCEDURE [--joint N ...] [--auto]"
    procedure: str | None = None
    joints: list[int] = []
    auto = False
    items = list(args)
    i = 0
    while i < len(items):
        a = items[i]
        i += 1
        key, value = a.key, a.value
        if key is None and isinstance(value, str) and value.startswith("--"):
            word, sep, rest = value[2:].partition("=")
            if word == "auto" and not sep:
                auto = True
                continue
            if word == "joint":
                if sep:
                    value = int(rest) if rest.lstrip("+-").isdigit() else rest
                elif i < len(items) and items[i].key is None:
                    value = items[i].value
                    i += 1
                else:
                    raise ConsoleError(ARGS, f"calibrate: --joint needs a joint number or name; {usage}")
                key = "joint"
            else:
                raise ConsoleError(ARGS, f"calibrate: unknown option {value!r}; {usage}")
        if key == "joint":
            if isinstance(value, tuple) or isinstance(value, float):
                raise ConsoleError(ARGS, f"calibrate: joint must be a number 1..{len(names)} or a name")
            j = resolve_joint(value, names)
            if j is None:
                joints = []  # "all"
            elif j not in joints:
                joints.append(j)
            continue
        if key == "auto":
            if value not in (0, 1):
                raise ConsoleError(VALUE, "calibrate: auto=1 (use the reference fixture) or auto=0")
            auto = bool(value)
            continue
        if key is not None:
            raise ConsoleError(ARGS, f"calibrate has no argument {key!r}; {usage}")
        if procedure is not None:
            raise ConsoleError(ARGS, f"calibrate: one procedure at a time (got {procedure!r} and {value!r}); {usage}")
        if not isinstance(value, str):
            raise ConsoleError(ARGS, f"calibrate: the procedure is a name ({choices}), got {value!r}")
        procedure = value
    if procedure is None:
        raise ConsoleError(ARGS, f"calibrate: which procedure? ({choices}); {usage}")
    try:
        run = resolve_procedure_names(procedure)
    except ValueError:
        raise ConsoleError(VALUE, f"calibrate: no procedure {procedure!r}; choose from {choices}") from None
    if not auto:
        needs = [n for n in run if n in PROMPTING]
        if needs:
            raise ConsoleError(ARGS, f"calibrate {procedure}: {', '.join(needs)} asks for reference angles, and the "
                                     "console cannot prompt; add --auto (the rig's reference fixture), or run "
                                     "`vmehil calibrate` at a terminal")
    return CalibrationRequest(procedure, tuple(run), tuple(joints) if joints else None, auto)


class LoopPositioner(EmulatedPositioner):
    """The procedures' :class:`~vmehil.calibration.base.Positioner` on the live loop: the same rig
    (crate, plant, drivers) and the same :class:`~servo.loop.ServoLoop` object the console
    serves. Ticks are those of :class:`servo.runner.LockstepRunner` (tick ``k`` at ``k·T`` of the
    crate's clock) with the positioner's hooks (``on_tick`` after the sensors were published,
    ``override_command`` after the loop's command); the runner's ``after_tick`` hooks do not run."""

    def __init__(self, system: EmulatedRig, loop: Any, store: CalibrationStore | None = None) -> None:
        self.system = system
        self.io = system.io
        if loop.io is not system.io:
            raise ValueError("the live loop does not drive this rig's drivers")
        if store is not None:
            self.io.apply_calibration(store)
        self.period_s = system.rig.period_s
        self.loop = loop
        sync_tick_count(loop, system)
        if loop.fault is not None or not loop.enabled:
            from vmehil.calibration.base import CalibrationAbort

            raise CalibrationAbort("the servo loop is stopped" + (f" ({loop.fault.cause})" if loop.fault else ""))
        hold = hold_position(loop)
        loop.set_motion(Sequencer([], hold, _plan_context(loop)))
        self._theta_d = hold
        self._override: dict[int, float] = {}
        self._t0_ns = 0


def sync_tick_count(loop: Any, system: EmulatedRig) -> None:
    """Make the loop's next tick lie at or after the crate's present time (a procedure that ran
    its own loop on the rig, like ``friction``, moved the clock on): runners put tick ``k`` at
    ``k·T``, and a clock that is ahead would never run the boards' pending events."""
    now = int(system.crate.clock.now_ns)
    period = system.period_ns
    if loop.tick_count * period < now:
        loop.tick_count = -(-now // period)


def _snapshot(io: Any) -> Callable[[], None]:
    """What the drivers have in force now; the returned function puts it back."""
    adc = {n: d.calibration for n, d in io.adc.items()}
    dac = {n: d.calibration for n, d in io.dac.items()}
    pot = dict(io.pot_cal)
    scaling = [(s.encoder_counts_per_rev, s.amp_gain_a_per_v, s.amp_offset_a) for s in io.scaling]
    quad = {n: dict(q.counts_per_rev_x4) for n, q in io.quad.items()}
    store = io.calibration

    def restore() -> None:
        for n, c in adc.items():
            io.adc[n].calibration = c
        for n, c in dac.items():
            io.dac[n].calibration = c
        io.pot_cal.clear()
        io.pot_cal.update(pot)
        for s, (cpr, gain, off) in zip(io.scaling, scaling, strict=True):
            s.encoder_counts_per_rev, s.amp_gain_a_per_v, s.amp_offset_a = cpr, gain, off
        for n, c in quad.items():
            io.quad[n].counts_per_rev_x4 = dict(c)
        io.calibration = store

    return restore


class ConsoleCalibrator:
    """The console's ``calibrate`` hook for a loop driving emulated rig ``system``; results go to
    the calibration file ``path`` (default: the rig's, as ``vmehil calibrate`` and ``vmehil run``
    use). Pass it as ``Console(calibrate=...)``."""

    def __init__(self, system: EmulatedRig, path: str | Path | None = None) -> None:
        from vmehil.calibration.store import default_store_path

        self.system = system
        self.path = Path(path) if path is not None else default_store_path(system.rig)
        self.running = False

    # ---- in the pump (a tick boundary) ----------------------------------------------------------
    def __call__(self, s: Session, args: list[Arg], command: str = "calibrate") -> Outcome:
        """``calibrate ARGS``; ``command``: the console command the reply is named after (``home J``
        runs ``calibrate home --joint J`` and answers ``OK home …``)."""
        loop = s.loop
        req = replace(parse_request(list(args), list(loop.names)), command=command)
        if self.running:
            raise ConsoleError(STATE, "a calibration is already running; wait for its OK/ERR line")
        if s.defer is None:
            raise ConsoleError(STATE, "calibrate needs a console that runs long commands between ticks")
        _require_running(loop)
        _require_idle(loop)
        if s.executor is not None and s.executor.active:
            raise ConsoleError(STATE, "compound commands are running: cancel them (cancel) or wait, then calibrate")
        store = self._store_in_force()
        loop.set_motion(Sequencer([], hold_position(loop), _plan_context(loop)))  # the safe hold
        self.running = True
        try:
            s.defer(lambda send: self._job(s, req, store, send))
        except Exception:
            self.running = False
            raise
        joints = ",".join(loop.names[j] for j in req.joints) if req.joints else "all"
        loop.note(s.source, f"calibrate {req.procedure} (joints {joints}{', auto' if req.auto else ''})")
        return Outcome([kv("INFO", f"calibrating {', '.join(req.names)} on rig {self.system.rig.name}:",
                           joints=joints, auto=req.auto, file=str(self.path)),
                        "INFO the loop holds the joints; the procedures move them with it; stop aborts"],
                       deferred=True)

    def _store_in_force(self) -> CalibrationStore:
        from vmehil.calibration.store import CalibrationFileError, load_store

        if not self.path.exists():
            return CalibrationStore.empty(self.system.rig)
        try:
            return load_store(self.path, self.system.rig)
        except (CalibrationFileError, OSError, ValueError) as e:
            raise ConsoleError(FILE, f"calibration file {self.path} refused: {e}") from None

    # ---- the job (between ticks, the thread that ticks the loop) --------------------------------
    def _job(self, s: Session, req: CalibrationRequest, store: CalibrationStore,
             send: Callable[[list[str]], None]) -> None:
        from vmehil.calibration.base import CalibrationAbort, CalibrationContext
        from vmehil.calibration.procedure_runner import run_procedures
        from vmehil.calibration.store import load_store

        loop, system = s.loop, self.system
        restore = _snapshot(system.io)
        ticks0 = loop.tick_count
        last_progress: dict[str, float] = {}

        def say(text: str) -> None:
            send([f"INFO {ln}" if ln.strip() else "INFO" for ln in str(text).splitlines() or [""]])

        def progress(what: str, i: int, n: int) -> None:
            if n <= 0:
                return
            frac = min(1.0, i / n)
            prev = last_progress.get(what)
            if prev is not None and frac < 1.0 and frac - prev < PROGRESS_STEP:
                return
            last_progress[what] = frac
            send([f"INFO progress {what}: {100 * frac:.0f}%"])

        def no_prompt(question: str) -> str:
            raise CalibrationAbort("the procedure asks for a reference angle and the console cannot prompt; "
                                   "use --auto")

        ctx = CalibrationContext(
            rig=system.rig, bus=system.crate, store=store, auto=req.auto,
            fixture=EmulatedFixture(system) if req.auto else None,
            positioner_factory=lambda st: LoopPositioner(system, loop, st),
            joints=list(req.joints) if req.joints is not None else None,
            prompt=no_prompt, say=say, progress=progress, options={"report": None})
        outcome = None
        try:
            outcome = run_procedures(ctx, list(req.names), out_path=self.path)
            if outcome.written is not None:
                restore()
                system.io.apply_calibration(load_store(outcome.written, system.rig))
            else:
                restore()
        except BaseException:
            restore()
            raise
        finally:
            self.running = False
            sync_tick_count(loop, system)
            if loop.fault is None and loop.enabled:
                loop.set_motion(Sequencer([], hold_position(loop), _plan_context(loop)))
        lines = []
        for r in outcome.results:
            if r.procedure == "home":  # what homing found, per joint (docs/console.md, "home")
                for name, v in r.data.get("joints", {}).items():
                    lines.append(kv("DATA", "home", joint=name, index_deg=round(math.degrees(v["index_angle_rad"]), 6),
                                    index_counts=v["index_counts"], offset_counts=v["offset_counts"],
                                    pot_minus_index_deg=round(math.degrees(v["pot_minus_index_rad"]), 4),
                                    homed="yes" if system.io.homed[loop.names.index(name)] else "no"))
            for c in r.checks:
                lines.append(kv("DATA", "calibration", procedure=r.procedure, item=c.item,
                                value=float(c.value),
                                unit=c.unit, limit=float(c.limit), kind=c.kind, result="pass" if c.passed else "FAIL"))
            for sk in r.skipped:
                lines.append(kv("DATA", "calibration", procedure=r.procedure, item=sk, result="skipped"))
        seconds = (loop.tick_count - ticks0) * loop.period_s
        result = f"written {outcome.written}" if outcome.written else f"not written ({outcome.error or 'FAIL'})"
        loop.note(s.source, f"calibrate {req.procedure}: {result}")
        failed = sum(not c.passed for r in outcome.results for c in r.checks)
        if outcome.error is not None:
            f = loop.fault
            where = f" (the loop stopped: {f.cause})" if f is not None else ""
            # `home J` names its one procedure already: its abort's own sentence, once (before:
            # "ERR STATE home home: home: CalibrationAbort: j2: …")
            why = (f"{req.command}: {outcome.reason}" if req.command == req.procedure and outcome.reason
                   else f"{req.command} {req.procedure}: {outcome.error}")
            lines.append(f"ERR {STATE} {why}{where}; "
                         f"{self.path} left unchanged" + (", enable to servo again" if f is not None else ""))
        elif outcome.unchanged:
            # every check passed and no entry changed (friction writes none): nothing to write is
            # success, not a failed check
            lines.append(kv("OK", req.command, procedures=",".join(req.names),
                            checks=sum(len(r.checks) for r in outcome.results), written="unchanged",
                            loop_s=round(seconds, 3),
                            state="running" if loop.fault is None and loop.enabled else "stopped"))
        elif outcome.written is None:
            lines.append(f"ERR {VALUE} {req.command} {req.procedure}: {failed} check(s) failed; "
                         f"{self.path} left unchanged")
        else:
            checks = sum(len(r.checks) for r in outcome.results)
            lines.append(kv("OK", req.command, procedures=",".join(req.names), checks=checks,
                            written=str(outcome.written), loop_s=round(seconds, 3),
                            state="running" if loop.fault is None and loop.enabled else "stopped"))
        send(lines)


def calibrator_for(system: Any, path: str | Path | None = None) -> ConsoleCalibrator | None:
    """The hook for ``system`` if it is an emulated rig whose drivers the loop uses, else None."""
    if isinstance(system, EmulatedRig):
        return ConsoleCalibrator(system, path)
    return None


__all__ = ["CalibrationRequest", "ConsoleCalibrator", "LoopPositioner", "calibrator_for", "parse_request",
           "sync_tick_count"]
