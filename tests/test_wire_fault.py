"""Fault command wire format: golden bytes, layout by hand, encoder refusals, malformed input."""

from __future__ import annotations

import math
import struct

import pytest

from protocols.wire import WIRE_VERSION, Kind, Reason, WireError
from protocols.wire_fault import (
    Clear,
    Delay,
    Dropout,
    FaultCommand,
    FaultOp,
    LinkCut,
    LinkRestore,
    Loss,
    Partition,
    Restart,
    decode_fault,
    encode_fault,
    fault_op,
)

SID = "demo"
HEAD = bytes([0x51, WIRE_VERSION, Kind.FAULT, 4]) + b"demo"

#: Each command with its golden payload (hex) and the same bytes packed by hand.
GOLDEN: list[tuple[FaultCommand, str, bytes]] = [
    (Clear(), "5101040464656d6f00", HEAD + bytes([FaultOp.CLEAR])),
    (
        LinkCut(0, 4, one_way=True, duration_s=2.5),
        "5101040464656d6f01000004000100002040",
        HEAD + bytes([FaultOp.LINK_CUT]) + struct.pack("<HHBf", 0, 4, 1, 2.5),
    ),
    (
        LinkRestore(0, 4),
        "5101040464656d6f0200000400",
        HEAD + bytes([FaultOp.LINK_RESTORE]) + struct.pack("<HH", 0, 4),
    ),
    (
        Loss(0.5, (1, 2), 3.0),
        "5101040464656d6f030000003f010100020000004040",
        HEAD + bytes([FaultOp.LOSS]) + struct.pack("<fBHHf", 0.5, 1, 1, 2, 3.0),
    ),
    (
        Delay(40.0, None),
        "5101040464656d6f04000020420000000000",
        HEAD + bytes([FaultOp.DELAY]) + struct.pack("<fBHH", 40.0, 0, 0, 0),
    ),
    (
        Partition(((0, 1, 2), (3, 4))),
        "5101040464656d6f0502000300000001000200020003000400",
        HEAD + bytes([FaultOp.PARTITION]) + struct.pack("<HH3HH2H", 2, 3, 0, 1, 2, 2, 3, 4),
    ),
    (Partition(None), "5101040464656d6f050000", HEAD + bytes([FaultOp.PARTITION, 0, 0])),
    (
        Restart(3, 2.5),
        "5101040464656d6f06030000002040",
        HEAD + bytes([FaultOp.RESTART]) + struct.pack("<Hf", 3, 2.5),
    ),
    (Dropout(6), "5101040464656d6f070600", HEAD + bytes([FaultOp.DROPOUT, 6, 0])),
]


@pytest.mark.parametrize(("command", "golden", "by_hand"), GOLDEN)
def test_golden_bytes_and_layout(command: FaultCommand, golden: str, by_hand: bytes) -> None:
    data = encode_fault(command, SID)
    assert data.hex() == golden
    assert data == by_hand
    assert decode_fault(bytes.fromhex(golden), SID) == command


def test_each_command_has_its_op() -> None:
    ops = [fault_op(command) for command, _, _ in GOLDEN]
    assert [op.name.lower() for op in ops] == [
        "clear", "link_cut", "link_restore", "loss", "delay", "partition", "partition",
        "restart", "dropout",
    ]  # fmt: skip
    assert [encode_fault(c, SID)[len(HEAD)] for c, _, _ in GOLDEN] == [int(op) for op in ops]


def test_defaults_round_trip() -> None:
    for command in (LinkCut(3, 7), Loss(0.25), Delay(0.0, (2, 9)), Loss(1.0, None, 60.0)):
        assert decode_fault(encode_fault(command, SID), SID) == command


@pytest.mark.parametrize(
    "command",
    [
        LinkCut(1, 1),
        LinkCut(0, 70000),
        LinkCut(0, 1, duration_s=0.0),
        LinkCut(0, 1, duration_s=-1.0),
        LinkCut(0, 1, duration_s=math.inf),
        Loss(1.5),
        Loss(math.nan),
        Loss(0.1, (2, 2)),
        Delay(-1.0),
        Delay(math.nan),
        Partition(()),
        Partition(((0, 1), (1, 2))),
        Partition(((0,), ())),
        Restart(3, 0.0),
        Restart(3, math.nan),
        Restart(-1, 1.0),
        Dropout(-1),
    ],
)
def test_encoder_refuses_what_cannot_be_sent(command: FaultCommand) -> None:
    with pytest.raises(ValueError):
        encode_fault(command, SID)


def _op(op: int, body: bytes = b"") -> bytes:
    return HEAD + bytes([op]) + body


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (HEAD, Reason.TRUNCATED),
        (_op(9), Reason.BAD_VALUE),
        (_op(FaultOp.CLEAR, b"\0"), Reason.TRAILING),
        (_op(FaultOp.LINK_CUT, struct.pack("<HHBf", 0, 4, 0, 1.0)[:-1]), Reason.TRUNCATED),
        (_op(FaultOp.LINK_CUT, struct.pack("<HHBf", 0, 4, 2, 1.0)), Reason.BAD_VALUE),
        (_op(FaultOp.LINK_CUT, struct.pack("<HHBf", 3, 3, 0, 1.0)), Reason.BAD_VALUE),
        (_op(FaultOp.LINK_CUT, struct.pack("<HHBf", 0, 4, 0, math.nan)), Reason.BAD_VALUE),
        (_op(FaultOp.LINK_CUT, struct.pack("<HHBf", 0, 4, 0, -2.0)), Reason.BAD_VALUE),
        (_op(FaultOp.LINK_RESTORE, struct.pack("<HHB", 0, 4, 0)), Reason.TRAILING),
        (_op(FaultOp.LOSS, struct.pack("<fBHHf", 1.5, 0, 0, 0, 0.0)), Reason.BAD_VALUE),
        (_op(FaultOp.LOSS, struct.pack("<fBHHf", math.nan, 0, 0, 0, 0.0)), Reason.BAD_VALUE),
        (_op(FaultOp.LOSS, struct.pack("<fBHHf", 0.5, 0, 1, 2, 0.0)), Reason.BAD_VALUE),
        (_op(FaultOp.LOSS, struct.pack("<fBHHf", 0.5, 2, 1, 2, 0.0)), Reason.BAD_VALUE),
        (_op(FaultOp.DELAY, struct.pack("<fBHH", -5.0, 0, 0, 0)), Reason.BAD_VALUE),
        (_op(FaultOp.DELAY, struct.pack("<fBHH", math.inf, 0, 0, 0)), Reason.BAD_VALUE),
        (_op(FaultOp.PARTITION, b"\x01"), Reason.TRUNCATED),
        (_op(FaultOp.PARTITION, struct.pack("<HH", 1, 2) + b"\0\0"), Reason.TRUNCATED),
        (_op(FaultOp.PARTITION, struct.pack("<HH2H", 1, 2, 3, 1)), Reason.BAD_VALUE),
        (_op(FaultOp.PARTITION, struct.pack("<HH", 1, 0)), Reason.BAD_VALUE),
        (_op(FaultOp.PARTITION, struct.pack("<HHHHH", 2, 1, 5, 1, 5)), Reason.BAD_VALUE),
        (_op(FaultOp.PARTITION, struct.pack("<HHH", 1, 1, 5) + b"\0"), Reason.TRAILING),
        (b"\x51\x01\x02\x04demo\x00", Reason.WRONG_KIND),
        (b"\x51\x02\x04\x04demo\x00", Reason.BAD_VERSION),
        (b"\x51\x01\x04\x05other\x00", Reason.WRONG_SWARM),
        (b"\x00\x01\x04\x04demo\x00", Reason.BAD_MAGIC),
        (_op(FaultOp.CLEAR) + bytes(5000), Reason.OVERSIZED),
    ],
)
def test_malformed_fault_is_rejected(data: bytes, reason: Reason) -> None:
    with pytest.raises(WireError) as info:
        decode_fault(data, SID)
    assert info.value.reason is reason


def test_every_truncation_raises_only_wire_errors() -> None:
    for _, golden, _ in GOLDEN:
        data = bytes.fromhex(golden)
        for n in range(len(data)):
            with pytest.raises(WireError):
                decode_fault(data[:n], SID)
