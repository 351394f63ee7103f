"""protocols/mavlink/fast.py against pymavlink: the same bytes out, the same messages in, for every
message of the common dialect with random fields; anything pymavlink would have to judge (junk,
truncation, bad checksums, signed or MAVLink 1 frames, unknown ids) is left to it."""

from __future__ import annotations

import math
import os
import struct
from typing import Any

os.environ["MAVLINK20"] = "1"

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from protocols.mavlink.fast import fast_receive_ok, pack, packed, parse
from protocols.mavlink.signing import setup_signing

_INT_RANGES = {
    "uint8_t": (0, 255), "int8_t": (-128, 127), "uint16_t": (0, 65535),
    "int16_t": (-32768, 32767), "uint32_t": (0, 2**32 - 1), "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1), "int64_t": (-(2**63), 2**63 - 1),
}  # fmt: skip


def _value(ftype: str, length: int, rng: np.random.Generator, zeros: bool) -> object:
    def one() -> object:
        if zeros and rng.random() < 0.5:
            return 0 if ftype not in ("float", "double") else 0.0
        if ftype in ("float", "double"):
            return float(np.float32(rng.normal(0.0, 100.0)))
        lo, hi = _INT_RANGES[ftype]
        return int(rng.integers(lo, hi, endpoint=True, dtype=np.uint64 if lo == 0 else np.int64))

    if ftype == "char":
        size = int(rng.integers(0, length + 1)) if length else 1
        return bytes(rng.integers(97, 123, size).astype(np.uint8))
    if length:
        return [one() for _ in range(length)]
    return one()


def _random_message(cls: type, rng: np.random.Generator, zeros: bool = False) -> object:
    c: Any = cls
    lengths = dict(zip(c.ordered_fieldnames, c.array_lengths, strict=True))
    types = dict(zip(c.fieldnames, c.fieldtypes, strict=True))
    return cls(*(_value(types[name], lengths[name], rng, zeros) for name in c.fieldnames))


def _codec(sysid: int = 7, compid: int = 1, seq: int = 0) -> object:
    codec = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    codec.robust_parsing = True
    codec.seq = seq
    return codec


def _pymavlink_parse(data: bytes) -> list[object]:
    return _codec().parse_buffer(data) or []


def _same(a: object, b: object) -> None:
    assert type(a) is type(b)
    for name in a.fieldnames:  # type: ignore[attr-defined]
        va, vb = getattr(a, name), getattr(b, name)
        if isinstance(va, float) and math.isnan(va):
            assert isinstance(vb, float) and math.isnan(vb), name
        elif isinstance(va, list) and any(isinstance(v, float) and math.isnan(v) for v in va):
            assert struct.pack(f"{len(va)}d", *va) == struct.pack(f"{len(vb)}d", *vb), name
        else:
            assert va == vb, name
    for attr in ("msgId", "incompat_flags", "compat_flags", "mlen", "seq", "srcSystem",
                 "srcComponent"):  # fmt: skip
        assert getattr(a._header, attr) == getattr(b._header, attr), attr  # type: ignore[attr-defined]
    assert bytes(a._msgbuf) == bytes(b._msgbuf)  # type: ignore[attr-defined]
    assert bytes(a._payload) == bytes(b._payload)  # type: ignore[attr-defined]
    assert a._crc == b._crc and a._signed == b._signed  # type: ignore[attr-defined]


@pytest.mark.parametrize("zeros", [False, True])
def test_every_common_message_packs_and_parses_as_pymavlink_does(zeros: bool) -> None:
    rng = np.random.default_rng(3 if zeros else 2)
    for msg_id, cls in sorted(mavlink.mavlink_map.items()):
        for _ in range(3):
            msg = _random_message(cls, rng, zeros)
            seq, sysid, compid = (int(v) for v in rng.integers(0, 256, 3))
            codec = _codec(max(sysid, 1), compid, seq)
            frame = pack(msg, codec)
            assert frame == bytes(msg.pack(codec)), cls.msgname  # type: ignore[attr-defined]
            ours, theirs = parse(frame), _pymavlink_parse(frame)
            assert ours is not None and len(ours) == len(theirs) == 1, msg_id
            _same(ours[0], theirs[0])


def test_a_datagram_of_several_frames_parses_whole() -> None:
    rng = np.random.default_rng(5)
    codec = _codec(3)
    classes = [mavlink.MAVLink_attitude_message, mavlink.MAVLink_local_position_ned_message,
               mavlink.MAVLink_heartbeat_message, mavlink.MAVLink_statustext_message]  # fmt: skip
    frames = []
    for k, cls in enumerate(classes * 3):
        codec.seq = k
        frames.append(pack(_random_message(cls, rng), codec))
    data = b"".join(frames)
    ours, theirs = parse(data), _pymavlink_parse(data)
    assert ours is not None and len(ours) == len(theirs) == len(frames)
    for a, b in zip(ours, theirs, strict=True):
        _same(a, b)
    assert parse(b"") == []


def test_a_light_message_has_the_fields_of_pymavlinks_object() -> None:
    """Every message without text fields read lightly (fast.fields_of): the same values, type
    name and sender as pymavlink's object of the frame, in a datagram of several kinds."""
    rng = np.random.default_rng(11)
    light = frozenset(cls for cls in mavlink.mavlink_map.values() if "char" not in cls.fieldtypes)
    for cls in sorted(light, key=lambda c: c.id)[:400]:
        codec = _codec(int(rng.integers(1, 255)), int(rng.integers(0, 256)))
        others = [pack(_random_message(mavlink.MAVLink_statustext_message, rng), codec)]
        data = pack(_random_message(cls, rng, bool(rng.random() < 0.5)), codec) + others[0]
        ours, theirs = parse(data, light), _pymavlink_parse(data)
        assert ours is not None and len(ours) == len(theirs) == 2
        for name in theirs[0].fieldnames:
            a, b = getattr(ours[0], name), getattr(theirs[0], name)
            assert struct.pack("d", a) == struct.pack("d", b) if isinstance(b, float) else a == b
        for method in ("get_type", "get_srcSystem", "get_srcComponent"):
            assert getattr(ours[0], method)() == getattr(theirs[0], method)(), method
        _same(ours[1], theirs[1])  # a message with text: pymavlink's object still


def test_what_pymavlink_must_judge_is_left_to_it() -> None:
    rng = np.random.default_rng(6)
    codec = _codec(4)
    msg = _random_message(mavlink.MAVLink_set_attitude_target_message, rng)
    frame = pack(msg, codec)
    assert parse(frame) is not None
    assert parse(frame[:-1]) is None  # truncated
    assert parse(frame + frame[:5]) is None  # a whole frame and a truncated one
    bad = bytearray(frame)
    bad[12] ^= 0xFF
    assert parse(bytes(bad)) is None  # bad checksum
    assert parse(b"\x00junk" + frame) is None
    unknown = bytearray(frame)
    unknown[7:10] = (0xFF, 0xFF, 0x00)  # an id the dialect does not know
    assert parse(bytes(unknown)) is None
    v1 = msg.pack(_codec(4), force_mavlink1=True)  # type: ignore[attr-defined]
    assert parse(bytes(v1)) is None
    signing = _signed_twin()
    signed = pack(msg, signing)  # a signing codec: pymavlink packs (and signs) it
    assert signed == bytes(msg.pack(_signed_twin()))  # type: ignore[attr-defined]
    assert signed[2] & mavlink.MAVLINK_IFLAG_SIGNED
    assert parse(signed) is None
    assert fast_receive_ok(_codec()) and not fast_receive_ok(signing)


def _signed_twin() -> Any:
    """A signing codec at a fixed time (two of them sign a frame the same way)."""
    twin = _codec(4)
    setup_signing(twin, bytes(range(32)), 0, wall_clock=lambda: 1.9e9)
    return twin


@pytest.mark.parametrize("signed", [False, True])
def test_a_message_packed_from_its_fields_is_framed_as_its_object(signed: bool) -> None:
    """``packed(cls, *fields)`` (the simulator's state messages, no pymavlink object) frames to
    the bytes of ``cls(*fields)``, for every message of the common dialect, signed or not, and
    gives that object back."""
    rng = np.random.default_rng(5)
    key = bytes(range(32))
    for _, cls in sorted(mavlink.mavlink_map.items()):
        c: Any = cls
        lengths = dict(zip(c.ordered_fieldnames, c.array_lengths, strict=True))
        types = dict(zip(c.fieldnames, c.fieldtypes, strict=True))
        values = [_value(types[n], lengths[n], rng, False) for n in c.fieldnames]
        ours, theirs = _codec(7, 1, 9), _codec(7, 1, 9)
        if signed:
            for codec in (ours, theirs):
                setup_signing(codec, key, link_id=1)
                codec.signing.timestamp = 1234
        frame = pack(packed(cls, *values), ours)
        assert frame == bytes(cls(*values).pack(theirs)), c.msgname
        back, made = packed(cls, *values).message(), cls(*values)
        assert type(back) is cls
        assert [getattr(back, n) for n in c.fieldnames] == [getattr(made, n) for n in c.fieldnames]
