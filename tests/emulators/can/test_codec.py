"""The DBC message set and its codec: the shipped file, range limits, quantization, fuzzing, logs."""

from __future__ import annotations

import functools
import subprocess
import sys
from importlib import resources

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulators.can.bus import Endpoint, open_bus, replay
from emulators.can.can_plant_link import CanPlantLink, merge_events
from emulators.can.codec import CanCodec, DbcExchangeCodec, FrameError, index_offsets
from emulators.can.dbc import DBC_PATH, dbc_text
from emulators.can.node import PlantNode
from emulators.can.toy import ToyCommand, ToyPlant, ToySensors
from emulators.harness import PlantLinkError
from emulators.signals import QuadratureEvents

CODEC = CanCodec()


def test_the_shipped_dbc_is_the_generators_output_and_is_package_data():
    assert DBC_PATH.read_bytes().decode() == dbc_text(), "regenerate with: python -m emulators.can.dbc"
    assert (resources.files("emulators.can") / "vmehil.dbc").is_file()


def test_fd_frames_are_marked_fd_in_the_dbc():
    assert CODEC.message("SENS", 0).is_fd and CODEC.message("SYNC").is_fd
    # 12 bytes since the holding-brake line (#29): FD like SENS (its first 8 bytes as before)
    assert CODEC.message("CMD", 0).is_fd and CODEC.message("CMD", 0).length == 12
    assert CODEC.message("CMD", 0).get_signal_by_name("HoldingBrake").start == 64


def test_resolutions_are_finer_than_the_electronics():
    # 12-bit ADC over ±10 V: 4.9 mV; the wire must be at least 10x finer
    for name in ("PotVoltage", "TachVoltage", "CurrentMonitor"):
        assert CODEC.specs["SENS"][name].scale <= 0.5e-3
    assert CODEC.specs["CMD"]["AmpCommand"].scale <= 0.5e-3
    assert CODEC.specs["CMD"]["PwmDuty"].raw_max * CODEC.specs["CMD"]["PwmDuty"].scale == pytest.approx(1.0)


@pytest.mark.parametrize("msg", CODEC.db.messages, ids=lambda m: m.name)
def test_every_signal_round_trips_at_its_range_limits(msg):
    kind, joint, _ = CODEC._by_id[msg.frame_id]
    specs = CODEC.specs[kind]
    for limit in ("raw_min", "raw_max"):
        raw = {s: (getattr(sp, limit) if not sp.is_float else (-1e300 if limit == "raw_min" else 1e300))
               for s, sp in specs.items()}
        m = can.Message(arbitration_id=msg.frame_id, data=msg.encode(raw, scaling=False, strict=False),
                        is_fd=msg.is_fd, is_extended_id=False)
        f = CODEC.decode(m)
        assert (f.kind, f.joint) == (kind, joint)
        assert f.raw == raw
        for s, sp in specs.items():
            if not sp.is_float:  # physical limits quantize back to the same raw value
                phys = sp.physical(raw[s])
                assert sp.quantize(phys)[0] == raw[s]
                lo, hi = msg.get_signal_by_name(s).minimum, msg.get_signal_by_name(s).maximum
                assert lo - sp.scale / 2 <= phys <= hi + sp.scale / 2


def test_values_beyond_the_range_are_clipped_and_counted():
    c = CanCodec()
    raw = c.command_raw(ToyCommand(np.array([100.0, -100.0, np.nan]), np.ones(3, bool), np.zeros(3, bool),
                                   np.array([2.0, -1.0, 0.5]), np.ones(3, bool), np.zeros(3, bool)))
    assert raw["AmpCommand"].tolist() == [2**23 - 1, -(2**23), 0]
    assert raw["PwmDuty"].tolist() == [1_000_000, 0, 500_000]
    assert c.counters.clipped == 5


@pytest.mark.parametrize("level", [False, True])
def test_the_watchdog_line_rides_in_sync_not_in_the_joint_frames(level):
    cmd = ToyCommand.idle(2)
    cmd.watchdog_line = level
    assert DbcExchangeCodec(CODEC).command(cmd).watchdog_line is level  # the in-process path
    raw = CODEC.command_raw(cmd)
    assert all("Watchdog" not in CODEC.decode(m).raw for m in CODEC.command_frames(raw, 5))
    sync = CODEC.decode(CODEC.sync_frame(raw, 5, 0.008, 0.001))
    assert (sync.raw["Watchdog"], sync.raw["Tick"], sync.raw["Seq"]) == (int(level), 5, 5)


volts = st.floats(-20, 20, allow_nan=False)
events = st.builds(QuadratureEvents, counts=st.integers(-(2**24), 2**24), illegal=st.integers(0, 70000),
                   index_offsets=st.lists(st.integers(-(2**23), 2**23 - 1), max_size=3).map(tuple),
                   phase=st.integers(0, 3))


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(volts, volts, volts, st.booleans(), events, st.booleans()), min_size=1, max_size=8))
def test_the_frames_carry_exactly_what_the_in_process_codec_gives(rows):
    n = len(rows)
    s = ToySensors(pot_v=np.array([r[0] for r in rows]), tach_v=np.array([r[1] for r in rows]),
                   imon_v=np.array([r[2] for r in rows]), amp_fault=np.array([r[3] for r in rows]),
                   encoder=[r[4] for r in rows], switching=np.array([r[5] for r in rows]),
                   truth={"theta_joint": np.arange(n) * 0.1, "omega_joint": np.zeros(n), "current_a": np.ones(n),
                          "friction_torque_nm": np.full(n, -1.5)})
    direct = DbcExchangeCodec(CODEC).sensors(s)
    frames = CODEC.sensor_frames(CODEC.sensors_raw(s), 9, s.truth)
    decoded = [CODEC.decode(can.Message(arbitration_id=m.arbitration_id, data=m.data, is_fd=m.is_fd,
                                         is_extended_id=False)) for m in frames]
    sens = [f for f in decoded if f.kind == "SENS"]
    raw = {k: np.array([f.raw[k] for f in sens]) for k in sens[0].raw if k != "Seq"}
    via_can = CODEC.sensors_from_raw(raw, ToySensors)
    for f in ("pot_v", "tach_v", "imon_v", "amp_fault", "switching"):
        assert np.array_equal(getattr(direct, f), getattr(via_can, f))
    assert direct.encoder == via_can.encoder
    # quantization error within half an LSB inside the range
    inside = np.abs(s.pot_v) < 16.7
    assert np.all(np.abs(direct.pot_v - s.pot_v)[inside] <= 1e-6 + 1e-12)
    truth = [f for f in decoded if f.kind == "TRUTH"]
    assert [f.raw["ThetaJoint"] for f in truth] == list(s.truth["theta_joint"])


@functools.cache
def _two_codecs() -> tuple[CanCodec, CanCodec]:
    return CanCodec(), CanCodec()  # each parses the DBC (≈ 1 s): once per session


any_volts = st.one_of(st.floats(-40, 40), st.sampled_from([float("nan"), float("inf"), -float("inf"), 16.7, -16.7]))


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(any_volts, any_volts, any_volts, st.booleans(), events, st.booleans()), min_size=1,
                max_size=16))
@pytest.mark.slow
def test_the_fused_in_process_sensors_path_gives_the_general_paths_values_and_clip_count(rows):
    n = len(rows)
    s = ToySensors(pot_v=np.array([r[0] for r in rows]), tach_v=np.array([r[1] for r in rows]),
                   imon_v=np.array([r[2] for r in rows]), amp_fault=np.array([r[3] for r in rows]),
                   encoder=[r[4] for r in rows], switching=np.array([r[5] for r in rows]),
                   truth={"theta_joint": np.arange(n) * 0.1})
    fused_codec, general_codec = _two_codecs()
    clipped0 = fused_codec.counters.clipped, general_codec.counters.clipped
    fused = DbcExchangeCodec(fused_codec).sensors(s)
    general = general_codec.sensors_from_raw(general_codec.sensors_raw(s), ToySensors, s.truth)
    for f in ("pot_v", "tach_v", "imon_v", "amp_fault", "switching"):
        a, b = getattr(fused, f), getattr(general, f)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), f
    assert fused.encoder == general.encoder
    assert fused.truth == general.truth
    assert fused_codec.counters.clipped - clipped0[0] == general_codec.counters.clipped - clipped0[1]
    finite = all(np.isfinite(r[k]) for r in rows for k in range(3))
    assert (DbcExchangeCodec(CODEC)._sensors_fused(s) is not None) == finite  # the fused path ran


@given(st.integers(0, 40), st.integers(-1000, 1000), st.integers(1, 4000))
def test_index_offsets_are_exact_for_evenly_spaced_pulses(count, first, spacing):
    true = tuple(first + k * spacing for k in range(count))
    k = min(count, 15)
    got = index_offsets(k, true[0] if true else 0, true[k - 1] if true else 0)
    assert got == true[:k]


def test_merged_events_shift_index_offsets_by_the_counts_before_them():
    a = QuadratureEvents(counts=10, illegal=1, index_offsets=(4,), phase=2)
    b = QuadratureEvents(counts=-3, illegal=2, index_offsets=(-1,), phase=3)
    assert merge_events([a, b]) == QuadratureEvents(counts=7, illegal=3, index_offsets=(4, 9), phase=3)


frames = st.builds(
    lambda fid, data, ext, fd: can.Message(arbitration_id=fid, data=data, is_extended_id=ext,
                                           is_fd=fd or len(data) > 8),
    st.one_of(st.sampled_from(sorted(CODEC._by_id)), st.integers(0, 0x7FF)),
    st.binary(max_size=64), st.booleans(), st.booleans())


@functools.cache
def fuzz_pair() -> tuple[PlantNode, CanPlantLink]:
    """One node and one link for every fuzz example (state carried over is part of the fuzzing)."""
    node = PlantNode(can.Bus(interface="virtual", channel="fuzz-node"), lambda s: ToyPlant(2, seed=s), 2,
                     command_type=ToyCommand)
    link = CanPlantLink(can.Bus(interface="virtual", channel="fuzz-link"), ["a", "b"], sensors_type=ToySensors)
    return node, link


@pytest.fixture(scope="module", autouse=True)
def _shut_fuzz_buses():
    yield
    if fuzz_pair.cache_info().currsize:
        node, link = fuzz_pair()
        node.ep.bus.shutdown()
        link.ep.bus.shutdown()


@settings(max_examples=400, deadline=None)
@given(st.lists(frames, max_size=12))
def test_fuzzed_frames_never_crash_the_decoder_the_node_or_the_link(msgs):
    node, link = fuzz_pair()
    for m in msgs:
        try:
            CODEC.decode(m)
        except FrameError as e:
            assert e.reason in ("unknown_id", "wrong_length", "undecodable", "out_of_range")
        node.handle(m)
        f = link.codec.try_decode(m)
        if f is not None:
            try:
                link._process(f, False)
            except PlantLinkError:
                pass  # a well-formed status frame saying something bad is a typed error, not a crash


@pytest.mark.slow
def test_a_recorded_log_decodes_with_the_cantools_command_line_and_replays(tmp_path):
    log = tmp_path / "bus.log"
    n = 2
    node_bus = open_bus("virtual", "logtest")
    node = PlantNode(node_bus, lambda s: ToyPlant(n, seed=s), n, command_type=ToyCommand)
    thread, stop = node.start_thread()
    link = CanPlantLink(Endpoint(open_bus("virtual", "logtest"), set(), log_path=log), ["a", "b"], seed=1,
                        sensors_type=ToySensors)
    got = []
    try:
        for _k in range(5):
            cmd = ToyCommand(np.array([0.5, -0.25]), np.ones(n, bool), np.zeros(n, bool), np.zeros(n),
                             np.ones(n, bool), np.zeros(n, bool))
            got.append(link.exchange(cmd, 0.008, 0.001))
    finally:
        stop.set()
        thread.join(5)
        link.close()
        node_bus.shutdown()
    text = log.read_text()
    assert "##" in text  # CAN FD frames in candump's format
    out = subprocess.run([sys.executable, "-m", "cantools", "decode", str(DBC_PATH)], input=text,
                         capture_output=True, text=True, check=True).stdout
    assert out.count("SENS_J01(") == 5 and out.count("CMD_J00(") == 5 and "PotVoltage:" in out
    assert "AmpCommand: 0.5 V" in out
    # replay: the pot voltages in the log are the ones the link returned
    pots = [CODEC.decode(m).raw["PotVoltage"] for m in replay(log) if m.arbitration_id == 0x201]
    assert [CODEC.specs["SENS"]["PotVoltage"].physical(p) for p in pots] == [s.pot_v[1] for s in got]
