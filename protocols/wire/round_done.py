"""The lockstep round-done marker (Kind.ROUND_DONE) on ``swarm/<sid>/round/<first drone>``.

An agent process publishes one after the agents it hosts have finished a control round: every
consensus message of that round they sent went out before it, on the same Zenoh session, so a
receiver that has the marker has every one of those messages it will ever get (one session's
samples reach another session in order). In lockstep an agent waits, before its tick ``k``, for
the markers of round ``k - 1`` of every live drone (drone_agent/process/round_gate.py) instead of
waiting a fixed wall time: what it computes then never depends on the machine's load.

Body after the common header (``protocols.wire.format``, schema WIRE_VERSION), little-endian::

    u32 round          the control round the drones below have finished
    u16 n              number of drones
    n x u16 drones     the drones that finished it, strictly increasing
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass

from protocols.wire.format import (
    Kind,
    Reason,
    WireError,
    check_ids,
    encode_header,
    expect_length,
    open_payload,
    uint_ids,
)

MAX_ROUND_BYTES = 1024
_FIXED = struct.Struct("<IH")
_MAX_ROUND = 2**32 - 1


@dataclass(frozen=True)
class RoundDone:
    """``drones`` (sorted) have finished control round ``round``."""

    round: int
    drones: tuple[int, ...]


def encode_round_done(done: RoundDone, swarm_id: str) -> bytes:
    """The payload of ``done``; ValueError for a round or drone ids that do not fit."""
    if not isinstance(done.round, int) or not 0 <= done.round <= _MAX_ROUND:
        raise ValueError(f"round must be an integer 0..{_MAX_ROUND}, got {done.round!r}")
    ids = uint_ids(done.drones, "drone")
    body = _FIXED.pack(done.round, len(ids)) + struct.pack(f"<{len(ids)}H", *ids)
    payload = encode_header(Kind.ROUND_DONE, swarm_id) + body
    if len(payload) > MAX_ROUND_BYTES:
        raise ValueError(f"{len(ids)} drones do not fit a {MAX_ROUND_BYTES}-byte marker")
    return payload


def decode_round_done(data: bytes, swarm_id: str) -> RoundDone:
    """The marker in ``data``; WireError (with its reason) for anything else."""
    off = open_payload(data, Kind.ROUND_DONE, swarm_id, MAX_ROUND_BYTES)
    if len(data) < off + _FIXED.size:
        raise WireError(Reason.TRUNCATED, f"round marker: {len(data)} bytes")
    round_, n = _FIXED.unpack_from(data, off)
    off += _FIXED.size
    expect_length(data, off + 2 * n, "round marker")
    drones = struct.unpack_from(f"<{n}H", data, off)
    check_ids(drones, "round marker")
    return RoundDone(round_, tuple(drones))


def round_done_of(round_: int, drones: Iterable[int]) -> RoundDone:
    """A marker of ``drones`` (any order) for ``round_``."""
    return RoundDone(round_, tuple(sorted(drones)))
