"""The melmalec-16 rig: 16 motors in five 3-axis units plus the crawler, through the full stack."""

from __future__ import annotations

from collections import Counter

import numpy as np

from servo.runner import LockstepRunner
from vmehil.reports.run_report import summarize
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

UNITS = ("leg1", "leg2", "leg3", "leg4", "arm")


def test_each_unit_has_its_own_adc_dac_and_decoder_on_distinct_a16_pages() -> None:
    system = build_emulated_rig("melmalec-16", seed=0)
    rig = system.rig
    assert rig.n_joints == 16
    boards = {b.get_str("name"): b for b in rig.table.table("crate").tables("board")}
    bases = [(b.get_str("space"), b.get_int("base")) for b in boards.values()]
    assert len(set(bases)) == len(bases)
    assert all(space == "A16" and base % 0x100 == 0 for space, base in bases)
    for u, unit in enumerate(UNITS):
        joints = [j for j in rig.joints if j.name.startswith(unit)]
        assert len(joints) == 3
        for kind in ("amp_command", "pot", "tach", "imon", "encoder", "amp_enable", "amp_fault", "amp_reset"):
            assert {j.wiring[kind].board for j in joints} == {f"{kind_board(kind)}{u}"}
    # no pin is used twice
    pins = Counter((p.board, p.channel) for j in rig.joints for p in j.wiring.values())
    assert max(pins.values()) == 1
    crawler = rig.joints[-1]
    assert crawler.amplifier == "hbridge" and "pot" not in crawler.wiring
    assert system.io.position_source[-1] == "encoder"
    system.close()


def kind_board(kind: str) -> str:
    return {"amp_command": "dac", "pot": "adc", "tach": "adc", "imon": "adc", "encoder": "quad"}.get(kind, "pio")


def test_melmalec_demo_moves_all_sixteen_joints_without_faults() -> None:
    """The default demo's coordinated move (3 s of it): every joint follows its quintic within a
    few degrees (the uncalibrated pots' ~1° bow included), no watchdog trip."""
    system = build_emulated_rig("melmalec-16", seed=2)
    n_ticks = 375
    loop = build_loop(system, n_ticks=n_ticks)
    loop.start()
    LockstepRunner(system, loop).run(n_ticks)
    assert loop.fault is None
    rec = loop.recorder.trimmed()
    err_deg = np.degrees(np.abs(rec["theta_d"] - rec["theta_true"]))
    assert np.nanmax(err_deg) < 3.0
    moved = np.degrees(np.abs(rec["theta_true"][-1] - rec["theta_true"][0]))
    assert np.all(moved > 3.0)  # every joint, the crawler included, really moved
    summary = summarize(loop, rig=system.rig.name, seed=2, realtime=False, overruns=0)
    assert summary["faults"] == [] and len(summary["joints"]) == 16
    system.close()


def test_the_crawlers_hbridge_noise_reaches_only_the_arm_units_adc() -> None:
    """Each unit's electronics are its own (docs/melmalec.md): the bridge's switching noise is
    coupled into adc4 (the arm's, which also reads the crawler's current) and no other ADC."""
    system = build_emulated_rig("melmalec-16", seed=0)
    coupled = {name: len(b._noise_sources) for name, b in system.crate.boards.items() if name.startswith("adc")}
    assert coupled == {"adc0": 0, "adc1": 0, "adc2": 0, "adc3": 0, "adc4": 1}
    system.close()
