"""MAVLink 2 framing without pymavlink's per-byte parser and per-frame objects.

pymavlink packs a message through a header object, a bytearray and several struct calls
(~2.5 us of CPU on the 2-core machine), and parses a datagram one byte at a time through a state
machine (~6 us a frame), which the simulator pays for every telemetry frame and setpoint and the
ground station for every telemetry frame and logged status. This module does the same framing in
a few calls (~0.9 us to pack; ~1.2 us to check and split a frame, ~4 us with pymavlink's message
object built):

- :func:`pack` gives the same bytes as ``msg.pack(codec)`` for an unsigned codec (it falls back
  to pymavlink for a signing one); the caller advances ``codec.seq`` as before;
  :func:`pack_payload` frames a payload packed by the caller (no message object at all);
- :func:`parse` turns a datagram made only of whole, unsigned MAVLink 2 frames of known messages
  with good checksums into the message objects pymavlink would give (same fields, header and
  buffers), and returns None for anything else (junk, truncation, a bad checksum, a signed or
  MAVLink 1 frame, an unknown id), so that the caller parses that datagram with pymavlink, which
  counts and reports what is wrong as before; :func:`frames` gives the checked frames alone
  (class, header, payload), for a caller that unpacks its few messages itself.

Only for receive codecs without a signing key: an unsigned frame to a signing codec must go
through pymavlink's signature policy (callers check :func:`fast_receive_ok`).
tests/test_mavlink_fast.py compares both ways with pymavlink, message by message.
"""

from __future__ import annotations

import os

os.environ["MAVLINK20"] = "1"  # before any pymavlink import (DEPENDENCIES.md)

import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from operator import attrgetter, itemgetter
from typing import Any, NamedTuple

from fastcrc.crc16 import mcrf4xx
from pymavlink.dialects.v20 import common as mavlink

_MAGIC_V2 = 0xFD
_HEADER = struct.Struct("<BBBBBBBHB")
_CRC = struct.Struct("<H")
_HEADER_LEN = 10
_MIN_FRAME = _HEADER_LEN + 1 + 2  # MAVLink 2 keeps at least one payload byte
_EXTRA = [bytes((b,)) for b in range(256)]  # a message's CRC_EXTRA byte


def fast_receive_ok(codec: Any) -> bool:
    """Whether the next datagram for ``codec`` may be parsed by :func:`parse`: it has no signing
    key (an unsigned frame to a signing codec is judged by pymavlink's signing policy) and holds
    no part of a frame from an earlier datagram (pymavlink goes on parsing that)."""
    return codec.signing.secret_key is None and not codec.buf_len()


# -- packing -----------------------------------------------------------------------------------
_Fields = Callable[[Any], Sequence[Any]]
_FIELDS: dict[type, _Fields] = {}


def _wire_plan(cls: Any) -> list[tuple[str, int, int]]:
    """Each field of message class ``cls`` in wire order: the attribute its value is packed from,
    its place among the constructor's (declared) arguments, and its length where the value is an
    array spread out (0: one value; a char array is packed from its raw bytes: pymavlink keeps
    the text as ``name`` and the bytes as ``_name_raw``)."""
    names = list(cls.fieldnames)
    types = dict(zip(names, cls.fieldtypes, strict=True))
    return [
        (f"_{name}_raw", names.index(name), 0)
        if types[name] == "char"
        else (name, names.index(name), length)
        for name, length in zip(cls.ordered_fieldnames, cls.array_lengths, strict=True)
    ]


def _spread(
    plan: list[tuple[Any, int]], values: Callable[[Any, Any], Any]
) -> Callable[[Any], list[Any]]:
    """The wire-order values of a message, arrays spread out, from ``values(key)`` of each field
    (``plan``: each field's key and its spread length, 0 for one value)."""

    def fields(source: Any) -> list[Any]:
        out: list[Any] = []
        for key, length in plan:
            value = values(source, key)
            if length:
                out.extend(value[:length])
            else:
                out.append(value)
        return out

    return fields


def _fields_of(cls: type) -> _Fields:
    """The wire-order values of a message of class ``cls``, arrays spread out (as its pack)."""
    getter = _FIELDS.get(cls)
    if getter is not None:
        return getter
    plan = [(name, length) for name, _, length in _wire_plan(cls)]
    if not any(length for _, length in plan):  # no arrays to spread: one C call
        get = attrgetter(*(name for name, _ in plan))
        getter = (lambda msg: (get(msg),)) if len(plan) == 1 else get
    else:
        getter = _spread(plan, getattr)
    _FIELDS[cls] = getter
    return getter


class Packed(NamedTuple):
    """A message as its class and its full payload (its fields in wire order, ``cls.unpacker``'s
    layout), made by :func:`packed` without pymavlink's message object; :func:`pack` frames it
    as it frames the object."""

    cls: Any
    payload: bytes

    def message(self) -> Any:
        """pymavlink's message object of the same fields."""
        return _built(self.cls, self.payload)


_WIRE: dict[type, Callable[[Sequence[Any]], Sequence[Any]]] = {}


def packed(cls: Any, *values: Any) -> Packed:
    """Message class ``cls`` with ``values`` in its declared order, as its constructor takes
    them (a numeric array as a sequence of its length, a char array as bytes), packed."""
    wire = _WIRE.get(cls)
    if wire is None:
        wire = _WIRE[cls] = _wire_order(cls)
    return Packed(cls, cls.unpacker.pack(*wire(values)))


def _wire_order(cls: Any) -> Callable[[Sequence[Any]], Sequence[Any]]:
    """The wire-order values (arrays spread) of a message's declared-order values."""
    plan = [(k, length) for _, k, length in _wire_plan(cls)]
    if not any(length for _, length in plan):  # no arrays to spread: one C call
        get = itemgetter(*(k for k, _ in plan))
        return (lambda values: (get(values),)) if len(plan) == 1 else get
    return _spread(plan, lambda values, k: values[k])


def pack(msg: Any, codec: Any) -> bytes:
    """``msg.pack(codec)``: the same MAVLink 2 frame (codec's system, component and sequence
    number; trailing zero bytes of the payload cut), without pymavlink's per-frame objects. A
    :class:`Packed` message is framed from its payload (signed: from the object it makes)."""
    if type(msg) is Packed:
        if codec.signing.sign_outgoing:
            return bytes(msg.message().pack(codec))
        return pack_payload(msg.cls, msg.payload, codec)
    if codec.signing.sign_outgoing:
        return bytes(msg.pack(codec))
    cls = type(msg)
    return pack_payload(cls, cls.unpacker.pack(*_fields_of(cls)(msg)), codec)


def payload_of(msg: Any) -> tuple[Any, bytes]:
    """A message's class and full payload (its fields in wire order), as :func:`pack` frames
    them: a :class:`Packed` one's own, a pymavlink object's packed from its fields."""
    if type(msg) is Packed:
        return msg.cls, msg.payload
    cls = type(msg)
    return cls, cls.unpacker.pack(*_fields_of(cls)(msg))


def pack_payload(cls: Any, payload: bytes, codec: Any) -> bytes:
    """The unsigned MAVLink 2 frame of message class ``cls`` with the full ``payload`` (its
    fields in wire order, ``cls.unpacker``'s layout), from ``codec``'s system and component with
    its sequence number: what pymavlink's pack makes of the same fields. The caller checks that
    ``codec`` does not sign (:func:`pack` does)."""
    payload = payload.rstrip(b"\x00") or payload[:1]  # MAVLink 2 cuts trailing zeros, keeps one
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
class Frame(NamedTuple):
    """One checked MAVLink 2 frame of a datagram: its message class, header fields, the payload
    zero-padded (or cut) to the message's full size (``cls.unpacker`` unpacks it), the frame's
    place in the datagram and its checksum."""

    cls: Any
    compat_flags: int
    seq: int
    sysid: int
    compid: int
    body: bytes
    start: int
    end: int
    crc: int


def frames(data: bytes, known: Mapping[int, Any] | None = None) -> list[Frame] | None:
    """The frames of ``data`` if it is only whole, unsigned MAVLink 2 frames of messages in
    ``known`` (id -> class; default: the whole common dialect) with good checksums; None
    otherwise (parse it with pymavlink then)."""
    table = mavlink.mavlink_map if known is None else known
    out: list[Frame] = []
    view = memoryview(data)
    i, n = 0, len(data)
    while i < n:
        if n - i < _MIN_FRAME or data[i] != _MAGIC_V2 or data[i + 2] != 0:
            return None  # not MAVLink 2, truncated, or signed (incompatibility flags)
        plen = data[i + 1]
        end = i + _HEADER_LEN + plen + 2
        if end > n:
            return None
        cls = table.get(data[i + 7] | (data[i + 8] << 8) | (data[i + 9] << 16))
        if cls is None:
            return None
        crc = mcrf4xx(_EXTRA[cls.crc_extra], mcrf4xx(view[i + 1 : end - 2]))
        if crc != data[end - 2] | (data[end - 1] << 8):
            return None
        size = cls.unpacker.size
        payload = data[i + _HEADER_LEN : end - 2]
        body = payload[:size] if plen >= size else payload + bytes(size - plen)
        seq, sysid, compid = data[i + 4], data[i + 5], data[i + 6]
        out.append(Frame(cls, data[i + 3], seq, sysid, compid, body, i, end, crc))
        i = end
    return out


def parse(data: bytes, light: frozenset[Any] = frozenset()) -> list[Any] | None:
    """The messages of ``data`` (pymavlink's message objects, as its parser gives them) if it
    is only whole, unsigned MAVLink 2 frames of known messages with good checksums; None
    otherwise (parse it with pymavlink then). A message of a class in ``light`` comes as its
    :func:`fields_of` instead (the same fields, no pymavlink object)."""
    found = frames(data)
    if found is None:
        return None
    out: list[Any] = []
    for frame in found:
        msg = fields_of(frame) if frame.cls in light else message_of(frame, data)
        if msg is None:
            return None
        out.append(msg)
    return out


_LIGHT: dict[Any, Any] = {}


def _light_class(cls: Any) -> Any:
    """A named tuple of message class ``cls``'s fields (declared order) and its sender, with
    the reading methods of pymavlink's messages that a receiver uses (``get_type``,
    ``get_srcSystem``, ``get_srcComponent``); made once per class."""
    made = _LIGHT.get(cls)
    if made is None:
        if "char" in cls.fieldtypes:  # pymavlink's object makes text of a char array
            raise ValueError(f"{cls.msgname} has text fields: not read lightly")
        base = NamedTuple(  # type: ignore[misc]
            f"Light{cls.msgname.title()}",
            [*((name, Any) for name in cls.fieldnames), ("src_system", int),
             ("src_component", int)],
        )  # fmt: skip
        name = cls.msgname
        made = _LIGHT[cls] = type(
            base.__name__,
            (base,),
            {
                "__slots__": (),
                "get_type": lambda self: name,
                "get_srcSystem": lambda self: self.src_system,
                "get_srcComponent": lambda self: self.src_component,
            },
        )
    return made


def fields_of(f: Frame) -> Any:
    """The fields of frame ``f`` as its class's light message (:func:`_light_class`): the values
    pymavlink's object of the frame has (arrays as lists), read the same way; None if the
    payload does not unpack."""
    values = _values(f.cls, f.body)
    if values is None:
        return None
    return _light_class(f.cls)(*values, f.sysid, f.compid)


def _values(cls: Any, body: bytes) -> list[Any] | None:
    """The declared-order values of message class ``cls`` in the full payload ``body`` (wire
    order), as pymavlink's constructor takes them; None if it does not unpack."""
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
    return [v.rstrip(b"\x00") if isinstance(v, bytes) else v for v in values]


def _built(cls: Any, body: bytes) -> Any:
    """Message class ``cls``'s object of the full payload ``body`` (wire order), None if it
    does not unpack or pymavlink cannot build it."""
    values = _values(cls, body)
    if values is None:
        return None
    try:
        return cls(*values)
    except Exception:  # as pymavlink: a message it cannot build is not a message
        return None


def message_of(f: Frame, data: bytes) -> Any:
    """The message object of frame ``f`` of ``data`` (pymavlink's MAVLink.decode, unsigned)."""
    cls = f.cls
    msg = _built(cls, f.body)
    if msg is None:
        return None
    frame = bytearray(data[f.start : f.end])
    msg._signed = False
    msg._msgbuf = frame
    msg._payload = frame[6:-2]
    msg._crc = f.crc
    msg._header = mavlink.MAVLink_header(
        cls.id, 0, f.compat_flags, len(frame) - _HEADER_LEN - 2, f.seq, f.sysid, f.compid
    )
    return msg


@dataclass(frozen=True)
class FieldPlaces:
    """Where a message's fields are in its unpacked payload (``cls.unpacker``'s tuple, wire
    order): ``at`` each field's first value, ``arrays`` an array field's first element,
    ``scalars`` the fields in their declared order when none is an array."""

    at: dict[str, int]
    arrays: dict[str, int]
    scalars: tuple[int, ...]


_PLACES: dict[type, FieldPlaces] = {}


def field_places(cls: Any) -> FieldPlaces:
    """Where the fields of pymavlink message class ``cls`` are (:func:`message_of` reads them
    from the same places), for a reader that takes a frame's values without building its
    message object; made once per class."""
    got = _PLACES.get(cls)
    if got is not None:
        return got
    at: dict[str, int] = {}
    arrays: dict[str, int] = {}
    for name, kind, order in zip(cls.fieldnames, cls.fieldtypes, cls.orders, strict=True):
        tip = sum(cls.lengths[:order])
        at[name] = tip
        if cls.lengths[order] > 1 and kind != "char":
            arrays[name] = tip
    scalars = () if arrays else tuple(at[n] for n in cls.fieldnames)
    got = _PLACES[cls] = FieldPlaces(at, arrays, scalars)
    return got
