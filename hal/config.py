"""Typed access to TOML configuration tables with errors that name the file and the key.

Crate files, rig files, motion files and calibration files all go through
:class:`ConfigTable`, so a bad file always says *which file*, *which key* and *what was
expected*.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hal.errors import HalError

_MISSING = object()


class ConfigError(HalError, ValueError):
    """A configuration file is malformed; the message names file, key and expectation."""

    def __init__(self, source: str, key: str, expected: str, got: Any = _MISSING) -> None:
        self.source = source
        self.key = key
        self.expected = expected
        # key "": the file as a whole (missing, not TOML) — no key to name
        msg = f"{source}: key '{key}': expected {expected}" if key else f"{source}: expected {expected}"
        if got is not _MISSING:
            msg += f", got {got!r}"
        super().__init__(msg)


#: the largest configuration file read (rig, crate, calibration, fault scenario, gains list): a
#: hand-written or generated one is a few kB; the bound keeps ``--faults /dev/zero`` from reading
#: until memory runs out
MAX_CONFIG_FILE_BYTES = 4 << 20


def read_limited(path: str | Path, max_bytes: int = MAX_CONFIG_FILE_BYTES, what: str = "a file") -> bytes:
    """The bytes of the input file ``path``, refused as a :class:`ConfigError` naming it when it
    holds more than ``max_bytes`` (it is read at most one byte past the limit: a device or a pipe
    that never ends is not read to the end) or is a directory. The one reader of every input file
    (``FileNotFoundError`` and other ``OSError``s propagate for the caller to word)."""
    p = Path(path)
    try:
        with p.open("rb") as f:
            data = f.read(max_bytes + 1)
    except IsADirectoryError:
        raise ConfigError(str(p), "", f"{what}, not a directory") from None
    if len(data) > max_bytes:
        raise ConfigError(str(p), "", f"{what} of at most {max_bytes:,} bytes (it holds more)")
    return data


def load_toml(path: str | Path, max_bytes: int = MAX_CONFIG_FILE_BYTES) -> ConfigTable:
    """Read a TOML file (at most ``max_bytes``, :func:`read_limited`) into a :class:`ConfigTable`;
    syntax errors name the file."""
    p = Path(path)
    try:
        data = tomllib.loads(read_limited(p, max_bytes, "a TOML file").decode("utf-8"))
    except FileNotFoundError:
        raise ConfigError(str(p), "", "an existing TOML file (there is none)") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(str(p), "", f"valid TOML ({e})") from None
    except UnicodeDecodeError as e:  # tomllib decodes the whole file first
        raise ConfigError(str(p), "", f"a UTF-8 text file ({e})") from None
    return ConfigTable(data, str(p))


class ConfigTable:
    """A TOML table with its source and key path, and typed getters."""

    def __init__(self, data: dict[str, Any], source: str, prefix: str = "") -> None:
        if not isinstance(data, dict):
            raise ConfigError(source, prefix or "<root>", "a table", data)
        self.data = data
        self.source = source
        self.prefix = prefix
        self._used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix else name

    def error(self, name: str, expected: str, got: Any = _MISSING) -> ConfigError:
        return ConfigError(self.source, self.key(name), expected, got)

    def __contains__(self, name: str) -> bool:
        return name in self.data

    def keys(self) -> Iterator[str]:
        return iter(self.data)

    def raw(self, name: str, default: Any = _MISSING) -> Any:
        self._used.add(name)
        if name in self.data:
            return self.data[name]
        if default is _MISSING:
            raise self.error(name, "a value (the key is missing)")
        return default

    def get_str(self, name: str, default: Any = _MISSING, choices: tuple[str, ...] | None = None) -> str:
        v = self.raw(name, default)
        if not isinstance(v, str):
            raise self.error(name, "a string", v)
        if choices is not None and v not in choices:
            raise self.error(name, "one of " + ", ".join(choices), v)
        return v

    def get_int(self, name: str, default: Any = _MISSING, min: int | None = None, max: int | None = None) -> int:
        v = self.raw(name, default)
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(name, "an integer", v)
        if (min is not None and v < min) or (max is not None and v > max):
            raise self.error(name, f"an integer in [{min}, {max}]", v)
        return v

    def get_float(
        self, name: str, default: Any = _MISSING, min: float | None = None, max: float | None = None
    ) -> float:
        """A finite number (NaN and ±inf are refused) within ``[min, max]``."""
        v = self.raw(name, default)
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise self.error(name, "a number", v)
        v = float(v)
        if not math.isfinite(v):
            raise self.error(name, "a finite number", v)
        if (min is not None and v < min) or (max is not None and v > max):
            raise self.error(name, f"a number in [{min}, {max}]", v)
        return v

    def get_bool(self, name: str, default: Any = _MISSING) -> bool:
        v = self.raw(name, default)
        if not isinstance(v, bool):
            raise self.error(name, "true or false", v)
        return v

    def floats(self, name: str, default: Any = _MISSING, length: int | None = None) -> list[float]:
        """A list of finite numbers (of ``length`` when given)."""
        v = self.raw(name, default)
        if not isinstance(v, list) or not all(
            isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in v
        ):
            raise self.error(name, "a list of finite numbers", v)
        if length is not None and len(v) != length:
            raise self.error(name, f"a list of {length} numbers", v)
        return [float(x) for x in v]

    def table(self, name: str, default: Any = _MISSING) -> ConfigTable:
        v = self.raw(name, default)
        if not isinstance(v, dict):
            raise self.error(name, "a table", v)
        return ConfigTable(v, self.source, self.key(name))

    def tables(self, name: str, default: Any = _MISSING) -> list[ConfigTable]:
        v = self.raw(name, default)
        if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
            raise self.error(name, "an array of tables ([[...]])", v)
        return [ConfigTable(x, self.source, f"{self.key(name)}[{i}]") for i, x in enumerate(v)]

    def check_unknown(self, allowed: set[str] | None = None) -> None:
        """Raise if the table has keys nobody read (catches typos like ``bsae = 0x100``)."""
        allowed = allowed if allowed is not None else self._used
        for k in self.data:
            if k not in allowed:
                raise ConfigError(
                    self.source, self.key(k), "a known key (" + ", ".join(sorted(allowed)) + ")",
                    "unknown key",
                )
