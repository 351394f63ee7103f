"""The consensus batch (Kind.CONSENSUS_BATCH): one agent process's consensus messages of one
control tick from one spatial cell, in one Zenoh sample (issue 9, "batched messaging").

A process hosting several agents publishes, after its agents due at a tick have finished, one
batch per cell its agents publish from, on ``swarm/<sid>/consensus/<cx>/<cy>/<cz>/<first
sender>`` (the key of the batch's first message: receivers subscribe by cell as before). A batch
of one message is sent as that message alone (Kind.CONSENSUS): a process hosting one agent
speaks exactly the single-message schema, and every receiver takes both kinds on its cell keys.
The batch does not change what is received: each message in it is one consensus message, as
``protocols.wire.format`` encodes it alone, and the receiving side still applies, per agent pair,
the radio range (from the message's position), link faults, heard sets and incarnations as for a
single message. It only saves the per-message publication, delivery and parsing.

Version 3 (BATCH_VERSION, sent): the messages in columns, so that a receiver checks the whole
batch in a few array operations and builds each message it takes as views of the columns (its
arrays are read-only slices of the batch's), instead of parsing each message. Body after the
common header (``protocols.wire.format``), little-endian::

    u16 n              number of messages (2..)
    n x 46 bytes       each message's fixed fields, as consensus version 4 lays them out
                       (round, sender, degree, ready_hops, incarnation, takeoff_round,
                       position, velocity, n_heard, n_edges), senders strictly increasing
    sum(n_heard + n_edges) x u16
                       per message in turn: its heard ids, then its edge neighbours (each run
                       strictly increasing)
    sum(n_edges) x u32 per message in turn: its edge incarnations (0xFFFFFFFF: not said)
    sum(1 + n_edges) x 18 x f64
                       per message in turn: gamma, then its edge sums in the order of its ids

Each message is what consensus version 4 carries (a version-4 payload of the same fields decodes
to the same message, bit for bit), and each must be within the receiver's consensus size limit
as that payload. :func:`open_batch` checks everything :func:`protocols.wire.format.decode_consensus`
checks of each message; a bad message rejects the whole batch (one process wrote it).

Version 2 (still decoded: :func:`open_batch`): the same columns with each message's fixed
fields as consensus version 3 lays them out (42 bytes: no takeoff_round); its messages decode
as that version's payloads do, with ``takeoff_round`` None.

Version 1 (still decoded: :func:`split_batch`, :func:`open_batch`)::

    u16 n              number of messages (2..)
    n x u32 length     byte length of each message
    n x message        complete consensus payloads (header included, any consensus version),
                       senders strictly increasing, each at most the receiver's size limit

:func:`split_batch` checks the header, the counts and lengths and the senders' order, and reads
each message's sender, round and position (``protocols.wire.format.consensus_head``) so a receiver
can apply the radio range before fully decoding a message; WireError for anything malformed, with
its reason.
"""

from __future__ import annotations

import itertools
import operator
import struct
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from protocols.model.frames import FloatArray
from protocols.wire.consensus_message import ConsensusMessage, EdgeIncarnations, EdgeSums
from protocols.wire.format import (
    _FLOATS,
    _NOT_SAID,
    CONSENSUS_VERSION,
    MAX_CONSENSUS_BYTES,
    N_GAMMA,
    NO_INCARNATION,
    NO_TAKEOFF,
    ConsensusPacket,
    ConsensusParts,
    Kind,
    Reason,
    WireError,
    consensus_head,
    decode_consensus,
    encode_header,
    expect_length,
    open_versioned,
)

#: Schema version of consensus batches sent (versions 1 and 2 still decode: :func:`open_batch`).
BATCH_VERSION = 3
BATCH_VERSIONS = (1, 2, 3)
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
    """The version-1 batch of ``payloads``, (sender, consensus payload) pairs with senders
    strictly increasing (what earlier builds send; :func:`encode_columns` makes version 3);
    ValueError for fewer than two, more than MAX_BATCH_MESSAGES, or unsorted."""
    n = len(payloads)
    if not 2 <= n <= MAX_BATCH_MESSAGES:
        raise ValueError(f"a batch holds 2..{MAX_BATCH_MESSAGES} messages, got {n}")
    senders = [s for s, _ in payloads]
    if any(a >= b for a, b in itertools.pairwise(senders)):
        raise ValueError("batch senders must be strictly increasing")
    parts = [p for _, p in payloads]
    return b"".join(
        (
            encode_header(Kind.CONSENSUS_BATCH, swarm_id, 1),
            _COUNT.pack(n),
            struct.pack(f"<{n}I", *(len(p) for p in parts)),
            *parts,
        )
    )


def _message_count(data: bytes, off: int) -> tuple[int, int]:
    """The number of messages of a consensus batch (either version) whose count is at ``off``
    (2..MAX_BATCH_MESSAGES), and the offset after it; WireError otherwise."""
    if len(data) < off + _COUNT.size:
        raise WireError(Reason.TRUNCATED, f"consensus batch: {len(data)} bytes")
    (n,) = _COUNT.unpack_from(data, off)
    if not 2 <= n <= MAX_BATCH_MESSAGES:
        raise WireError(Reason.BAD_VALUE, f"consensus batch of {n} messages")
    return n, off + _COUNT.size


def split_batch(
    data: bytes, swarm_id: str, *, max_consensus_bytes: int = MAX_CONSENSUS_BYTES
) -> list[BatchEntry]:
    """The messages of version-1 batch ``data``, heads read (not fully decoded); WireError
    otherwise (a batch in columns: :func:`open_batch`)."""
    off, _ = open_versioned(
        data, Kind.CONSENSUS_BATCH, swarm_id, max_batch_bytes(max_consensus_bytes), (1,)
    )
    n, off = _message_count(data, off)
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


# -- versions 2 and 3: the messages in columns -------------------------------------------------
#: one message's fixed fields in a version-3 batch (protocols.wire.format's consensus version 4
#: layout)
_RECORD = np.dtype(
    [
        ("round", "<u4"),
        ("sender", "<u2"),
        ("degree", "<u2"),
        ("ready_hops", "<u2"),
        ("incarnation", "<u4"),
        ("takeoff", "<u4"),
        ("motion", "<f4", (6,)),
        ("n_heard", "<u2"),
        ("n_edges", "<u2"),
    ]
)
#: one message's fixed fields in a version-2 batch (consensus version 3: no takeoff round)
_RECORD_V2 = np.dtype(
    [
        ("round", "<u4"),
        ("sender", "<u2"),
        ("degree", "<u2"),
        ("ready_hops", "<u2"),
        ("incarnation", "<u4"),
        ("motion", "<f4", (6,)),
        ("n_heard", "<u2"),
        ("n_edges", "<u2"),
    ]
)
_RECORDS = {2: _RECORD_V2, 3: _RECORD}
assert _RECORD.itemsize == 46 and _RECORD_V2.itemsize == 42


def encode_columns(parts: Sequence[ConsensusParts], swarm_id: str) -> bytes:
    """The version-3 batch of ``parts`` (:func:`protocols.wire.format.consensus_parts`,
    :func:`protocols.wire.format.column_parts`), senders strictly increasing; ValueError for fewer
    than two, more than MAX_BATCH_MESSAGES, or unsorted."""
    n = len(parts)
    if not 2 <= n <= MAX_BATCH_MESSAGES:
        raise ValueError(f"a batch holds 2..{MAX_BATCH_MESSAGES} messages, got {n}")
    senders = [p.sender for p in parts]
    if not all(map(operator.lt, senders, senders[1:])):
        raise ValueError("batch senders must be strictly increasing")
    return b"".join(
        (
            encode_header(Kind.CONSENSUS_BATCH, swarm_id, BATCH_VERSION),
            _COUNT.pack(n),
            *(p.fixed for p in parts),
            *(p.ids for p in parts),
            *(p.tags for p in parts),
            *(p.floats for p in parts),
        )
    )


class ConsensusBatch:
    """A received batch, checked whole: per message its ``senders``, ``rounds`` and
    ``origins`` (NED, m) as Python values, for the receivers' range checks, and each message
    decoded on demand (:meth:`packet`), once per message whichever agents take it."""

    __slots__ = ("_columns", "_payloads", "origins", "rounds", "senders")

    def __init__(
        self,
        senders: list[int],
        rounds: list[int],
        origins: list[tuple[float, float, float]],
        payloads: list[bytes] | None,
        columns: _Columns | None,
    ) -> None:
        self.senders, self.rounds, self.origins = senders, rounds, origins
        self._payloads, self._columns = payloads, columns

    def __len__(self) -> int:
        return len(self.senders)

    def packet(self, k: int, swarm_id: str, max_bytes: int) -> ConsensusPacket:
        """Message ``k``, decoded (WireError if a version-1 batch's message does not)."""
        if self._columns is not None:
            return self._columns.packet(k)
        assert self._payloads is not None
        return decode_consensus(self._payloads[k], swarm_id, max_bytes=max_bytes)


class _Columns:
    """A batch's columns (arrays read-only; per message values as lists) and where each
    message's ids, tags and float rows start."""

    __slots__ = (
        "degree",
        "floats",
        "id_at",
        "ids",
        "ids_list",
        "incarnation",
        "motion",
        "n_edges",
        "n_heard",
        "ready",
        "round",
        "row_at",
        "said",
        "sender",
        "tag_at",
        "tags",
        "takeoff",
    )

    def __init__(
        self,
        rec: npt.NDArray[np.void],
        motion: FloatArray,
        ids: npt.NDArray[np.intp],
        tags: npt.NDArray[np.int64],
        said: npt.NDArray[np.bool_] | None,
        floats: FloatArray,
        starts: tuple[list[int], list[int], list[int], list[int], list[int]],
    ) -> None:
        self.sender: list[int] = rec["sender"].tolist()
        self.round: list[int] = rec["round"].tolist()
        self.degree: list[int] = rec["degree"].tolist()
        self.ready: list[int] = rec["ready_hops"].tolist()
        self.incarnation: list[int] = rec["incarnation"].tolist()
        self.takeoff: list[int | None] = (
            [None if t == NO_TAKEOFF else t for t in rec["takeoff"].tolist()]
            if rec.dtype == _RECORD
            else [None] * len(self.sender)  # a version-2 batch: not said
        )
        self.motion, self.ids, self.tags, self.said, self.floats = motion, ids, tags, said, floats
        self.ids_list: list[int] = ids.tolist()
        self.n_heard, self.n_edges, self.id_at, self.tag_at, self.row_at = starts

    def packet(self, k: int) -> ConsensusPacket:
        h, e = self.n_heard[k], self.n_edges[k]
        i0, r0, t0 = self.id_at[k], self.row_at[k], self.tag_at[k]
        neighbours = self.ids[i0 + h : i0 + h + e]
        tags = self.tags[t0 : t0 + e]
        if self.said is None:
            edge_tags = EdgeIncarnations(neighbours, tags)
        else:
            said = self.said[t0 : t0 + e]
            edge_tags = EdgeIncarnations(neighbours[said], tags[said])
        motion = self.motion[k]
        position = motion[:3]
        floats = self.floats[r0 : r0 + 1 + e]
        message = ConsensusMessage(
            sender=self.sender[k],
            round=self.round[k],
            gamma=floats[0],
            edge_sums=EdgeSums(neighbours, floats[1:]),
            heard=frozenset(self.ids_list[i0 : i0 + h]),
            degree=self.degree[k],
            ready_hops=self.ready[k],
            position_ned_m=position,
            velocity_ned_m_s=motion[3:],
            incarnation=self.incarnation[k],
            edge_incarnations=edge_tags,
            takeoff_round=self.takeoff[k],
        )
        return ConsensusPacket(message, position)


def open_batch(
    data: bytes, swarm_id: str, *, max_consensus_bytes: int = MAX_CONSENSUS_BYTES
) -> ConsensusBatch:
    """Batch ``data`` of any version, checked (every message of a batch in columns (version 2
    or 3) whole, as :func:`protocols.wire.format.decode_consensus` checks one; a version-1 batch's
    heads, as :func:`split_batch`); WireError otherwise."""
    if len(data) > 1 and data[1] == 1:
        entries = split_batch(data, swarm_id, max_consensus_bytes=max_consensus_bytes)
        return ConsensusBatch(
            [e.sender for e in entries],
            [e.round for e in entries],
            [e.origin for e in entries],
            [e.payload for e in entries],
            None,
        )
    off, version = open_versioned(
        data, Kind.CONSENSUS_BATCH, swarm_id, max_batch_bytes(max_consensus_bytes), BATCH_VERSIONS
    )
    record = _RECORDS[version]
    n, off = _message_count(data, off)
    if len(data) < off + record.itemsize * n:
        raise WireError(Reason.TRUNCATED, f"consensus batch: {len(data)} bytes, {n} messages")
    rec = np.frombuffer(data, record, n, off)
    off += record.itemsize * n
    n_heard, n_edges = rec["n_heard"].tolist(), rec["n_edges"].tolist()
    total_heard, total_edges = sum(n_heard), sum(n_edges)
    total_ids = total_heard + total_edges
    off_tags = off + 2 * total_ids
    off_floats = off_tags + 4 * total_edges
    expect_length(data, off_floats + _FLOATS * (n + total_edges), "consensus batch")
    # each message alone, as the consensus payload of its fields' version (the same header size)
    single = len(encode_header(Kind.CONSENSUS, swarm_id, CONSENSUS_VERSION)) + record.itemsize
    # the largest message alone: header, fields, 2 per id, and per edge 4 (its tag) and 144
    biggest = max(map(operator.add, n_heard, map((3 + _FLOATS // 2).__mul__, n_edges)))
    if single + _FLOATS + 2 * biggest > max_consensus_bytes:
        raise WireError(
            Reason.OVERSIZED,
            f"a batched message of {single + _FLOATS + 2 * biggest} bytes, "
            f"at most {max_consensus_bytes}",
        )
    motion = rec["motion"].astype(np.float64)
    if np.count_nonzero(np.isfinite(motion)) != 6 * n:
        raise WireError(Reason.NOT_FINITE, "consensus position or velocity is NaN or infinite")
    senders = rec["sender"].tolist()
    if not all(map(operator.lt, senders, senders[1:])):
        raise WireError(Reason.BAD_VALUE, "consensus batch senders must be strictly increasing")
    floats = np.frombuffer(data, "<f8", N_GAMMA * (n + total_edges), off_floats).astype(np.float64)
    if np.count_nonzero(np.isfinite(floats)) != floats.shape[0]:
        raise WireError(Reason.NOT_FINITE, "consensus gamma or an edge sum is NaN or infinite")
    ids = np.frombuffer(data, "<u2", total_ids, off).astype(np.intp)
    # where each message's ids start (its heard ids, then its edge ids) and its tags and rows
    id_at = list(itertools.accumulate(map(operator.add, n_heard, n_edges), initial=0))
    tag_at = list(itertools.accumulate(n_edges, initial=0))
    row_at = list(map(operator.add, tag_at, range(n + 1)))
    if total_ids > 1:  # strictly increasing runs: a step down (or none) only where one starts
        starts = np.zeros(total_ids + 1, dtype=bool)
        starts[id_at] = True
        starts[list(map(operator.add, id_at[:-1], n_heard))] = True
        if not ((ids[1:] > ids[:-1]) | starts[1:-1]).all():
            raise WireError(Reason.BAD_VALUE, "heard and edge ids must be strictly increasing")
    tags = np.frombuffer(data, "<u4", total_edges, off_tags).astype(np.int64)
    said = None
    if data.find(_NOT_SAID, off_tags, off_floats) >= 0:  # look closer: not every one said
        said = tags != NO_INCARNATION
        if said.all():
            said = None
        else:
            said.setflags(write=False)
    for arr in (motion, floats, ids, tags):
        arr.setflags(write=False)
    runs = (n_heard, n_edges, id_at, tag_at, row_at)
    cols = _Columns(rec, motion, ids, tags, said, floats.reshape(-1, N_GAMMA), runs)
    origins = [(x, y, z) for x, y, z, *_ in motion.tolist()]
    return ConsensusBatch(senders, cols.round, origins, None, cols)
