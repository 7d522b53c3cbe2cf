"""Pieces of the MAVLink endpoint without a link: key files, URLs, the table (the stability check is
servo.gain_guard's, tested in test_console_gain_guard.py)."""

from __future__ import annotations

import argparse
import os
from types import SimpleNamespace

import pytest

from tests.support.fakes import fake_loop
from vmehil.mavlink.endpoint import MavlinkEndpoint, MavlinkError, check_url, free_udp_port
from vmehil.mavlink.extension import MavlinkOptions, add_arguments, attach
from vmehil.mavlink.params import MAX_NAME_LEN, ParamRefused, ParamTable
from vmehil.mavlink.signing import KeyFileError, key_from_passphrase, load_key_file, write_key_file

T = 0.008


def test_key_file_round_trip_and_permissions(tmp_path):
    key = key_from_passphrase("secret")
    p = write_key_file(tmp_path / "mav.key", key)
    assert (os.stat(p).st_mode & 0o777) == 0o600
    assert load_key_file(p) == key
    os.chmod(p, 0o640)
    with pytest.raises(KeyFileError, match="chmod 600"):
        load_key_file(p)
    os.chmod(p, 0o604)
    with pytest.raises(KeyFileError, match="group or others"):
        load_key_file(p)
    bad = tmp_path / "bad.key"
    for text, match in (("zz" * 32, "not hexadecimal"), ("ab" * 16, "16 bytes"), ("", "one line")):
        bad.write_text(text)
        os.chmod(bad, 0o600)
        with pytest.raises(KeyFileError, match=match):
            load_key_file(bad)
    with pytest.raises(KeyFileError, match="does not exist"):
        load_key_file(tmp_path / "missing")


@pytest.mark.parametrize("url", ["udpin:0.0.0.0:14550", "udpout:10.0.0.5:14550", "tcpin:example.org:5760",
                                 "udpin:192.168.1.2:1"])
def test_non_loopback_address_refused_unless_allowed(url):
    with pytest.raises(MavlinkError, match="not a loopback"):
        check_url(url)
    assert check_url(url, allow_remote=True)[0] in ("udpin", "udpout", "tcpin")


@pytest.mark.parametrize("url", ["udpin:127.0.0.1:14550", "udpout:localhost:1", "udp:127.0.0.2:5", "tcp:::1:5"])
def test_loopback_urls_accepted_and_bad_ones_explained(url):
    if url.startswith("tcp:::1"):
        with pytest.raises(MavlinkError, match="SCHEME:HOST:PORT"):
            check_url(url)
    else:
        assert check_url(url)[1] in ("127.0.0.1", "localhost", "127.0.0.2")
    for bad in ("serial:/dev/ttyS0:57600", "udpin:127.0.0.1", "udpin:127.0.0.1:x"):
        with pytest.raises(MavlinkError):
            check_url(bad)


def test_parameter_names_fit_mavlink_and_indices_are_stable():
    loop, _, _ = fake_loop(12)
    t = ParamTable(loop)
    assert len(t) == 12 * 12 + 1
    assert max(len(n) for n in t.names) <= MAX_NAME_LEN
    assert len(set(t.names)) == len(t)
    assert t.names[:4] == ["J1_KP", "J1_KPI", "J1_KV", "J1_KVI"]
    assert t.find("J12_SO_SETTLE")[1].joint == 11
    with pytest.raises(ParamRefused):
        t.find("J13_KP")


def _args(**kw):
    """The run's options as the MAVLink extension reads them (``RunNeeds``), from these flags."""
    p = argparse.ArgumentParser()
    add_arguments(p)
    argv = []
    for k, v in kw.items():
        argv += [f"--{k.replace('_', '-')}"] + ([] if v is True else [str(v)])
    return SimpleNamespace(mavlink=MavlinkOptions.from_args(p.parse_args(argv)))


def test_extension_attaches_only_when_asked_and_hooks_after_tick(tmp_path):
    loop, _, runner = fake_loop(1)
    assert attach(_args(), None, loop, runner) is None
    ep = attach(_args(mavlink=f"udpin:127.0.0.1:{free_udp_port()}", mavlink_rate=5), None, loop, runner)
    try:
        assert isinstance(ep, MavlinkEndpoint) and runner.after_tick == [ep.after_tick]
        assert ep.rate_hz == pytest.approx(125 / 25)
    finally:
        ep.close()
    key = tmp_path / "k"
    key.write_text("ab" * 32)
    os.chmod(key, 0o644)
    with pytest.raises(KeyFileError):
        attach(_args(mavlink="udpin:127.0.0.1:1", mavlink_key_file=key), None, loop, runner)
    with pytest.raises(MavlinkError, match="allow-remote"):
        attach(_args(mavlink="udpin:0.0.0.0:14550"), None, loop, runner)
    with pytest.raises(MavlinkError, match="rate"):
        attach(_args(mavlink="udpin:127.0.0.1:1", mavlink_rate=500), None, loop, runner)


def test_key_is_never_an_option():
    p = argparse.ArgumentParser()
    add_arguments(p)
    opts = {o for a in p._actions for o in a.option_strings}
    assert not any(o.endswith("-key") or "passphrase" in o for o in opts)
