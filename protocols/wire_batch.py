"""The consensus batch (Kind.CONSENSUS_BATCH): one agent process's consensus messages of one
control tick from one spatial cell, in one Zenoh sample (issue 9, "batched messaging").

A process hosting several agents publishes, after its agents due at a tick have finished, one
batch per cell its agents publish from, on ``swarm/<sid>/consensus/<cx>/<cy>/<cz>/<first
sender>`` (the key of the batch's first message: receivers subscribe by cell as before). A batch
of one message is sent as that message alone (Kind.CONSENSUS): a process hosting one agent
speaks exactly the single-message schema, and every receiver takes both kinds on its cell keys.
The batch does not change what is received: each inner message is a complete consensus payload
(``protocols.wire``, any of its versions), and the receiving side still applies, per agent pair,
the radio range (from the inner message's position), link faults, heard sets and incarnations as
for a single message. It only saves the per-message publication, delivery and header parsing.

Body after the common header (``protocols.wire``, schema BATCH_VERSION), little-endian::

    u16 n              number of messages (2..)
    n x u32 length     byte length of each message
    n x message        complete consensus payloads (header included), senders strictly
                       increasing, each at most the receiver's consensus size limit

Decoding (:func:`split_batch`) checks the header, the counts and lengths and the senders' order,
and reads each message's sender, round and position (``protocols.wire.consensus_head``) so a
receiver can apply the radio range before fully decoding a message; WireError for anything
malformed, with its reason (a bad inner message rejects the whole batch: one sender wrote it).
"""

from __future__ import annotations

import itertools
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from protocols.wire import (
    MAX_CONSENSUS_BYTES,
    Kind,
    Reason,
    WireError,
    consensus_head,
    encode_header,
    open_versioned,
)

#: Schema version of consensus batches.
BATCH_VERSION = 1
BATCH_VERSIONS = (1,)
#: Most messages in one batch (a process hosts at most this many agents in one cell).
MAX_BATCH_MESSAGES = 256
_COUNT = struct.Struct("<H")


def max_batch_bytes(max_consensus_bytes: int = MAX_CONSENSUS_BYTES) -> int:
    """The largest batch a receiver with this consensus size limit accepts."""
    return 64 + MAX_BATCH_MESSAGES * (4 + max_consensus_bytes)


@dataclass(frozen=True)
class BatchEntry:
    """One message of a batch: its sender, round and radio origin (NED, m) and its payload."""

    sender: int
    round: int
    origin: tuple[float, float, float]
    payload: bytes


def encode_batch(payloads: Sequence[tuple[int, bytes]], swarm_id: str) -> bytes:
    """The batch of ``payloads``, (sender, consensus payload) pairs with senders strictly
    increasing; ValueError for fewer than two, more than MAX_BATCH_MESSAGES, or unsorted."""
    n = len(payloads)
    if not 2 <= n <= MAX_BATCH_MESSAGES:
        raise ValueError(f"a batch holds 2..{MAX_BATCH_MESSAGES} messages, got {n}")
    senders = [s for s, _ in payloads]
    if any(a >= b for a, b in itertools.pairwise(senders)):
        raise ValueError("batch senders must be strictly increasing")
    parts = [p for _, p in payloads]
    return b"".join(
        (
            encode_header(Kind.CONSENSUS_BATCH, swarm_id, BATCH_VERSION),
            _COUNT.pack(n),
            struct.pack(f"<{n}I", *(len(p) for p in parts)),
            *parts,
        )
    )


def split_batch(
    data: bytes, swarm_id: str, *, max_consensus_bytes: int = MAX_CONSENSUS_BYTES
) -> list[BatchEntry]:
    """The messages of batch ``data``, heads read (not fully decoded); WireError otherwise."""
    off, _ = open_versioned(
        data,
        Kind.CONSENSUS_BATCH,
        swarm_id,
        max_batch_bytes(max_consensus_bytes),
        BATCH_VERSIONS,
    )
    if len(data) < off + _COUNT.size:
        raise WireError(Reason.TRUNCATED, f"consensus batch: {len(data)} bytes")
    (n,) = _COUNT.unpack_from(data, off)
    off += _COUNT.size
    if not 2 <= n <= MAX_BATCH_MESSAGES:
        raise WireError(Reason.BAD_VALUE, f"consensus batch of {n} messages")
    if len(data) < off + 4 * n:
        raise WireError(Reason.TRUNCATED, f"consensus batch: {len(data)} bytes, {n} lengths")
    lengths = struct.unpack_from(f"<{n}I", data, off)
    off += 4 * n
    end = off + sum(lengths)
    if len(data) < end:
        raise WireError(Reason.TRUNCATED, f"consensus batch: {len(data)} bytes, lengths need {end}")
    if len(data) > end:
        raise WireError(Reason.TRAILING, f"consensus batch: {len(data)} bytes, lengths need {end}")
    out: list[BatchEntry] = []
    last = -1
    for length in lengths:
        payload = data[off : off + length]
        off += length
        sender, round_, origin = consensus_head(payload, swarm_id, max_bytes=max_consensus_bytes)
        if sender <= last:
            raise WireError(Reason.BAD_VALUE, "consensus batch senders must be strictly increasing")
        last = sender
        out.append(BatchEntry(sender, round_, origin, payload))
    return out
