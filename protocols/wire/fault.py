"""The fault command (Kind.FAULT): a link-fault drill sent to every agent on ``swarm/<sid>/fault``.

The commands are the classes of :mod:`protocols.faults` (the vocabulary scenarios use too); this
module is their codec. A command's ``t_s`` (a scenario's start time) does not travel: a drill
applies when it arrives, so only commands with ``t_s`` 0 are encoded.

Body after the common header (``protocols.wire.format``), little-endian: ``u8 op`` (FaultOp), then::

    CLEAR         (nothing)
    LINK_CUT      u16 i, u16 j, u8 one_way (0/1), f32 duration_s (0: until restored)
    LINK_RESTORE  u16 i, u16 j
    LOSS          f32 probability (0..1), u8 has_link (0/1), u16 i, u16 j,
                  f32 duration_s (0: until changed)
    DELAY         f32 delay_ms (>= 0), u8 has_link (0/1), u16 i, u16 j
                  [version 2: then f32 duration_s (> 0)]
    PARTITION     u16 n_groups (0: heal), then per group u16 n, n x u16 ids (strictly
                  increasing; no drone in two groups) [version 2: then f32 duration_s (> 0)]
    RESTART       u16 drone, f32 gap_s (> 0): the process hosting drone's agent kills it and
                  starts a new one (a new incarnation) gap_s simulated seconds later
    DROPOUT       u16 drone: the process hosting drone's agent kills it for good (its other
                  agents fly on; the ground station's dropout drill of a hosted agent)

``i``/``j`` are drone indices; with ``has_link`` 0 the command applies to every link and i, j
are 0. A one-way cut stops i -> j only (what j receives from i).

Versions (FAULT_VERSIONS): version 2 adds a duration to DELAY and PARTITION (a scenario's timed
delay or partition, sent as a drill); every other op is the same in both. A command is encoded at
the lowest version that carries it (a timed delay or partition at 2, anything else at 1, as
before), so a build that speaks only version 1 still reads every command it knows and refuses a
timed delay or partition as ``unsupported version 2``.
"""

from __future__ import annotations

import math
import struct
from enum import IntEnum

from protocols.faults import (
    Clear,
    Crash,
    Delay,
    Dropout,
    FaultCommand,
    LinkCut,
    LinkRestore,
    Loss,
    Pair,
    Partition,
    Restart,
)
from protocols.wire.format import (
    Kind,
    Reason,
    WireError,
    check_ids,
    encode_header,
    expect_length,
    open_versioned,
    uint_ids,
)
from protocols.wire.keys import MAX_DRONE_ID

__all__ = [
    "FAULT_VERSIONS",
    "MAX_DELAY_MS",
    "MAX_DURATION_S",
    "MAX_FAULT_BYTES",
    "FaultOp",
    "decode_fault",
    "encode_fault",
    "fault_op",
]

MAX_FAULT_BYTES = 4 * 1024
#: Longest timed fault (s): f32 keeps it exact to well under a control tick.
MAX_DURATION_S = 86_400.0
MAX_DELAY_MS = 60_000.0
#: The fault schema versions this build reads, the newest last.
FAULT_VERSIONS = (1, 2)


class FaultOp(IntEnum):
    """What a fault command does; its lower-case name is the command's ``kind``."""

    CLEAR = 0
    LINK_CUT = 1
    LINK_RESTORE = 2
    LOSS = 3
    DELAY = 4
    PARTITION = 5
    RESTART = 6
    DROPOUT = 7


def fault_op(command: FaultCommand) -> FaultOp:
    """The op of ``command``; its lower-case name (``link_cut``) names the drill in logs."""
    return FaultOp[command.kind.upper()]


_PAIR = struct.Struct("<HH")
_CUT = struct.Struct("<HHBf")
_LOSS = struct.Struct("<fBHHf")
_DELAY = struct.Struct("<fBHH")
_F32 = struct.Struct("<f")
_U16 = struct.Struct("<H")
_RESTART = struct.Struct("<Hf")


def _duration(value: float | None) -> float:
    if value is None:
        return 0.0
    if not 0.0 < value <= MAX_DURATION_S:
        raise ValueError(f"duration must be 0 < s <= {MAX_DURATION_S:g}, got {value!r}")
    return value


def _pair(i: int, j: int) -> Pair:
    a, b = (int(x) for x in (i, j))
    if not (0 <= a <= MAX_DRONE_ID and 0 <= b <= MAX_DRONE_ID) or a == b:
        raise ValueError(f"link must join two different drones 0..{MAX_DRONE_ID}, got {i}-{j}")
    return a, b


def _link(link: Pair | None) -> tuple[int, int, int]:
    return (0, 0, 0) if link is None else (1, *_pair(*link))


def _drone(drone: int) -> int:
    if not 0 <= drone <= MAX_DRONE_ID:
        raise ValueError(f"drone must be 0..{MAX_DRONE_ID}, got {drone!r}")
    return drone


def _timed(duration_s: float | None) -> tuple[int, bytes]:
    """The version and trailing bytes of an op that has a duration only from version 2."""
    return (1, b"") if duration_s is None else (2, _F32.pack(_duration(duration_s)))


def encode_fault(command: FaultCommand, swarm_id: str) -> bytes:
    """The payload of ``command`` for swarm ``swarm_id``; ValueError if a field is out of range,
    the command has a start time (``t_s``) or is a vehicle crash (not an agents' command)."""
    if isinstance(command, Crash):
        raise ValueError("a crash is the ground station's drill, not an agents' fault command")
    if command.t_s != 0.0:
        raise ValueError(f"a fault command's t_s does not travel: send it at t_s {command.t_s:g}")
    version, body = _body(command)
    return encode_header(Kind.FAULT, swarm_id, version) + bytes([fault_op(command)]) + body


def _body(command: FaultCommand) -> tuple[int, bytes]:
    if isinstance(command, Clear):
        return 1, b""
    if isinstance(command, LinkCut):
        i, j = _pair(command.i, command.j)
        return 1, _CUT.pack(i, j, int(command.one_way), _duration(command.duration_s))
    if isinstance(command, LinkRestore):
        return 1, _PAIR.pack(*_pair(command.i, command.j))
    if isinstance(command, Loss):
        if not 0.0 <= command.probability <= 1.0:
            raise ValueError(f"loss probability must be 0..1, got {command.probability!r}")
        return 1, _LOSS.pack(
            command.probability, *_link(command.link), _duration(command.duration_s)
        )
    if isinstance(command, Delay):
        if not 0.0 <= command.delay_ms <= MAX_DELAY_MS:
            raise ValueError(f"delay must be 0..{MAX_DELAY_MS:g} ms, got {command.delay_ms!r}")
        version, tail = _timed(command.duration_s)
        return version, _DELAY.pack(command.delay_ms, *_link(command.link)) + tail
    if isinstance(command, Restart):
        return 1, _RESTART.pack(_drone(command.drone), _duration(command.gap_s))
    if isinstance(command, Dropout):
        return 1, _U16.pack(_drone(command.drone))
    return _partition_body(command)


def _partition_body(command: Partition) -> tuple[int, bytes]:
    parts = [_U16.pack(len(command.groups))]
    seen: set[int] = set()
    for group in command.groups:
        ids = uint_ids(group, "partition drone")
        if not ids or seen.intersection(ids) or len(set(ids)) != len(ids):
            raise ValueError("partition groups must be non-empty and disjoint")
        seen.update(ids)
        parts.append(struct.pack(f"<H{len(ids)}H", len(ids), *ids))
    if command.heals and command.duration_s is not None:
        raise ValueError("healing a partition takes no duration")
    version, tail = _timed(command.duration_s)
    return version, b"".join(parts) + tail


def decode_fault(data: bytes, swarm_id: str, *, max_bytes: int = MAX_FAULT_BYTES) -> FaultCommand:
    """Decode a fault payload of swarm ``swarm_id``; WireError for anything malformed."""
    off, version = open_versioned(data, Kind.FAULT, swarm_id, max_bytes, FAULT_VERSIONS)
    if len(data) < off + 1:
        raise WireError(Reason.TRUNCATED, "fault: no op byte")
    op, off = data[off], off + 1
    if op == FaultOp.CLEAR:
        expect_length(data, off, "fault clear")
        return Clear()
    if op == FaultOp.LINK_CUT:
        expect_length(data, off + _CUT.size, "fault link_cut")
        i, j, one_way, duration = _CUT.unpack_from(data, off)
        _check_pair(i, j)
        if one_way > 1:
            raise WireError(Reason.BAD_VALUE, f"fault one_way {one_way}")
        return LinkCut(i, j, bool(one_way), _check_duration(duration))
    if op == FaultOp.LINK_RESTORE:
        expect_length(data, off + _PAIR.size, "fault link_restore")
        i, j = _PAIR.unpack_from(data, off)
        _check_pair(i, j)
        return LinkRestore(i, j)
    if op == FaultOp.LOSS:
        expect_length(data, off + _LOSS.size, "fault loss")
        p, has_link, i, j, duration = _LOSS.unpack_from(data, off)
        if not 0.0 <= p <= 1.0:  # also refuses NaN
            raise WireError(Reason.BAD_VALUE, f"fault loss probability {p}")
        return Loss(p, _check_link(has_link, i, j), _check_duration(duration))
    if op == FaultOp.DELAY:
        return _decode_delay(data, off, version)
    if op == FaultOp.PARTITION:
        return _decode_partition(data, off, version)
    if op == FaultOp.RESTART:
        expect_length(data, off + _RESTART.size, "fault restart")
        drone, gap = _RESTART.unpack_from(data, off)
        gap_s = _check_duration(gap)
        if gap_s is None:
            raise WireError(Reason.BAD_VALUE, "fault restart gap 0 s")
        return Restart(drone, gap_s)
    if op == FaultOp.DROPOUT:
        expect_length(data, off + _U16.size, "fault dropout")
        (drone,) = _U16.unpack_from(data, off)
        return Dropout(drone)
    raise WireError(Reason.BAD_VALUE, f"fault op {op}")


def _decode_delay(data: bytes, off: int, version: int) -> Delay:
    timed = version >= 2
    expect_length(data, off + _DELAY.size + (_F32.size if timed else 0), "fault delay")
    ms, has_link, i, j = _DELAY.unpack_from(data, off)
    if not 0.0 <= ms <= MAX_DELAY_MS:
        raise WireError(Reason.BAD_VALUE, f"fault delay {ms} ms")
    duration_s = _check_timed(data, off + _DELAY.size) if timed else None
    return Delay(ms, _check_link(has_link, i, j), duration_s)


def _decode_partition(data: bytes, off: int, version: int) -> Partition:
    if len(data) < off + 2:
        raise WireError(Reason.TRUNCATED, "fault partition: no group count")
    (n_groups,), off = _U16.unpack_from(data, off), off + 2
    groups: list[tuple[int, ...]] = []
    seen: set[int] = set()
    for _ in range(n_groups):
        if len(data) < off + 2:
            raise WireError(Reason.TRUNCATED, "fault partition: group cut short")
        (n,), off = _U16.unpack_from(data, off), off + 2
        if len(data) < off + 2 * n:
            raise WireError(Reason.TRUNCATED, "fault partition: group cut short")
        ids = struct.unpack_from(f"<{n}H", data, off)
        off += 2 * n
        check_ids(ids, "partition")
        if not ids or seen.intersection(ids):
            raise WireError(Reason.BAD_VALUE, "partition groups must be non-empty and disjoint")
        seen.update(ids)
        groups.append(tuple(ids))
    if version < 2:
        expect_length(data, off, "fault partition")
        return Partition(tuple(groups))
    expect_length(data, off + _F32.size, "fault partition")
    if not groups:
        raise WireError(Reason.BAD_VALUE, "fault partition: a heal with a duration")
    return Partition(tuple(groups), _check_timed(data, off))


def _check_pair(i: int, j: int) -> None:
    if i == j:
        raise WireError(Reason.BAD_VALUE, f"fault link {i}-{j} joins a drone to itself")


def _check_link(has_link: int, i: int, j: int) -> Pair | None:
    if has_link > 1 or (has_link == 0 and (i or j)):
        raise WireError(Reason.BAD_VALUE, f"fault link flag {has_link} with {i}-{j}")
    if not has_link:
        return None
    _check_pair(i, j)
    return i, j


def _check_duration(duration: float) -> float | None:
    if not (math.isfinite(duration) and 0.0 <= duration <= MAX_DURATION_S):
        raise WireError(Reason.BAD_VALUE, f"fault duration {duration} s")
    return duration or None


def _check_timed(data: bytes, off: int) -> float:
    """The f32 duration at ``off`` of a version-2 delay or partition: > 0."""
    (duration,) = _F32.unpack_from(data, off)
    duration_s = _check_duration(duration)
    if duration_s is None:
        raise WireError(Reason.BAD_VALUE, "fault duration 0 s in a timed delay or partition")
    return duration_s
