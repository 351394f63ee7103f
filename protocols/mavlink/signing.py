"""MAVLink 2 signing: key files and codec set-up shared by the simulator, agents and GCS.

A key file holds the 32-byte secret either raw (exactly 32 bytes) or as 64 hexadecimal characters
(surrounding whitespace allowed). pymavlink also calls the unsigned-callback for frames with a
*wrong* signature, so only harmless message types may pass through it (DEPENDENCIES.md): never
commands or setpoints.
"""

from __future__ import annotations

import hashlib
import time
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: Message types accepted without a valid signature: link-level only, never commands.
HARMLESS_UNSIGNED = frozenset({"RADIO_STATUS"})
#: MAVLink signing timestamps count 10 µs units since 2015-01-01.
_SIGNING_EPOCH_S = 1420070400
#: A new stream may start up to a minute (in 10 µs units) before our own timestamp.
_NEW_STREAM_SLACK = 6_000_000


class SigningKeyError(ValueError):
    """The key file is missing or is not 32 bytes (raw) or 64 hex characters."""


def load_signing_key(path: str | Path) -> bytes:
    """The 32-byte secret of a key file; SigningKeyError naming the file and what is wrong."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise SigningKeyError(f"{p}: cannot read the signing key ({exc.strerror or exc})") from None
    if len(data) == 32:
        return data
    text = data.strip()
    if len(text) == 64:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    raise SigningKeyError(
        f"{p}: a signing key is 32 raw bytes or 64 hex characters, this file has {len(data)} bytes"
    )


def _allow_harmless(_mav: Any, msg_id: int) -> bool:
    from pymavlink.dialects.v20 import common

    cls = common.mavlink_map.get(msg_id)
    return cls is not None and cls.msgname in HARMLESS_UNSIGNED


def setup_signing(
    mav: Any, key: bytes, link_id: int, wall_clock: Callable[[], float] | None = None
) -> None:
    """Sign everything ``mav`` (a pymavlink codec) sends, and reject unsigned or wrongly signed
    incoming frames except harmless link-level types."""
    now = (wall_clock or time.time)()
    mav.signing.secret_key = key
    mav.signing.sign_outgoing = True
    mav.signing.allow_unsigned_callback = _allow_harmless
    mav.signing.link_id = link_id
    mav.signing.timestamp = max(int((now - _SIGNING_EPOCH_S) * 100_000), 1)
    mav.check_signature = types.MethodType(check_signature_first, mav)


def check_signature_first(mav: Any, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """pymavlink's ``MAVLink.check_signature``, but the signature is verified *before* the
    stream's timestamp is recorded. pymavlink records the timestamp of a frame with a wrong
    signature too, so anyone could block a signed stream by sending junk-signed frames with a
    large timestamp (every genuine frame after it would be "old")."""
    timestamp_low, timestamp_high = mav.mav_sign_unpacker.unpack(msgbuf[-12:-6])
    timestamp = timestamp_low + (timestamp_high << 32)
    digest = hashlib.sha256(mav.signing.secret_key + bytes(msgbuf[:-6])).digest()
    if digest[:6] != bytes(msgbuf[-6:]):
        return False
    stream = (msgbuf[-13], src_system, src_component)
    last = mav.signing.stream_timestamps.get(stream)
    if last is not None and timestamp <= last:
        return False  # a replay, or out of order
    if last is None and timestamp + _NEW_STREAM_SLACK < mav.signing.timestamp:
        return False  # a new stream more than a minute in the past
    mav.signing.stream_timestamps[stream] = timestamp
    mav.signing.timestamp = max(mav.signing.timestamp, timestamp)
    return True
