"""The plant, its exchange codec and the harness in lane mode (batched lockstep, issue #34).

B scalar plants (different seeds, one plant value varied per lane as a ``--vary`` study does)
are stacked with ``Plant.from_lanes`` into one plant of B·n joints; B more plants built alike
run scalar beside it (the twins: an independent execution of the same program). Every period,
every lane's sensors, encoder events and truth must equal its twin's bit for bit, and so must
the state and the noise generators at the end.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

from emulators.can.codec import DbcExchangeCodec
from emulators.harness import Harness, InProcessLink, JointNets
from emulators.plant import Plant, PlantCommand, PlantParams, PlantSensors, load_plant_params
from emulators.signals import QuadratureEvents, Signals
from hal.lanes import LaneSet, lane

T = 0.008  # servo period (s)
DELAY = 0.002  # computation delay (s)
B = 4
BASE = load_plant_params("jpl-arm")  # 7 joints: 6 linear amplifiers (brakes on some), an H-bridge; a watchdog
N = len(BASE.joints)


def _params(b: int) -> PlantParams:
    """Lane ``b``'s plant values: jpl-arm, one joint's value varied per lane."""
    p = copy.deepcopy(BASE)
    if b == 1:
        p.joints[2].link.inertia_kg_m2 *= 1.25
    if b == 2:
        p.joints[1].friction.coulomb_nm *= 1.3
    if b == 3:  # no viscous friction on joint 1: this plant's stick/slip step takes the guarded formulas
        p.joints[0].friction.viscous_nm_s_per_rad = 0.0
    return p


def _plants(seed0: int = 10, lanes: int = B) -> list[Plant]:
    out = [Plant(_params(b % B), seed=seed0 + b) for b in range(lanes)]
    out[0].amp_state.thermal[0] = 0.995  # lane 0's joint 1 amplifier hot: it trips when driven hard
    return out


def _command(rng: np.random.Generator, k: int, b: int, n: int = N) -> PlantCommand:
    """A period's command of lane ``b``: random volts, duty, direction; some enables low, the
    H-bridge braking now and then, the holding brakes' lines, fault resets; the watchdog line
    toggled every period, except lane 1 from period 60 on and lane 2 from period 100 on (their
    pumps run out inside a period, each in its own)."""
    c = PlantCommand.idle(n)
    c.amp_command_v = rng.normal(0.0, 2.0, n)
    if b == 0 and k < 60:
        c.amp_command_v[0] = 10.0  # the amplifier's current limit: it overheats
    c.amp_enable = rng.random(n) < (0.3 if b == 0 and 40 <= k < 50 else 0.9)
    c.pwm_duty = rng.random(n)
    c.pwm_direction = rng.random(n) < 0.5
    c.brake = rng.random(n) < 0.15
    c.holding_brake = rng.random(n) < 0.8
    c.fault_reset = rng.random(n) < 0.05
    if b == 1 and k >= 60:
        c.watchdog_line = True
    elif b == 2 and k >= 100:
        c.watchdog_line = False
    else:
        c.watchdog_line = bool(k & 1)
    return c


def _assert_sensors_equal(got: PlantSensors, want: PlantSensors, where: str) -> None:
    for f in ("pot_v", "tach_v", "imon_v", "amp_fault", "switching", "switching_noise_v"):
        a, w = np.asarray(getattr(got, f)), np.asarray(getattr(want, f))
        assert a.dtype == w.dtype and np.array_equal(a, w), f"{where}: {f}"
    assert got.encoder == want.encoder, f"{where}: encoder"
    assert got.truth.keys() == want.truth.keys(), where
    for key, w in want.truth.items():
        a = got.truth[key]
        assert a.dtype == w.dtype and np.array_equal(a, w), f"{where}: truth {key}"


def _gen_states(plant: Plant, src: str) -> list[Any]:
    return [g.bit_generator.state for g in plant._noise[src]._gens]


def test_stacked_plant_equals_its_scalar_twins_every_period_bit_for_bit():
    twins, lanes = _plants(), LaneSet(B)
    lp = Plant.from_lanes(_plants(), lanes)
    assert lp.n_joints == B * N and lp.n_lanes == B
    rng = np.random.default_rng(7)
    index_pulses = faults = braking = 0
    for k in range(130):
        if k == 30:  # the environment pushes lane 2's joint 4 (a torque gauge): its plant's flags change
            push = np.zeros(N)
            push[3] = 2.5
            twins[2].set_external_torque(push)
            lp.set_external_torque(np.concatenate([push if b == 2 else np.zeros(N) for b in range(B)]))
        cmds = [_command(rng, k, b) for b in range(B)]
        want = [p.step_period(c, T, DELAY) for p, c in zip(twins, cmds, strict=True)]
        got = lp.step_period(PlantCommand.from_lanes(cmds), T, DELAY)
        for b in range(B):
            _assert_sensors_equal(got.lane(b), want[b], f"period {k} lane {b}")
        index_pulses += sum(len(e.index_offsets) for w in want for e in w.encoder)
        faults += sum(int(w.amp_fault.sum()) for w in want)
        braking += sum(int(w.truth["brake_engaged"].sum()) for w in want)
    # the program reached what it is meant to exercise
    assert [p.watchdog.trips > 0 for p in twins] == [False, True, True, False]
    assert index_pulses > 0 and faults > 0 and braking > 0
    assert lanes.alive.all()
    # the state and the noise generators at the end
    for name in ("theta_m", "omega_m", "theta_l", "omega_l", "i", "tach_state"):
        assert np.array_equal(getattr(lp, name), np.concatenate([getattr(p, name) for p in twins])), name
    assert np.array_equal(lp.amp_state.cause, np.concatenate([p.amp_state.cause for p in twins]))
    assert np.array_equal(lp.brakes.engaged, np.concatenate([p.brakes.engaged for p in twins]))
    for src in ("pot", "tach", "imon"):
        assert _gen_states(lp, src) == [s for p in twins for s in _gen_states(p, src)], src
    for b, p in enumerate(twins):
        wd = lp.watchdog.lane(b)  # type: ignore[attr-defined]
        assert (wd.level, wd.last_edge_s, wd.trips) == (p.watchdog.level, p.watchdog.last_edge_s, p.watchdog.trips)


def test_a_joint_computes_the_same_wherever_it_sits_in_the_kernel_call():
    """The kernel computes each joint from its own column: a 7-joint call (a scalar plant) and a
    7·B-joint call with the same plant at any lane give the same bits (no cross-joint sums, no
    libm result that depends on the call's width)."""
    lanes_n = 24
    twins = _plants(100, lanes_n)
    lp = Plant.from_lanes(_plants(100, lanes_n), LaneSet(lanes_n))
    rng = np.random.default_rng(3)
    for k in range(25):
        cmds = [_command(rng, k, b % B) for b in range(lanes_n)]
        want = [p.step_period(c, T, DELAY) for p, c in zip(twins, cmds, strict=True)]
        got = lp.step_period(PlantCommand.from_lanes(cmds), T, DELAY)
        for b in range(lanes_n):
            _assert_sensors_equal(got.lane(b), want[b], f"period {k} lane {b}")


def test_a_stacked_plant_has_every_attribute_of_a_scalar_plant():
    """So that a state or parameter added to the scalar plant is not forgotten by the stacking."""
    p = _plants(lanes=1)[0]
    p.step_period(p.idle_command(), T, DELAY)
    lp = Plant.from_lanes(_plants(lanes=2), LaneSet(2))
    lp.step_period(lp.idle_command(), T, DELAY)
    missing = set(p.__dict__) - set(lp.__dict__) - {"_segments", "_active_faults"}
    assert not missing


def test_stacking_refuses_what_does_not_run_in_lanes():
    with pytest.raises(NotImplementedError, match="numpy path"):
        Plant.from_lanes([Plant(_params(0), kernel="numpy"), Plant(_params(1), kernel="numpy")], LaneSet(2))
    faulty = _plants(lanes=2)
    faulty[1].inject("tach_stuck", joint=BASE.joints[0].name)
    with pytest.raises(NotImplementedError, match="injected fault"):
        Plant.from_lanes(faulty, LaneSet(2))
    late = _plants(lanes=2)
    late[0].step_period(late[0].idle_command(), T)
    with pytest.raises(NotImplementedError, match="different times"):
        Plant.from_lanes(late, LaneSet(2))
    lp = Plant.from_lanes(_plants(lanes=2), LaneSet(2))
    with pytest.raises(NotImplementedError):
        lp.reset()
    with pytest.raises(NotImplementedError):
        lp.inject("tach_stuck", joint=BASE.joints[0].name)


# ---- the exchange codec ---------------------------------------------------------------------
def _wild_sensors(rng: np.random.Generator, n: int) -> PlantSensors:
    """An answer with values out of the wire's range, non-finite ones and index pulses."""
    pot = rng.normal(0.0, 8.0, n)
    pot[rng.random(n) < 0.1] = 40.0  # beyond ±16.78 V: clipped
    tach = rng.normal(0.0, 1.0, n)
    tach[rng.random(n) < 0.05] = np.nan
    events = [QuadratureEvents(counts=int(rng.integers(-3000, 3000)), illegal=int(rng.integers(0, 3)),
                               index_offsets=tuple(int(x) for x in rng.integers(-900, 900, int(rng.integers(0, 4)))),
                               phase=int(rng.integers(0, 4))) for _ in range(n)]
    return PlantSensors(pot_v=pot, tach_v=tach, imon_v=rng.normal(0.0, 3.0, n), amp_fault=rng.random(n) < 0.2,
                        encoder=events, switching=rng.random(n) < 0.5, switching_noise_v=rng.random(n),
                        truth={"theta_joint": rng.normal(size=n)})


@pytest.mark.parametrize("lanes_n", [3, 12])  # 3·7 values: the codec's small path; 12·7: its array path
def test_codec_quantizes_stacked_values_as_the_scalar_exchange_does(lanes_n):
    rng = np.random.default_rng(11)
    codec = DbcExchangeCodec()
    for _ in range(6):
        answers = [_wild_sensors(rng, N) for _ in range(lanes_n)]
        got = codec.sensors_lanes(PlantSensors.from_lanes(answers))
        for b, s in enumerate(answers):
            want = codec.sensors(s)
            g = got.lane(b)
            for f in ("pot_v", "tach_v", "imon_v", "amp_fault", "switching"):
                assert np.array_equal(getattr(g, f), getattr(want, f)), f
            assert g.encoder == want.encoder
            assert np.array_equal(g.truth["theta_joint"], want.truth["theta_joint"])
        cmds = []
        for b in range(lanes_n):
            c = _command(rng, b, b % B)
            c.amp_command_v[rng.random(N) < 0.1] = 99.0  # out of range: clipped
            c.amp_command_v[rng.random(N) < 0.05] = np.inf
            c.pwm_duty[0] = np.nan
            cmds.append(c)
        got_cmd = codec.command_lanes(PlantCommand.from_lanes(cmds))
        for b, c in enumerate(cmds):
            want_cmd, g_cmd = codec.command(c), got_cmd.lane(b, N)
            for f in ("amp_command_v", "amp_enable", "fault_reset", "pwm_duty", "pwm_direction", "brake",
                      "holding_brake", "watchdog_line"):
                assert np.array_equal(getattr(g_cmd, f), getattr(want_cmd, f)), f


# ---- the harness ----------------------------------------------------------------------------
def _joint_nets() -> list[JointNets]:
    """jpl-arm's joints wired as a rig would, with a few nets left unwired (an enable tied high,
    a joint without tach or reset), the last joint an H-bridge."""
    out = []
    for j, jp in enumerate(BASE.joints):
        name = jp.name
        if jp.amplifier == "hbridge":
            out.append(JointNets(name, amp_enable=f"{name}.en", amp_fault=f"{name}.flt", pwm=f"{name}.pwm",
                                 direction=f"{name}.dir", brake=f"{name}.brk", pot=f"{name}.pot",
                                 imon=f"{name}.imon", encoder=f"{name}.enc"))
            continue
        out.append(JointNets(name, amp_command=f"{name}.cmd", amp_enable=None if j == 3 else f"{name}.en",
                             amp_reset=None if j == 4 else f"{name}.rst", amp_fault=f"{name}.flt",
                             holding_brake=f"{name}.hold" if jp.holding_brake.present else None,
                             pot=f"{name}.pot", tach=None if j == 4 else f"{name}.tach", imon=f"{name}.imon",
                             encoder=f"{name}.enc"))
    return out


def _drive_nets(rng: np.random.Generator, signals: list[Signals], lane_signals: Signals, k: int,
                joints: list[JointNets], watchdog_net: str = "wd") -> None:
    """Random command-net values per lane, on each twin's nets and (stacked) on the lane nets."""
    for jn in joints:
        for net, kind in ((jn.amp_command, "v"), (jn.pwm, "duty"), (jn.amp_enable, "en"), (jn.amp_reset, "bit"),
                          (jn.direction, "bit"), (jn.brake, "bit"), (jn.holding_brake, "hold")):
            if net is None:
                continue
            if kind == "v":
                vals: list[Any] = rng.normal(0.0, 2.0, len(signals)).tolist()
            elif kind == "duty":
                vals = rng.random(len(signals)).tolist()
            else:
                p = {"en": 0.85, "hold": 0.8}.get(kind, 0.1)
                vals = (rng.random(len(signals)) < p).tolist()
            if kind in ("v", "duty") and k % 3 == 0:  # a net every lane holds alike is one scalar
                vals = [vals[0]] * len(vals)
            for s, v in zip(signals, vals, strict=True):
                (s.set_analog if kind in ("v", "duty") else s.set_digital)(net, v)
            lv = vals[0] if all(v == vals[0] for v in vals) else np.array(vals)
            (lane_signals.set_analog if kind in ("v", "duty") else lane_signals.set_digital)(net, lv)
    for s in signals:
        s.set_digital(watchdog_net, bool(k & 1))
    lane_signals.set_digital(watchdog_net, bool(k & 1))


def _record_quadrature(signals: Signals, into: dict[str, Any], joints: list[JointNets]) -> None:
    for jn in joints:
        if jn.encoder:
            signals.subscribe(jn.encoder, lambda net, ev: into.__setitem__(net, ev))


def _exchange_and_compare(rng: np.random.Generator, harness: Harness, lane_sig: Signals, twins: list[Harness],
                          ticks: int) -> None:
    """Tick the lane harness and its scalar twins alike: random command nets, collect, step,
    publish; every lane's command, answer, sensor nets and encoder events must be its twin's."""
    joints, n, lanes_n = twins[0].joints, twins[0].n, len(twins)
    assert harness.watchdog_net is not None
    seen_twins: list[dict[str, Any]] = [{} for _ in twins]
    seen_lanes: dict[str, Any] = {}
    for h, into in zip(twins, seen_twins, strict=True):
        _record_quadrature(h.signals, into, joints)
    _record_quadrature(lane_sig, seen_lanes, joints)
    for k in range(ticks):
        _drive_nets(rng, [h.signals for h in twins], lane_sig, k, joints, harness.watchdog_net)
        cmd = harness.collect()
        for b, h in enumerate(twins):
            want, got = h.collect(), cmd.lane(b, n)
            for f in ("amp_command_v", "amp_enable", "fault_reset", "pwm_duty", "pwm_direction", "brake",
                      "holding_brake", "watchdog_line"):
                assert np.array_equal(getattr(got, f), getattr(want, f)), f"tick {k} lane {b}: {f}"
        for h in twins:
            h.step(T, DELAY)
            h.publish()
        harness.step(T, DELAY)
        harness.publish()
        assert harness.last is not None
        for b, h in enumerate(twins):
            assert h.last is not None
            _assert_sensors_equal(harness.last.lane(b), h.last, f"tick {k} lane {b}")
            for jn in joints:
                for net in (jn.pot, jn.tach, jn.imon):
                    if net:
                        assert lane(lane_sig.analog[net], b) == h.signals.analog[net], f"tick {k} lane {b}: {net}"
                if jn.amp_fault:
                    assert bool(lane(lane_sig.digital[jn.amp_fault], b)) == h.signals.digital[jn.amp_fault]
            for net, ev in seen_twins[b].items():
                lev = seen_lanes[net]
                assert isinstance(lev.counts, np.ndarray) and lev.counts.dtype == np.int64
                assert len(lev.index_offsets) == lanes_n
                assert (int(lev.counts[b]), int(lev.illegal[b]), tuple(lev.index_offsets[b]), int(lev.phase[b])) == (
                    ev.counts, ev.illegal, tuple(ev.index_offsets), ev.phase), f"tick {k} lane {b}: {net}"
    encoders = {jn.encoder for jn in joints if jn.encoder}
    assert encoders and all(d.keys() == encoders for d in seen_twins) and seen_lanes.keys() == encoders


def test_harness_collects_and_publishes_lane_nets_as_its_scalar_twins_do():
    """Nets wired as a rig would, some unwired (an enable tied high)."""
    twins = [Harness(Signals(), _joint_nets(), InProcessLink(p), watchdog_net="wd") for p in _plants()]
    src = [Harness(Signals(), _joint_nets(), InProcessLink(p), watchdog_net="wd") for p in _plants()]
    lane_sig = Signals.from_lanes([h.signals for h in src])  # the stacked crate's nets
    harness = Harness.from_lanes(src, lane_sig, InProcessLink.from_lanes([h.link for h in src], LaneSet(B)))
    _exchange_and_compare(np.random.default_rng(5), harness, lane_sig, twins, 60)


def test_built_rigs_exchange_in_lanes_as_each_alone():
    """Three jpl-arm rigs built as a run builds them (their power-up exchange done), stacked as
    the batch stacks them (vmehil.rig_setup.lane_rig: the link over the stacked plant with the
    rigs' codec, the harness on ``Signals.from_lanes``), against three twin rigs."""
    from vmehil.rig_setup.system import build_emulated_rig

    seeds = (1, 2, 9)
    twins = [build_emulated_rig("jpl-arm", seed=s) for s in seeds]
    systems = [build_emulated_rig("jpl-arm", seed=s) for s in seeds]
    lanes = LaneSet(len(seeds))
    plant = Plant.from_lanes([s.plant for s in systems if s.plant is not None], lanes)
    link = InProcessLink(plant, codec=systems[0].link.codec)  # type: ignore[attr-defined]
    assert link.lanes is lanes and link.names == systems[0].link.names
    lane_sig = Signals.from_lanes([s.crate.signals for s in systems])
    harness = Harness.from_lanes([s.harness for s in systems], signals=lane_sig, link=link)
    assert harness.last is not None
    for b, t in enumerate(twins):
        assert t.harness.last is not None
        _assert_sensors_equal(harness.last.lane(b), t.harness.last, f"power-up lane {b}")
    _exchange_and_compare(np.random.default_rng(8), harness, lane_sig, [t.harness for t in twins], 40)
    assert lanes.alive.all()


def test_a_dead_lane_gets_its_amplifiers_off_and_its_plant_stays_finite():
    lanes = LaneSet(B)
    src = [Harness(Signals(), _joint_nets(), InProcessLink(p), watchdog_net="wd") for p in _plants()]
    lane_sig = Signals()
    harness = Harness.from_lanes(src, lane_sig, InProcessLink.from_lanes([h.link for h in src], lanes))
    for jn in _joint_nets():
        if jn.amp_command:
            lane_sig.analog[jn.amp_command] = np.array([1.0, np.nan, 1.0, 1.0])
        if jn.pwm:
            lane_sig.analog[jn.pwm] = np.array([0.5, np.nan, 0.5, 0.5])
        if jn.amp_enable:
            lane_sig.digital[jn.amp_enable] = True
    lanes.eject(np.array([False, True, False, False]), "a test: lane 1 left")
    cmd = harness.collect()
    assert not cmd.lane(1, N).amp_enable.any() and not cmd.lane(1, N).amp_command_v.any()
    assert cmd.lane(0, N).amp_enable.all() and (cmd.lane(2, N).amp_command_v[:N - 1] == 1.0).all()
    for k in range(20):
        lane_sig.digital["wd"] = bool(k & 1)
        harness.step(T, DELAY)
        harness.publish()
    assert harness.last is not None
    dead = harness.last.lane(1)
    assert np.isfinite(dead.pot_v).all() and np.isfinite(dead.truth["theta_joint"]).all()
    assert (harness.last.lane(0).truth["current_a"][:N - 1] != 0.0).all()
    assert lanes.reasons == {1: "a test: lane 1 left"}
