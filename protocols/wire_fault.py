"""The fault command (Kind.FAULT): a link-fault drill sent to every agent on ``swarm/<sid>/fault``.

Body after the common header (``protocols.wire``), little-endian: ``u8 op`` (FaultOp), then::

    CLEAR         (nothing)
    LINK_CUT      u16 i, u16 j, u8 one_way (0/1), f32 duration_s (0: until restored)
    LINK_RESTORE  u16 i, u16 j
    LOSS          f32 probability (0..1), u8 has_link (0/1), u16 i, u16 j,
                  f32 duration_s (0: until changed)
    DELAY         f32 delay_ms (>= 0), u8 has_link (0/1), u16 i, u16 j
    PARTITION     u16 n_groups (0: heal), then per group u16 n, n x u16 ids (strictly
                  increasing; no drone in two groups)
    RESTART       u16 drone, f32 gap_s (> 0): the process hosting drone's agent kills it and
                  starts a new one (a new incarnation) gap_s simulated seconds later
    DROPOUT       u16 drone: the process hosting drone's agent kills it for good (its other
                  agents fly on; the ground station's dropout drill of a hosted agent)

``i``/``j`` are drone indices; with ``has_link`` 0 the command applies to every link and i, j
are 0. A one-way cut stops i -> j only (what j receives from i).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from enum import IntEnum

from protocols.keys import MAX_DRONE_ID
from protocols.wire import (
    Kind,
    Reason,
    WireError,
    check_ids,
    encode_header,
    expect_length,
    open_payload,
    uint_ids,
)

MAX_FAULT_BYTES = 4 * 1024
#: Longest timed fault (s): f32 keeps it exact to well under a control tick.
MAX_DURATION_S = 86_400.0
MAX_DELAY_MS = 60_000.0

Pair = tuple[int, int]


class FaultOp(IntEnum):
    """What a fault command does."""

    CLEAR = 0
    LINK_CUT = 1
    LINK_RESTORE = 2
    LOSS = 3
    DELAY = 4
    PARTITION = 5
    RESTART = 6
    DROPOUT = 7


@dataclass(frozen=True)
class Clear:
    """No faults any more."""


@dataclass(frozen=True)
class LinkCut:
    """Cut the link i-j (only i -> j when ``one_way``) for ``duration_s`` s (None: until
    restored)."""

    i: int
    j: int
    one_way: bool = False
    duration_s: float | None = None


@dataclass(frozen=True)
class LinkRestore:
    """Restore the link i-j, both ways."""

    i: int
    j: int


@dataclass(frozen=True)
class Loss:
    """Packet loss ``probability`` (0..1) on ``link`` (both ways) or on every link (None), for
    ``duration_s`` s (None: until changed)."""

    probability: float
    link: Pair | None = None
    duration_s: float | None = None


@dataclass(frozen=True)
class Delay:
    """Added delay ``delay_ms`` (ms >= 0) on ``link`` (both ways) or on every link (None)."""

    delay_ms: float
    link: Pair | None = None


@dataclass(frozen=True)
class Partition:
    """Split the swarm into ``groups`` of drone ids; None heals the partition."""

    groups: tuple[tuple[int, ...], ...] | None


@dataclass(frozen=True)
class Restart:
    """Kill drone ``drone``'s agent now and start a new one ``gap_s`` simulated s later."""

    drone: int
    gap_s: float


@dataclass(frozen=True)
class Dropout:
    """Kill drone ``drone``'s agent now, for good."""

    drone: int


FaultCommand = Clear | LinkCut | LinkRestore | Loss | Delay | Partition | Restart | Dropout

_OPS: dict[type, FaultOp] = {
    Clear: FaultOp.CLEAR,
    LinkCut: FaultOp.LINK_CUT,
    LinkRestore: FaultOp.LINK_RESTORE,
    Loss: FaultOp.LOSS,
    Delay: FaultOp.DELAY,
    Partition: FaultOp.PARTITION,
    Restart: FaultOp.RESTART,
    Dropout: FaultOp.DROPOUT,
}


def fault_op(command: FaultCommand) -> FaultOp:
    """The op of ``command``; its lower-case name (``link_cut``) names the drill in logs."""
    return _OPS[type(command)]


_PAIR = struct.Struct("<HH")
_CUT = struct.Struct("<HHBf")
_LOSS = struct.Struct("<fBHHf")
_DELAY = struct.Struct("<fBHH")
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


def encode_fault(command: FaultCommand, swarm_id: str) -> bytes:
    """The payload of ``command`` for swarm ``swarm_id``; ValueError if a field is out of range."""
    head = encode_header(Kind.FAULT, swarm_id)
    if isinstance(command, Clear):
        return head + bytes([FaultOp.CLEAR])
    if isinstance(command, LinkCut):
        i, j = _pair(command.i, command.j)
        body = _CUT.pack(i, j, int(command.one_way), _duration(command.duration_s))
        return head + bytes([FaultOp.LINK_CUT]) + body
    if isinstance(command, LinkRestore):
        return head + bytes([FaultOp.LINK_RESTORE]) + _PAIR.pack(*_pair(command.i, command.j))
    if isinstance(command, Loss):
        if not 0.0 <= command.probability <= 1.0:
            raise ValueError(f"loss probability must be 0..1, got {command.probability!r}")
        body = _LOSS.pack(command.probability, *_link(command.link), _duration(command.duration_s))
        return head + bytes([FaultOp.LOSS]) + body
    if isinstance(command, Delay):
        if not 0.0 <= command.delay_ms <= MAX_DELAY_MS:
            raise ValueError(f"delay must be 0..{MAX_DELAY_MS:g} ms, got {command.delay_ms!r}")
        return head + bytes([FaultOp.DELAY]) + _DELAY.pack(command.delay_ms, *_link(command.link))
    if isinstance(command, Restart):
        if not 0 <= command.drone <= MAX_DRONE_ID:
            raise ValueError(f"drone must be 0..{MAX_DRONE_ID}, got {command.drone!r}")
        body = _RESTART.pack(command.drone, _duration(command.gap_s))
        return head + bytes([FaultOp.RESTART]) + body
    if isinstance(command, Dropout):
        if not 0 <= command.drone <= MAX_DRONE_ID:
            raise ValueError(f"drone must be 0..{MAX_DRONE_ID}, got {command.drone!r}")
        return head + bytes([FaultOp.DROPOUT]) + _U16.pack(command.drone)
    groups = command.groups
    parts = [head, bytes([FaultOp.PARTITION]), _U16.pack(0 if groups is None else len(groups))]
    seen: set[int] = set()
    for group in groups or ():
        ids = uint_ids(group, "partition drone")
        if not ids or seen.intersection(ids) or len(set(ids)) != len(ids):
            raise ValueError("partition groups must be non-empty and disjoint")
        seen.update(ids)
        parts.append(struct.pack(f"<H{len(ids)}H", len(ids), *ids))
    if groups is not None and not groups:
        raise ValueError("a partition needs at least one group (None heals it)")
    return b"".join(parts)


def decode_fault(data: bytes, swarm_id: str, *, max_bytes: int = MAX_FAULT_BYTES) -> FaultCommand:
    """Decode a fault payload of swarm ``swarm_id``; WireError for anything malformed."""
    off = open_payload(data, Kind.FAULT, swarm_id, max_bytes)
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
        expect_length(data, off + _DELAY.size, "fault delay")
        ms, has_link, i, j = _DELAY.unpack_from(data, off)
        if not 0.0 <= ms <= MAX_DELAY_MS:
            raise WireError(Reason.BAD_VALUE, f"fault delay {ms} ms")
        return Delay(ms, _check_link(has_link, i, j))
    if op == FaultOp.PARTITION:
        return _decode_partition(data, off)
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


def _decode_partition(data: bytes, off: int) -> Partition:
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
    expect_length(data, off, "fault partition")
    return Partition(tuple(groups) if groups else None)


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
