"""Fault command wire format: golden bytes, layout by hand, encoder refusals, malformed input,
versions 1 and 2, and the scenario's faults carried by the same classes."""

from __future__ import annotations

import dataclasses
import math
import struct
from typing import Any, cast

import pytest

from protocols.faults import (
    Clear,
    Crash,
    Delay,
    Dropout,
    FaultCommand,
    LinkCut,
    LinkRestore,
    Loss,
    Partition,
    Restart,
)
from protocols.scenario.scenario_file import parse_scenario
from protocols.wire.fault import FaultOp, decode_fault, encode_fault, fault_op
from protocols.wire.format import WIRE_VERSION, Kind, Reason, WireError, open_versioned

SID = "demo"
HEAD = bytes([0x51, WIRE_VERSION, Kind.FAULT, 4]) + b"demo"
HEAD_V2 = bytes([0x51, 2, Kind.FAULT, 4]) + b"demo"

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
    (  # version 2: a timed delay
        Delay(40.0, (1, 2), 2.5),
        "5102040464656d6f0400002042010100020000002040",
        HEAD_V2 + bytes([FaultOp.DELAY]) + struct.pack("<fBHHf", 40.0, 1, 1, 2, 2.5),
    ),
    (  # version 2: a timed partition
        Partition(((0, 1), (2,)), 3.0),
        "5102040464656d6f05020002000000010001000200000040" + "40",
        HEAD_V2 + bytes([FaultOp.PARTITION]) + struct.pack("<HH2HHHf", 2, 2, 0, 1, 1, 2, 3.0),
    ),
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
        "restart", "dropout", "delay", "partition",
    ]  # fmt: skip
    assert [op.name.lower() for op in ops] == [c.kind for c, _, _ in GOLDEN]
    assert [encode_fault(c, SID)[len(HEAD)] for c, _, _ in GOLDEN] == [int(op) for op in ops]


def test_defaults_round_trip() -> None:
    for command in (LinkCut(3, 7), Loss(0.25), Delay(0.0, (2, 9)), Loss(1.0, None, 60.0)):
        assert decode_fault(encode_fault(command, SID), SID) == command


def test_a_heal_is_a_partition_without_groups() -> None:
    assert Partition(None) == Partition(()) and Partition(None).heals
    assert decode_fault(encode_fault(Partition(()), SID), SID) == Partition(None)


def test_only_timed_delays_and_partitions_need_version_2() -> None:
    """A build that speaks only version 1 reads every other command and refuses a timed delay
    or partition by its version, not by a misread body."""
    for command, golden, _ in GOLDEN:
        data = bytes.fromhex(golden)
        timed = isinstance(command, Delay | Partition) and command.duration_s is not None
        assert data[1] == (2 if timed else 1), command
        if timed:
            with pytest.raises(WireError, match="version 2, this build speaks 1") as info:
                open_versioned(data, Kind.FAULT, SID, 4096, (1,))
            assert info.value.reason is Reason.BAD_VERSION
    # the untimed ops read the same at version 2
    restore = HEAD_V2 + bytes([FaultOp.LINK_RESTORE]) + struct.pack("<HH", 0, 4)
    assert decode_fault(restore, SID) == LinkRestore(0, 4)


SCENARIO_FAULTS = [
    {"t_s": 1.0, "kind": "dropout", "drone": 2},
    {"t_s": 2.0, "kind": "loss", "probability": 0.5},
    {"t_s": 3.0, "kind": "loss", "probability": 0.25, "drones": [0, 1], "duration_s": 2.0},
    {"t_s": 4.0, "kind": "delay", "delay_ms": 40.0, "duration_s": 5.0},
    {"t_s": 4.5, "kind": "delay", "delay_ms": 20.0, "drones": [1, 2]},
    {"t_s": 5.0, "kind": "partition", "groups": [[0], [2]], "duration_s": 10.0},
    {"t_s": 6.0, "kind": "link_cut", "drones": [2, 0], "one_way": True, "duration_s": 1.5},
    {"t_s": 7.0, "kind": "link_cut", "drones": [1, 2]},
]


def test_a_scenario_fault_is_a_drill_command_with_a_start_time() -> None:
    """Each fault a scenario file can schedule (but the vehicle crash) is the command the wire
    carries, with its t_s: sent at its time, it arrives as itself."""
    data: dict[str, Any] = {
        "version": 1,
        "name": "faults",
        "duration_s": 20.0,
        "drones": [{"position_ned_m": [0.0, 3.0 * i, 0.0]} for i in range(3)],
        "trajectory": {
            "waypoints": [
                {"t_s": 0.0, "centre_ned_m": [0.0, 3.0, -2.0], "spread_m": [1.0, 3.0, 0.0]}
            ]
        },
        "faults": SCENARIO_FAULTS,
    }
    faults = parse_scenario(data, "x.toml").faults
    assert [f.t_s for f in faults] == [f["t_s"] for f in SCENARIO_FAULTS]
    for fault in faults:
        assert not isinstance(fault, Crash)
        with pytest.raises(ValueError, match="t_s does not travel"):
            encode_fault(fault, SID)
        command = dataclasses.replace(fault, t_s=0.0)
        assert decode_fault(encode_fault(command, SID), SID) == command


def test_a_crash_is_not_an_agents_command() -> None:
    with pytest.raises(ValueError, match="crash"):
        encode_fault(cast(FaultCommand, Crash(1)), SID)


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
        Partition(((0, 1), (1, 2))),
        Partition(None, 2.0),
        Delay(10.0, duration_s=0.0),
        Partition(((0,),), duration_s=math.inf),
        LinkCut(0, 1, t_s=3.0),
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
        (b"\x51\x03\x04\x04demo\x00", Reason.BAD_VERSION),
        (HEAD_V2 + bytes([FaultOp.DELAY]) + struct.pack("<fBHH", 5.0, 0, 0, 0), Reason.TRUNCATED),
        (
            HEAD_V2 + bytes([FaultOp.DELAY]) + struct.pack("<fBHHf", 5.0, 0, 0, 0, 0.0),
            Reason.BAD_VALUE,
        ),
        (HEAD_V2 + bytes([FaultOp.PARTITION]) + struct.pack("<Hf", 0, 1.0), Reason.BAD_VALUE),
        (HEAD_V2 + bytes([FaultOp.PARTITION]) + struct.pack("<HHH", 1, 1, 5), Reason.TRUNCATED),
        (
            HEAD_V2 + bytes([FaultOp.PARTITION]) + struct.pack("<HHHf", 1, 1, 5, math.nan),
            Reason.BAD_VALUE,
        ),
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
