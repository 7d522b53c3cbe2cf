"""Every input file is read with a size limit (hal.config.read_limited): a device that never ends,
a huge file or a directory is refused as a ConfigError naming the file, before it fills memory."""

from __future__ import annotations

import os

import pytest

from hal.config import MAX_CONFIG_FILE_BYTES, ConfigError, load_toml, read_limited


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_a_device_that_never_ends_is_refused_after_reading_one_byte_past_the_limit() -> None:
    with pytest.raises(ConfigError, match="/dev/zero.*at most 4,194,304 bytes"):
        load_toml("/dev/zero")
    assert MAX_CONFIG_FILE_BYTES == 4 << 20


def test_a_file_at_the_limit_is_read_and_one_byte_more_is_refused(tmp_path) -> None:
    f = tmp_path / "a.bin"
    f.write_bytes(b"a" * 100)
    assert read_limited(f, 100) == b"a" * 100
    with pytest.raises(ConfigError, match="at most 99 bytes"):
        read_limited(f, 99)


def test_a_directory_is_refused_as_bad_input(tmp_path) -> None:
    with pytest.raises(ConfigError, match="not a directory"):
        load_toml(tmp_path)


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_a_fault_scenario_from_dev_zero_is_refused(capsys) -> None:
    from vmehil import cli
    from vmehil.exit_status import EXIT_USAGE

    assert cli.main(["run", "--duration", "0.5", "--quiet", "--faults", "/dev/zero"]) == EXIT_USAGE
    assert "at most 4,194,304 bytes" in capsys.readouterr().err
