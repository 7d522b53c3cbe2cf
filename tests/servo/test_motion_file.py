"""Motion files: parsing (degrees at the edge), errors naming file and key, the demo motion and the
table of move types."""

from __future__ import annotations

import numpy as np
import pytest

import servo.motion as motion
from hal.config import ConfigError
from servo.motion import LspbMove, QuinticMove, WaitMove, default_demo_motion, load_motion
from servo.trajectory import JointLimits, PlanContext, Stay

GOOD = """
name = "pick"
[[move]]
targets_deg = [10, -20, 30]
speed = 0.5
[[move]]
type = "wait"
duration_s = 8
[[move]]
type = "lspb"
via_deg = [[0, 0, 0], [20, 10, 0]]
[[move]]
deltas_rad = [0.1, 0.0, -0.1]
[[move]]
type = "stay"
duration_s = 1.5
"""


def write(tmp_path, text, name="motion.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_parse_a_motion_file(tmp_path):
    m = load_motion(write(tmp_path, GOOD), 3)
    assert m.name == "pick" and m.source.endswith("motion.toml")
    q, w, lspb, rel, stay = m.moves
    assert isinstance(q, QuinticMove) and q.speed == 0.5
    np.testing.assert_allclose(q.target, np.radians([10, -20, 30]))
    assert isinstance(w, WaitMove) and w.duration == 8.0
    assert isinstance(lspb, LspbMove)
    np.testing.assert_allclose(lspb.vias[1], np.radians([20, 10, 0]))
    np.testing.assert_allclose(rel.delta, [0.1, 0.0, -0.1])
    assert isinstance(stay, WaitMove) and stay.duration == 1.5
    # play it: each move starts where the previous one ended
    seq = m.sequencer(np.zeros(3), PlanContext(JointLimits.make(3, 1.0, 2.0)))
    t = 0.0
    while not seq.finished:
        seq.sample(t)
        t += 0.008
    assert [r.kind for r in seq.records] == ["quintic", "wait", "lspb", "quintic", "wait"]
    np.testing.assert_allclose(seq.sample(t).theta_d, np.radians([20, 10, 0]) + np.array([0.1, 0.0, -0.1]))


@pytest.mark.parametrize(("text", "key", "expected"), [
    ('[[move]]\ntargets_deg = [1, 2]\n', "move[0].targets_deg", "3 numbers"),
    ('[[move]]\nspeed = 0.5\n', "move[0].targets_deg", "exactly one"),
    ('[[move]]\ntargets_deg = [1, 2, 3]\ndeltas_deg = [1, 2, 3]\n', "move[0].targets_deg", "exactly one"),
    ('[[move]]\ntargets_deg = [1, 2, 3]\ntargets_rad = [1, 2, 3]\n', "move[0].targets_deg", "not both"),
    ('[[move]]\ntargets_deg = [1, 2, 3]\nspeed = 2\n', "move[0].speed", "(0, 1]"),
    ('[[move]]\ntargets_deg = [1, 2, 3]\n[[move]]\ntype = "wait"\n', "move[1].duration_s", "missing"),
    ('[[move]]\ntype = "wait"\nduration_s = -1\n', "move[0].duration_s", "[0.0, None]"),
    ('[[move]]\ntype = "fly"\n', "move[0].type", "one of"),
    ('[[move]]\ntype = "wait"\nduration_s = 3\nspeed = 1\n', "move[0].speed", "a known key"),
    ('[[move]]\ntype = "lspb"\nvia_deg = [[1, 2, 3], [1, 2]]\n', "move[0].via_deg[1]", "3 numbers"),
    ('[[move]]\ntype = "lspb"\n', "move[0].via_deg", "exactly one"),
    ('name = "x"\n', "move", "missing"),
    ('[[move]]\ntargets_deg = [1, 2, 3]\nspeeed = 1\n', "move[0].speeed", "a known key"),
])
def test_errors_name_the_file_and_the_key(tmp_path, text, key, expected):
    p = write(tmp_path, text, "bad_motion.toml")
    with pytest.raises(ConfigError) as ei:
        load_motion(p, 3)
    assert ei.value.source == str(p)
    assert ei.value.key == key
    assert expected in str(ei.value)
    assert str(p) in str(ei.value)


def test_syntax_errors_and_missing_files_name_the_file(tmp_path):
    with pytest.raises(ConfigError, match="broken.toml"):
        load_motion(write(tmp_path, "[[move]\n", "broken.toml"), 3)
    with pytest.raises(ConfigError, match="nothere.toml"):
        load_motion(tmp_path / "nothere.toml", 3)


@pytest.mark.parametrize("n", [1, 6, 16])
def test_default_demo_moves_every_joint_then_holds_at_least_8_s(n):
    m = default_demo_motion(n)
    move, hold = m.moves
    assert np.all(np.abs(move.delta) > 0)
    assert hold.kind == "wait" and hold.duration >= 8.0
    seq = m.sequencer(np.zeros(n), PlanContext(JointLimits.make(n, 0.5)))
    s = seq.sample(0.5)
    assert not s.done and np.all(s.omega_d != 0)
    t_end = seq.records[0].duration
    assert seq.sample(t_end + 0.1).done
    np.testing.assert_allclose(seq.sample(t_end + 8.0).theta_d, move.delta)
    with pytest.raises(ConfigError, match="8 s"):
        default_demo_motion(n, hold_s=5.0)


def test_a_new_move_type_is_an_entry_in_the_move_table(tmp_path, monkeypatch):
    class Park:
        kind = "park"

        def __init__(self, dur):
            self.dur = dur

        def build(self, start, ctx):
            return Stay(np.zeros_like(start), self.dur)

    def parse_park(cfg, n):
        move = Park(cfg.get_float("duration_s", 1.0))
        cfg.check_unknown({"type", "duration_s"})
        return move

    monkeypatch.setitem(motion.MOVE_TYPES, "park", parse_park)
    m = load_motion(write(tmp_path, '[[move]]\ntype = "park"\nduration_s = 2\n'), 2)
    assert isinstance(m.moves[0], Park) and m.moves[0].dur == 2.0


def test_an_lspb_move_of_more_than_10000_vias_is_refused_naming_the_key() -> None:
    from hal.config import ConfigTable
    from servo.motion import parse_motion

    vias = [[float(k % 2)] for k in range(10_001)]
    with pytest.raises(ConfigError, match=r"move\[0\]\.via_rad.*at most 10000 via points"):
        parse_motion(ConfigTable({"move": [{"type": "lspb", "via_rad": vias}]}, "m.toml"), 1)
    motion = parse_motion(ConfigTable({"move": [{"type": "lspb", "via_rad": vias[:10_000]}]}, "m.toml"), 1)
    assert len(motion.moves[0].vias) == 10_000


def test_a_motion_of_more_than_10000_moves_is_refused() -> None:
    from hal.config import ConfigTable
    from servo.motion import parse_motion

    table = {"move": [{"type": "wait", "duration_s": 0.0} for _ in range(10_001)]}
    with pytest.raises(ConfigError, match="at most 10000 moves"):
        parse_motion(ConfigTable(table, "m.toml"), 1)


def test_a_motion_file_over_1_mib_is_refused_before_it_is_parsed(tmp_path) -> None:
    f = tmp_path / "big.toml"
    f.write_text("# " + "x" * (1 << 20) + "\n[[move]]\ntype = \"wait\"\nduration_s = 1\n")
    with pytest.raises(ConfigError, match="at most 1,048,576 bytes"):
        load_motion(f, 1)
