"""``vmehil plan``: check a motion file against the joints' soft limits and the scene's obstacles
without running it (docs/motion-safety.md).

    vmehil plan MOTION [--rig NAME|PATH] [--scene PATH|none] [--start-deg A,B,...] [--seed N]
                       [--calibration PATH] [--json PATH]

Every move is planned as ``vmehil run`` plans it — from where the joints are (read through the
drivers of the emulated rig, nothing enabled; ``--start-deg``: from these angles instead) — and
checked: each move's boundary and via points against ``[joint.limits]``, its path at the
rig's ``collision_check_points`` (20) instants against every obstacle. Prints one line per
refusal (or that the motion is clear); exit 0 when clear, 2 when refused. ``--json``:
``{"ok": bool, "refusals": [{"kind", "joint", "link", "obstacle", "point_index", "t_s", …}], …}``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

from vmehil.errors import CliError
from vmehil.exit_status import EXIT_OK, EXIT_USAGE
from vmehil.option_groups.cli_types import seed
from vmehil.option_groups.scene_options import add_scene_argument, resolve_scene
from vmehil.writers.files import write_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="check a motion file against the soft limits and the scene, without running it",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("motion", metavar="MOTION", help="motion file (TOML)")
    p.add_argument("--rig", metavar="NAME|PATH", default=None, help="rig preset name or TOML path (default jpl-arm)")
    add_scene_argument(p)
    p.add_argument("--start-deg", metavar="A,B,...", default=None,
                   help="plan from these joint angles (degrees, one per joint) instead of where the "
                        "emulated rig's joints read")
    p.add_argument("--seed", metavar="N", type=seed, default=0, help="seed of the emulated rig read for the start")
    p.add_argument("--calibration", metavar="PATH", default=None,
                   help="calibration file for the drivers that read the start (default as vmehil run's)")
    p.add_argument("--json", metavar="PATH", default=None, help="write the verdict and the refusals here")
    p.set_defaults(func=run, options=PlanOptions.from_args)


def _angles(text: str | None) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        values = tuple(float(x) for x in text.replace(" ", "").split(",") if x)
    except ValueError:
        raise CliError(f"--start-deg {text!r}: angles in degrees separated by commas (0,10,-5,...)") from None
    if not values or not all(np.isfinite(values)):
        raise CliError(f"--start-deg {text!r}: finite angles in degrees separated by commas")
    return values


@dataclass(frozen=True)
class PlanOptions:
    """``vmehil plan``'s options."""

    motion: str
    rig: str | None = None
    scene: str | None = None
    start_deg: tuple[float, ...] | None = None
    seed: int = 0
    calibration: str | None = None
    json: str | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> PlanOptions:
        return cls(motion=args.motion, rig=args.rig, scene=args.scene, start_deg=_angles(args.start_deg),
                   seed=args.seed, calibration=args.calibration, json=args.json)


def _start(opts: PlanOptions, rig: Any) -> np.ndarray:
    """Where the motion starts: ``--start-deg``, else the emulated rig's joints as its drivers read
    them (nothing is enabled)."""
    if opts.start_deg is not None:
        if len(opts.start_deg) != rig.n_joints:
            raise CliError(f"--start-deg: {rig.n_joints} angles for rig {rig.name}, got {len(opts.start_deg)}")
        return np.radians(np.asarray(opts.start_deg, float))
    from vmehil.commands.calibration_file import calibrated
    from vmehil.rig_setup.system import build_emulated_rig

    system = calibrated(opts.calibration, rig, lambda cal: build_emulated_rig(rig, seed=opts.seed, calibration=cal))
    try:
        return np.asarray(system.io.read().theta, float).copy()
    finally:
        system.close()


def plan_motion(moves: list[Any], start: np.ndarray, ctx: Any) -> tuple[list[Any], list[str], float]:
    """Plan ``moves`` from ``start`` one after the other, each checked against ``ctx.bounds`` by
    the sequencer's own check: the refusals of every move (a refused move is planned on from its
    planned end, so the later ones are judged too), notes on what cannot be judged before the run,
    and the total duration of the moves planned (s)."""
    from servo.trajectory import MotionRefused, PlanContext, Sequencer

    refusals: list[Any] = []
    notes: list[str] = []
    total = 0.0
    position = np.asarray(start, float)
    for i, move in enumerate(moves):
        if move.kind == "vservo":  # open: its targets come from the vision system while it runs
            notes.append(f"move {i + 1} (vservo): its targets come at run time and are checked then, each one; "
                         f"the {len(moves) - i - 1} move(s) after it are checked when they start")
            break
        seq = Sequencer([move], position, ctx)
        err = seq.plan_error
        if isinstance(err, MotionRefused):
            refusals.extend(_renumbered(r, i) for r in err.refusals)
            try:  # unchecked (a Cartesian move keeps the arm, not the limits): to go on from its end
                traj = move.build(position, PlanContext(ctx.limits, ctx.extras, _unchecked(ctx.bounds)))
            except MotionRefused:  # out of reach: no end to go on from
                if i + 1 < len(moves):
                    notes.append(f"move {i + 1} cannot be planned at all: the moves after it are planned from "
                                 "where it would start")
                continue
        elif err is not None:
            raise err
        else:
            traj = seq.planned[0]
        total += float(traj.duration)
        position = np.asarray(traj.end, float)
    return refusals, notes, total


def _unchecked(bounds: Any) -> Any:
    """``bounds`` without soft limits or scene: the arm model alone (a Cartesian move needs it)."""
    import dataclasses

    if bounds is None:
        return None
    n = len(bounds.names)
    return dataclasses.replace(bounds, min_rad=np.full(n, -np.inf), max_rad=np.full(n, np.inf), scene=None)


def _renumbered(refusal: Any, index: int) -> Any:
    """A refusal of a move checked on its own (move 1) as move ``index`` of the motion."""
    import dataclasses

    return dataclasses.replace(refusal, move=index,
                               detail=refusal.detail.replace("move 1:", f"move {index + 1}:", 1))


def run(opts: PlanOptions) -> int:
    from emulators.presets import resolve_rig
    from servo.assembly import plan_context
    from servo.motion import load_motion
    from servo.rig import load_rig
    from servo.settings import servo_settings

    rig = load_rig(resolve_rig(opts.rig))
    settings = servo_settings(rig)
    scene = resolve_scene(opts.scene, rig, settings)
    motion = load_motion(opts.motion, rig.n_joints)
    ctx = plan_context(settings, scene)
    start = _start(opts, rig)
    refusals, notes, total = plan_motion(list(motion.moves), start, ctx)
    bounds = ctx.bounds
    assert bounds is not None
    where = scene.source if scene is not None else "none"
    n_obstacles = len(scene) if scene is not None else 0
    print(f"plan {motion.name}: {len(motion.moves)} move(s) on {rig.name} from "
          f"[{', '.join(f'{x:.2f}' for x in np.degrees(start))}]°; soft limits of {rig.n_joints} joints; scene "
          f"{where} ({n_obstacles} obstacle(s){', no arm model: not checked' if settings.arm is None else ''}), "
          f"{bounds.points} points per move")
    for note in notes:
        print(f"  note: {note}")
    for r in refusals:
        print(f"  REFUSED {r.kind}: {r.detail}")
    ok = not refusals
    print(f"clear: {total:.3f} s of moves" if ok else f"refused: {len(refusals)} refusal(s)")
    if opts.json:
        write_json(opts.json, {"ok": ok, "motion": str(opts.motion), "rig": rig.name,
                               "scene": None if scene is None else scene.source,
                               "obstacles": n_obstacles, "points_per_move": bounds.points,
                               "start_deg": [round(float(x), 4) for x in np.degrees(start)],
                               "duration_s": round(total, 6), "notes": notes,
                               "refusals": [r.as_dict() for r in refusals]})
    sys.stdout.flush()
    return EXIT_OK if ok else EXIT_USAGE
