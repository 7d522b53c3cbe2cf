"""MAVLink 2 signing: the key file and the policy for unsigned messages.

Key file: one line of 64 hexadecimal digits (the 32-byte secret key), nothing else but
whitespace and ``#`` comment lines. The file must not be readable or writable by group or others
(``chmod 600``); anything else is refused. Keys are never taken from the command line.

MAVProxy derives its key from a passphrase as SHA-256(passphrase); :func:`key_from_passphrase`
does the same, so ``signing key PASSPHRASE`` typed into MAVProxy's console matches a key file
written with ``vmehil``'s :func:`write_key_file` (or by hand: ``sha256sum`` of the passphrase).
"""

from __future__ import annotations

import hashlib
import hmac
import stat
import types
from pathlib import Path
from typing import Any

from hal.config import ConfigError, read_limited
from vmehil.errors import VmehilError
from vmehil.writers.files import write_atomic

KEY_LEN = 32


class KeyFileError(VmehilError, ValueError):
    """The signing key file is missing, too open, or not a 32-byte hex key."""


def key_from_passphrase(passphrase: str) -> bytes:
    """MAVProxy's key derivation: SHA-256 of the UTF-8 passphrase (32 bytes)."""
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def write_key_file(path: str | Path, key: bytes) -> Path:
    """Write ``key`` (32 bytes) as hex to a new file created with mode 0600.

    Atomic, and at most 0600 from creation on: replacing an existing (perhaps more open) file never
    puts the key in it, even for a moment."""
    if len(key) != KEY_LEN:
        raise KeyFileError(f"a signing key is {KEY_LEN} bytes, got {len(key)}")
    return write_atomic(path, key.hex() + "\n", mode=0o600)


def load_key_file(path: str | Path) -> bytes:
    """Read a signing key (see the module docstring). Raises :class:`KeyFileError` saying what to fix."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise KeyFileError(f"signing key file {p} does not exist") from None
    if not stat.S_ISREG(st.st_mode):
        raise KeyFileError(f"signing key file {p} is not a regular file")
    if st.st_mode & 0o077:
        raise KeyFileError(f"signing key file {p} is accessible by group or others (mode "
                           f"{stat.S_IMODE(st.st_mode):04o}); run: chmod 600 {p}")
    try:
        text = read_limited(p, 4096, "a signing key file").decode("ascii", errors="replace")
    except ConfigError as e:
        raise KeyFileError(f"signing key file {p}: expected {e.expected}") from None
    lines = [ln.strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln and not ln.startswith("#")]
    if len(lines) != 1:
        raise KeyFileError(f"signing key file {p}: expected one line of {2 * KEY_LEN} hex digits")
    try:
        key = bytes.fromhex(lines[0])
    except ValueError:
        raise KeyFileError(f"signing key file {p}: the key is not hexadecimal") from None
    if len(key) != KEY_LEN:
        raise KeyFileError(f"signing key file {p}: the key has {len(key)} bytes, expected {KEY_LEN} "
                           f"({2 * KEY_LEN} hex digits)")
    return key


class UnsignedPolicy:
    """``allow_unsigned_callback`` for pymavlink with a key configured.

    Unsigned (or badly signed) messages are let through the parser only for the types in
    ``passed`` — HEARTBEAT, the parameter messages and COMMAND_LONG — so that the endpoint can
    answer a refused PARAM_SET/READ with PARAM_ERROR (PERMISSION_DENIED) instead of silence.
    The endpoint looks at each message's ``_signed`` flag and only heartbeats (and reads, when
    ``allow_unsigned_read``) are honoured unsigned. Everything else unsigned is dropped by pymavlink.
    """

    def __init__(self, mavlink_module) -> None:
        m = mavlink_module
        self.passed = {m.MAVLINK_MSG_ID_HEARTBEAT, m.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
                       m.MAVLINK_MSG_ID_PARAM_REQUEST_READ, m.MAVLINK_MSG_ID_PARAM_SET,
                       m.MAVLINK_MSG_ID_COMMAND_LONG}
        self.dropped = 0

    def __call__(self, mav, msg_id: int) -> bool:
        if msg_id in self.passed:
            return True
        self.dropped += 1
        return False


def check_signature_verified_first(mav: Any, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """pymavlink's ``MAVLink.check_signature`` with the signature checked *before* the stream's
    timestamp is recorded.

    pymavlink records a stream's timestamp before it compares the signature, so one forged
    frame carrying a future timestamp (and the ground station's link id, system and component)
    moves the stream's clock ahead and every genuine signed frame after it is refused as "old":
    the signed ground station is locked out. Here a frame whose signature does not verify
    changes nothing. The timestamp rules are pymavlink's (MAVLink 2 signing spec): a known
    stream's timestamp must increase; a new stream may be at most one minute behind ours.
    """
    signing = mav.signing
    timestamp_buf = msgbuf[-12:-6]
    link_id = msgbuf[-13]
    tlow, thigh = mav.mav_sign_unpacker.unpack(timestamp_buf)
    timestamp = tlow + (thigh << 32)
    digest = hashlib.sha256(signing.secret_key + bytes(msgbuf[:-6])).digest()[:6]
    if not hmac.compare_digest(digest, bytes(msgbuf[-6:])):
        return False
    stream_key = (link_id, src_system, src_component)
    last = signing.stream_timestamps.get(stream_key)
    if last is not None and timestamp <= last:
        return False  # a replay, or older than what this stream already sent
    if last is None and timestamp + 6000 * 1000 < signing.timestamp:
        return False  # a new stream more than a minute behind us
    signing.stream_timestamps[stream_key] = timestamp
    signing.timestamp = max(signing.timestamp, timestamp)
    return True


def install_verified_signature_check(mav: Any) -> None:
    """Make ``mav`` (a pymavlink ``MAVLink`` object with signing set up) use
    :func:`check_signature_verified_first`."""
    mav.check_signature = types.MethodType(check_signature_verified_first, mav)
