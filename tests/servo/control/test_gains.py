"""servo.control.gains: the one Gains type and the one gain-text parser (every command's --gains,
the sweep grids), with property tests: format → parse round trip, garbage never raises anything
but GainSyntaxError."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from servo.control.errors import GainError, GainSyntaxError
from servo.control.gains import DEFAULT_GAINS, GAIN_NAMES, Gains, format_gains, gain_items, parse_gains

# ---- the text form -------------------------------------------------------------------------------------


@pytest.mark.parametrize(("text", "expected"), [
    ("kp=100,kpi=5000,kv=50,kvi=1000", DEFAULT_GAINS),  # the documented form
    ("kp=175", {"kp": 175.0}),
    ("kpi=200000", {"kpi": 200000.0}),
    ("kp=200, KV=40", {"kp": 200.0, "kv": 40.0}),  # what `vmehil tune --gains` took (commas or spaces)
    ("kp=100 kpi=5000", {"kp": 100.0, "kpi": 5000.0}),
    (" kp = 100 , kv=50 ", {"kp": 100.0, "kv": 50.0}),  # what `vmehil run --gains` took (spaces around =)
    ("kp=1,,kv=2,", {"kp": 1.0, "kv": 2.0}),
    ("kp=1e2\tkvi=\n3", {"kp": 100.0, "kvi": 3.0}),
    ("kp=1,kp=2", {"kp": 2.0}),  # a repeated gain: the last one counts, as before
    ("kp=-5,kv=nan", {"kp": -5.0}),  # syntax only: the guard judges values (nan checked below)
    ("", {}),
    ("   ", {}),
    (None, {}),
])
def test_the_accepted_forms(text, expected):
    got = parse_gains(text)
    if "kv" in got and math.isnan(got["kv"]):
        got.pop("kv")
    assert got == expected


@pytest.mark.parametrize(("text", "token", "words"), [
    ("kp", "kp", "malformed: no '='"),
    ("kp=1,,kv", "kv", "malformed: no '='"),
    ("kp=", "kp=", "no value"),
    ("=5", "=5", "no gain name"),
    ("kq=3", "kq=3", "unknown gain 'kq'"),
    ("kp=fast", "kp=fast", "not a number"),
    ("kp=1;kv=2", "kp=1;kv=2", "not a number"),  # ';' separates a grid axis's values, not gains
    ("kp=100kv=5", "kp=100kv=5", "not a number"),
    ("kp=1 0", "0", "malformed"),
])
def test_errors_are_typed_and_name_the_bad_token(text, token, words):
    with pytest.raises(GainSyntaxError) as ei:
        parse_gains(text, what="--gains")
    e = ei.value
    assert e.token == token and e.text == text and isinstance(e, GainError)
    assert words in str(e) and f"{token!r}" in str(e) and str(e).startswith(f"--gains {text!r}:")


def test_gain_items_hand_grid_values_to_the_caller_as_text():
    assert gain_items("kp = 80 : 140 : 4, kvi=800; 1000") == [("kp", "80:140:4", "kp=80:140:4"),
                                                              ("kvi", "800;1000", "kvi=800;1000")]


gain_values = st.floats(allow_nan=False)  # any float, ±inf included: the parser is syntax only
gain_sets = st.dictionaries(st.sampled_from(GAIN_NAMES), gain_values)


@given(gain_sets)
def test_format_then_parse_gives_the_same_gains(gains):
    assert parse_gains(format_gains(gains)) == gains


@given(gain_sets, st.lists(st.sampled_from([",", " ", ", ", "\t", ",,", " ,\n"]), min_size=4, max_size=4),
       st.sampled_from(["=", " =", "= ", " = "]), st.booleans())
def test_any_separators_and_case_give_the_same_gains(gains, seps, eq, upper):
    items = [f"{k.upper() if upper else k}{eq}{v!r}" for k, v in gains.items()]
    text = "".join(item + seps[i % len(seps)] for i, item in enumerate(items))
    assert parse_gains(text) == gains


gain_alphabet = st.text(alphabet="kpviKPVI=,; .:e-+0123456789nafx\t\n_", max_size=40)


@given(st.one_of(st.text(max_size=60), gain_alphabet))
def test_garbage_never_raises_anything_but_the_typed_error(text):
    try:
        got = parse_gains(text)
    except GainSyntaxError as e:
        assert e.token and repr(e.token) in str(e) and e.text == text  # the message names the bad token
        return
    assert set(got) <= set(GAIN_NAMES) and all(isinstance(v, float) for v in got.values())


# ---- the type ---------------------------------------------------------------------------------------------


def test_one_joint_set_is_floats_hashable_and_compares_by_value():
    g = Gains(kp=100, kpi=5000, kv=50, kvi=1000)
    assert g == Gains.paper() and hash(g) == hash(Gains.paper()) and {g: 1}[Gains.paper()] == 1
    assert all(type(getattr(g, k)) is float for k in GAIN_NAMES)
    assert g.n is None and g.as_dict() == DEFAULT_GAINS
    assert str(g) == "kp=100, kpi=5000, kv=50, kvi=1000"
    assert g.replace(kv=60) == Gains(kp=100, kpi=5000, kv=60, kvi=1000) != g
    assert Gains.from_mapping({"KP": 120}) == Gains.paper().replace(kp=120)


def test_a_per_joint_set_is_read_only_arrays_with_one_joint_views():
    g = Gains.make(3, kp=[100, 120, 140], kv=55)
    assert g.n == 3 and g.as_dict()["kp"] == [100.0, 120.0, 140.0] and g.as_dict()["kv"] == [55.0] * 3
    with pytest.raises(ValueError):
        g.kp[0] = 1.0
    assert g.joint(1) == Gains(kp=120, kpi=5000, kv=55, kvi=1000)
    assert Gains.paper().broadcast(2) == Gains.make(2)
    assert g != Gains.make(3) and g == Gains.make(3, kp=np.array([100, 120, 140]), kv=[55] * 3)
    with pytest.raises(GainError, match="gains for 2 joints"):
        g.broadcast(2)


@pytest.mark.parametrize(("changes", "words"), [
    ({"kp": -1.0}, "is negative"),
    ({"kpi": math.nan}, "is not finite"),
    ({"kv": math.inf}, "is not finite"),
    ({"kvi": "10"}, "is not a number"),
    ({"kvi": True}, "is not a number"),
    ({"kq": 1.0}, "is not a gain name"),
])
def test_invalid_values_are_gain_errors_naming_the_gain(changes, words):
    with pytest.raises(GainError, match=words) as ei:
        Gains.paper().replace(**changes)
    assert ei.value.name == next(iter(changes))
    with pytest.raises(GainError, match=r"kp\[1\]"):
        Gains.make(2, kp=[1.0, -1.0])
