"""MAVLink 2 framing without pymavlink's per-byte parser and per-frame objects.

pymavlink packs a message through a header object, a bytearray and several struct calls, and
parses a datagram one byte at a time through a state machine: ~10-40 us of Python per frame,
which the simulator pays for every telemetry frame and setpoint and the ground station for every
telemetry frame and logged status. This module does the same framing in a few calls:

- :func:`pack` gives the same bytes as ``msg.pack(codec)`` for an unsigned codec (it falls back
  to pymavlink for a signing one); the caller advances ``codec.seq`` as before;
- :func:`parse` turns a datagram made only of whole, unsigned MAVLink 2 frames of known messages
  with good checksums into the message objects pymavlink would give (same fields, header and
  buffers), and returns None for anything else (junk, truncation, a bad checksum, a signed or
  MAVLink 1 frame, an unknown id), so that the caller parses that datagram with pymavlink, which
  counts and reports what is wrong as before.

Only for receive codecs without a signing key: an unsigned frame to a signing codec must go
through pymavlink's signature policy (callers check :func:`fast_receive_ok`).
tests/test_mavlink_fast.py compares both ways with pymavlink, message by message.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

import struct
from collections.abc import Callable
from typing import Any

from fastcrc.crc16 import mcrf4xx
from pymavlink.dialects.v20 import common as mavlink

_MAGIC_V2 = 0xFD
_HEADER = struct.Struct("<BBBBBBBHB")
_CRC = struct.Struct("<H")
_HEADER_LEN = 10
_MIN_FRAME = _HEADER_LEN + 1 + 2  # MAVLink 2 keeps at least one payload byte
_EXTRA = [bytes((b,)) for b in range(256)]  # a message's CRC_EXTRA byte


def fast_receive_ok(codec: Any) -> bool:
    """Whether frames for ``codec`` may be parsed by :func:`parse`: it has no signing key (an
    unsigned frame to a signing codec is judged by pymavlink's signing policy)."""
    return codec.signing.secret_key is None


# -- packing -----------------------------------------------------------------------------------
_Fields = Callable[[Any], list[Any]]
_FIELDS: dict[type, _Fields] = {}


def _fields_of(cls: type) -> _Fields:
    """The wire-order values of a message of class ``cls``, arrays spread out (as its pack)."""
    getter = _FIELDS.get(cls)
    if getter is not None:
        return getter
    names = list(cls.ordered_fieldnames)  # type: ignore[attr-defined]
    lengths = dict(zip(names, cls.array_lengths, strict=True))  # type: ignore[attr-defined]
    types = dict(zip(cls.fieldnames, cls.fieldtypes, strict=True))  # type: ignore[attr-defined]
    # a char array is packed from its raw bytes (pymavlink keeps the text as ``name`` and the
    # bytes as ``_name_raw``); other arrays are spread out
    plan = [
        (f"_{name}_raw", 0) if types[name] == "char" else (name, lengths[name]) for name in names
    ]

    def fields(msg: Any) -> list[Any]:
        out: list[Any] = []
        for name, length in plan:
            value = getattr(msg, name)
            if length:
                out.extend(value[:length])
            else:
                out.append(value)
        return out

    _FIELDS[cls] = fields
    return fields


def pack(msg: Any, codec: Any) -> bytes:
    """``msg.pack(codec)``: the same MAVLink 2 frame (codec's system, component and sequence
    number; trailing zero bytes of the payload cut), without pymavlink's per-frame objects."""
    if codec.signing.sign_outgoing:
        return bytes(msg.pack(codec))
    cls = type(msg)
    full = cls.unpacker.pack(*_fields_of(cls)(msg))
    payload = full.rstrip(b"\x00") or full[:1]  # MAVLink 2 cuts trailing zeros, keeps one byte
    msg_id = cls.id
    frame = (
        _HEADER.pack(
            _MAGIC_V2, len(payload), 0, 0, codec.seq, codec.srcSystem, codec.srcComponent,
            msg_id & 0xFFFF, msg_id >> 16,
        )
        + payload
    )  # fmt: skip
    return frame + _CRC.pack(mcrf4xx(_EXTRA[cls.crc_extra], mcrf4xx(frame[1:])))


# -- parsing -----------------------------------------------------------------------------------
def parse(data: bytes) -> list[Any] | None:
    """The messages of ``data`` if it is only whole, unsigned MAVLink 2 frames of known messages
    with good checksums; None otherwise (parse it with pymavlink then)."""
    out: list[Any] = []
    view = memoryview(data)
    i, n = 0, len(data)
    while i < n:
        if n - i < _MIN_FRAME or data[i] != _MAGIC_V2 or data[i + 2] != 0:
            return None  # not MAVLink 2, truncated, or signed (incompatibility flags)
        plen = data[i + 1]
        end = i + _HEADER_LEN + plen + 2
        if end > n:
            return None
        msg_id = data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16)
        cls = mavlink.mavlink_map.get(msg_id)
        if cls is None:
            return None
        crc = mcrf4xx(_EXTRA[cls.crc_extra], mcrf4xx(view[i + 1 : end - 2]))
        if crc != data[end - 2] | (data[end - 1] << 8):
            return None
        msg = _message(cls, data, i, plen, end, crc)
        if msg is None:
            return None
        out.append(msg)
        i = end
    return out


def _message(cls: Any, data: bytes, i: int, plen: int, end: int, crc: int) -> Any:
    """The message object of the frame ``data[i:end]`` (pymavlink's MAVLink.decode, unsigned)."""
    size = cls.unpacker.size
    payload = data[i + _HEADER_LEN : i + _HEADER_LEN + plen]
    body = payload[:size] if plen >= size else payload + bytes(size - plen)
    try:
        t = cls.unpacker.unpack(body)
    except struct.error:
        return None
    orders, lengths = cls.orders, cls.lengths
    if sum(lengths) == len(lengths):  # no arrays
        values: list[Any] = [t[o] for o in orders]
    else:
        values = []
        for order in orders:
            length = lengths[order]
            tip = sum(lengths[:order])
            field = t[tip]
            values.append(
                field if length == 1 or isinstance(field, bytes) else list(t[tip : tip + length])
            )
    values = [v.rstrip(b"\x00") if isinstance(v, bytes) else v for v in values]
    try:
        msg = cls(*values)
    except Exception:  # as pymavlink: a message it cannot build is not a message
        return None
    frame = bytearray(data[i:end])
    msg._signed = False
    msg._msgbuf = frame
    msg._payload = frame[6:-2]
    msg._crc = crc
    msg._header = mavlink.MAVLink_header(
        cls.id, 0, data[i + 3], plen, data[i + 4], data[i + 5], data[i + 6]
    )
    return msg
