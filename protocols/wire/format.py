"""Versioned, compact binary wire format of the swarm's Zenoh payloads; the consensus message.

All integers and floats are little-endian, with no padding. Every payload starts with::

    offset  size  field
    0       1     magic 0x51 ('Q')
    1       1     schema version of the kind (WIRE_VERSION; CONSENSUS_VERSION for consensus,
                  protocols.wire.status.STATUS_VERSION for status)
    2       1     message kind (Kind)
    3       1     swarm id length L (1..32)
    4       L     swarm id (ASCII, protocols.wire.keys rules)

Versions are per kind: plan, fault and round-done payloads are at WIRE_VERSION (1), status
payloads at their own version (``protocols.wire.status``); consensus payloads are sent at
CONSENSUS_VERSION (4). Version 2 added the sender's velocity and settled level, version 3 the
incarnations (drone_agent/core/consensus/scalar.py: a restarted agent's sums are never mixed with
its old life's), version 4 the round at which the sender's swarm took off
(drone_agent/core/flight_phase.py, TakeoffClock). Versions 1 to 3 are still decoded: a version-1
message's ``velocity_ned_m_s`` is None (the sender's velocity is unknown) and its ``ready_hops`` 0
(a version-1 neighbour holds the swarm on the ground); a version-1 or 2 message has incarnation 0
and no edge incarnations (its sums are taken as before); a message before version 4 has
``takeoff_round`` None (the sender does not say).
Bumping one kind keeps every other payload, and their golden bytes, unchanged; a build that
speaks only older versions counts a newer payload of that kind as ``wrong_version``.

The consensus body (Kind.CONSENSUS) follows the header::

    u32 round          control-tick number of the vehicles' common simulated time
    u16 sender         drone index
    u16 degree         the sender's degree for the degree-normalised gain
    u16 ready_hops     the sender's settled level (drone_agent.core.flight_phase.SwarmSettled;
                       from version 2, 0 from version 1)
    u32 incarnation    the sender agent's life: the round of its first step (from version 3)
    u32 takeoff_round  the control round at which the sender's swarm left the ground, as the
                       sender knows it; 0xFFFFFFFF: not flying / not said (from version 4)
    3 x f32 position   the sender's position, NED, m (receivers apply the radio range)
    3 x f32 velocity   the sender's velocity, NED, m/s (from version 2; for the separation layer)
    u16 n_heard, u16 n_edges
    n_heard x u16      heard-set, strictly increasing
    n_edges x u16      edge neighbours j, strictly increasing
    n_edges x u32      per edge neighbour j, the incarnation of j its running sum was made with
                       (0xFFFFFFFF: not said) (from version 3)
    18 x f64           gamma: the sender's estimate of the 18 channel averages
    n_edges x 18 x f64 running sums Q_sender,j of the sender's increments, one per edge neighbour
                       in the order of the ids above

The (neighbour, edge sum) pairs are stored as columns, ids first, so that all floats form one
block (one finiteness check, one copy). Gamma and edge sums are float64 because the estimator
needs them exact: a decoded message equals the sent one bit for bit. Position and velocity are
float32 (ample for the radio range and the separation layer): the decoded message carries them in
its ``position_ned_m`` and ``velocity_ned_m_s`` fields.

Decoders raise only :class:`WireError`, whose ``reason`` says why (callers count drops by
reason); encoders raise ValueError for a message that cannot be sent.
Status, plan, fault and round-done messages live in ``protocols.wire.status``,
``protocols.wire.plan``, ``protocols.wire.fault`` and ``protocols.wire.round_done``; a process's
consensus messages of one tick and cell travel together in ``protocols.wire.batch``, its
statuses of one tick in a status batch (``protocols.wire.status``).
"""

from __future__ import annotations

import itertools
import math
import operator
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from protocols.model.frames import FloatArray
from protocols.wire.consensus_message import ConsensusMessage, EdgeIncarnations, EdgeSums
from protocols.wire.keys import MAX_DRONE_ID, MAX_SWARM, MAX_SWARM_ID_LEN, validate_swarm_id

MAGIC = 0x51
WIRE_VERSION = 1
#: Schema version of consensus payloads sent (versions 1 to 3 still decode).
CONSENSUS_VERSION = 4
CONSENSUS_VERSIONS = (1, 2, 3, 4)
#: An edge incarnation on the wire that says nothing (the message did not give one).
NO_INCARNATION = 0xFFFF_FFFF
#: A take-off round on the wire that says nothing (the message's ``takeoff_round`` is None).
NO_TAKEOFF = 0xFFFF_FFFF
N_GAMMA = 18
_HEAD = struct.Struct("<BBBB")
_FIXED_V1 = struct.Struct("<IHH3fHH")
_FIXED_V2 = struct.Struct("<IHHH3f3fHH")
_FIXED_V3 = struct.Struct("<IHHHI3f3fHH")
_FIXED_V4 = struct.Struct("<IHHHII3f3fHH")
MAX_U32 = 0xFFFF_FFFF
_FIXED = {1: _FIXED_V1, 2: _FIXED_V2, 3: _FIXED_V3, 4: _FIXED_V4}
_FLOATS = N_GAMMA * 8  # bytes of one (18,) float64 block


def consensus_body_bytes(n_heard: int, n_edges: int) -> int:
    """The bytes of a consensus payload's fields (all but the common header) with ``n_heard``
    heard ids and ``n_edges`` edge sums."""
    return _FIXED_V4.size + 2 * (n_heard + n_edges) + 4 * n_edges + _FLOATS * (1 + n_edges)


#: Largest consensus payload accepted (bytes): the largest a swarm can send, every other drone of
#: the largest swarm heard and on an edge (edges are kept while their link is down, so a drone
#: that has flown past many others carries many), with the longest swarm id.
MAX_CONSENSUS_BYTES = (
    _HEAD.size + MAX_SWARM_ID_LEN + consensus_body_bytes(MAX_SWARM - 1, MAX_SWARM - 1)
)
_NOT_SAID = struct.pack("<I", NO_INCARNATION)
_VEC3_F32 = struct.Struct("<3f")


class Kind(IntEnum):
    """Message kind byte."""

    CONSENSUS = 1
    STATUS = 2
    PLAN = 3
    FAULT = 4
    ROUND_DONE = 5
    CONSENSUS_BATCH = 6  # protocols/wire/batch.py
    STATUS_BATCH = 7  # protocols/wire/status.py


class Reason(StrEnum):
    """Why a payload was rejected."""

    OVERSIZED = "oversized"
    TRUNCATED = "truncated"
    TRAILING = "trailing bytes"
    BAD_MAGIC = "bad magic"
    BAD_VERSION = "unsupported version"
    WRONG_KIND = "wrong kind"
    WRONG_SWARM = "wrong swarm"
    NOT_FINITE = "not finite"
    BAD_VALUE = "bad value"


class WireError(ValueError):
    """A payload that does not decode; ``reason`` (:class:`Reason`) says why."""

    def __init__(self, reason: Reason, detail: str) -> None:
        super().__init__(f"{reason.value}: {detail}")
        self.reason = reason


@dataclass(frozen=True, eq=False)
class ConsensusPacket:
    """A decoded consensus payload: the message and the sender's position (3,) NED, m (also
    the message's ``position_ned_m``)."""

    message: ConsensusMessage
    position_ned_m: FloatArray

    @property
    def velocity_ned_m_s(self) -> FloatArray | None:
        """The sender's velocity (3,) NED, m/s; None from a version-1 sender."""
        return self.message.velocity_ned_m_s


@lru_cache(maxsize=64)
def _sid(swarm_id: str) -> bytes:
    return validate_swarm_id(swarm_id).encode("ascii")


@lru_cache(maxsize=256)
def encode_header(kind: Kind, swarm_id: str, version: int = WIRE_VERSION) -> bytes:
    """The common header of a payload of ``kind`` (schema ``version``) for swarm ``swarm_id``."""
    sid = _sid(swarm_id)
    return _HEAD.pack(MAGIC, version, int(kind), len(sid)) + sid


def open_payload(data: bytes, kind: Kind, swarm_id: str, max_bytes: int) -> int:
    """Check the header of ``data`` (schema WIRE_VERSION) and return the offset of its body;
    WireError otherwise."""
    return open_versioned(data, kind, swarm_id, max_bytes, (WIRE_VERSION,))[0]


def open_versioned(
    data: bytes, kind: Kind, swarm_id: str, max_bytes: int, versions: tuple[int, ...]
) -> tuple[int, int]:
    """Check the header of ``data``, whose schema version must be one of ``versions`` (the
    newest last), and return the offset of its body and its version; WireError otherwise."""
    if len(data) > max_bytes:
        raise WireError(Reason.OVERSIZED, f"{len(data)} bytes, at most {max_bytes} accepted")
    header = encode_header(kind, swarm_id, versions[-1])
    if data[: len(header)] == header:  # the usual case, in one comparison
        return len(header), versions[-1]
    if len(data) < _HEAD.size:
        raise WireError(Reason.TRUNCATED, f"{len(data)} bytes, shorter than the header")
    magic, version, got_kind, sid_len = _HEAD.unpack_from(data)
    if magic != MAGIC:
        raise WireError(Reason.BAD_MAGIC, f"magic 0x{magic:02x}, expected 0x{MAGIC:02x}")
    if got_kind != kind:  # before the version: versions are per kind
        raise WireError(Reason.WRONG_KIND, f"kind {got_kind}, expected {int(kind)} ({kind.name})")
    if version not in versions:
        speaks = " or ".join(str(v) for v in versions)
        raise WireError(Reason.BAD_VERSION, f"version {version}, this build speaks {speaks}")
    end = _HEAD.size + sid_len
    if len(data) < end:
        raise WireError(Reason.TRUNCATED, f"{len(data)} bytes, swarm id needs {end}")
    if data[_HEAD.size : end] != _sid(swarm_id):
        other = bytes(data[_HEAD.size : end]).decode("ascii", "replace")
        raise WireError(Reason.WRONG_SWARM, f"swarm {other!r}, expected {swarm_id!r}")
    return end, version


def expect_length(data: bytes, expected: int, what: str) -> None:
    """WireError unless ``data`` is exactly ``expected`` bytes long (as its counts say)."""
    if len(data) < expected:
        raise WireError(Reason.TRUNCATED, f"{what}: {len(data)} bytes, counts need {expected}")
    if len(data) > expected:
        raise WireError(Reason.TRAILING, f"{what}: {len(data)} bytes, counts need {expected}")


def _uint(value: int, limit: int, what: str) -> int:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | np.integer)
        or not 0 <= value <= limit
    ):
        raise ValueError(f"{what} must be an integer 0..{limit}, got {value!r}")
    return int(value)


def uint_ids(ids: Iterable[int], what: str) -> list[int]:
    """Drone ids sorted for encoding; ValueError unless each is 0..65535 and there are at most
    65535 (a u16 count)."""
    try:  # the usual case: plain ints in range, checked at C speed
        out = sorted(ids)
        fine = not out or (
            out[0] >= 0 and out[-1] <= MAX_DRONE_ID and all(type(j) is int for j in out)
        )
    except TypeError:
        fine = False
    if not fine:
        out = sorted(_uint(j, MAX_DRONE_ID, what) for j in ids)
    if len(out) > MAX_DRONE_ID:
        raise ValueError(f"{len(out)} {what}s do not fit a u16 count")
    return out


def finite_array(
    values: object, shape: tuple[int, ...], what: str, dtype: str = "<f8"
) -> FloatArray:
    """``values`` as a new finite array of ``shape`` and ``dtype`` (a copy of its own);
    ValueError otherwise (also when a float64 overflows the float32 range)."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{what} must have shape {shape}, got {arr.shape}")
    with np.errstate(over="ignore"):  # a float32 overflow becomes inf, refused below
        out: FloatArray = arr.astype(dtype)
    if not np.isfinite(out).all():
        raise ValueError(f"{what} must be finite (and in range of {np.dtype(dtype).name})")
    return out


def finite_block(values: object, shape: tuple[int, ...], what: str, dtype: str = "<f8") -> bytes:
    """The bytes of :func:`finite_array`."""
    return finite_array(values, shape, what, dtype).tobytes()


def check_ids(ids: Sequence[int], what: str) -> None:
    """WireError unless the drone ids are strictly increasing (sorted, no duplicates)."""
    if any(a >= b for a, b in itertools.pairwise(ids)):
        raise WireError(Reason.BAD_VALUE, f"{what} ids must be strictly increasing")


class ConsensusParts(NamedTuple):
    """A consensus message checked and laid out for the wire: the byte pieces that
    :func:`encode_parts` sends alone and ``protocols.wire.batch.encode_columns`` sends in columns
    with other messages of one cell and tick (one layout, two arrangements).

    ``sender``: its sender; ``fixed``: the fixed fields (_FIXED_V4's layout: round, sender,
    degree, ready_hops, incarnation, takeoff round (NO_TAKEOFF: None), position and velocity as
    float32, n_heard, n_edges);
    ``ids``: the heard ids then the edge neighbours (u16 each); ``tags``: the edge incarnations
    (u32 each); ``floats``: gamma then the edge sums ((1 + n_edges) x 18 float64, finite);
    ``size``: the bytes of the single payload, header included."""

    sender: int
    fixed: bytes
    ids: bytes
    tags: bytes
    floats: bytes
    size: int


def encode_consensus(
    message: ConsensusMessage,
    position_ned_m: Sequence[float] | FloatArray,
    swarm_id: str,
    *,
    max_bytes: int = MAX_CONSENSUS_BYTES,
) -> bytes:
    """The payload (schema CONSENSUS_VERSION) of ``message`` sent from ``position_ned_m`` (3,)
    NED, m, moving at the message's ``velocity_ned_m_s`` (3,) NED, m/s (zero if None); both sent
    as float32. The position argument is the one sent (the transport's radio origin); the
    message's own ``position_ned_m`` field is not read.

    ValueError if a field is out of range (ids and degree uint16, round uint32, incarnation and
    takeoff round 0..0xFFFFFFFE), not finite, or the payload would be larger than ``max_bytes``.
    """
    parts = consensus_parts(message, position_ned_m, swarm_id, max_bytes=max_bytes)
    return encode_parts(parts, swarm_id)


def encode_parts(parts: ConsensusParts, swarm_id: str) -> bytes:
    """The single payload of a message laid out by :func:`consensus_parts`."""
    return b"".join(
        (
            encode_header(Kind.CONSENSUS, swarm_id, CONSENSUS_VERSION),
            parts.fixed,
            parts.ids,
            parts.tags,
            parts.floats,
        )
    )


def consensus_parts(
    message: ConsensusMessage,
    position_ned_m: Sequence[float] | FloatArray,
    swarm_id: str,
    *,
    max_bytes: int = MAX_CONSENSUS_BYTES,
) -> ConsensusParts:
    """``message`` from ``position_ned_m`` checked and laid out (:class:`ConsensusParts`), with
    the ValueErrors of :func:`encode_consensus`."""
    sender = _uint(message.sender, MAX_DRONE_ID, "sender")
    round_ = _uint(message.round, MAX_U32, "round")
    degree = _uint(message.degree, MAX_DRONE_ID, "degree")
    ready = _uint(message.ready_hops, MAX_DRONE_ID, "ready_hops")
    incarnation = _uint(message.incarnation, MAX_U32 - 1, "incarnation")
    takeoff = message.takeoff_round
    takeoff = NO_TAKEOFF if takeoff is None else _uint(takeoff, MAX_U32 - 1, "takeoff_round")
    heard = uint_ids(message.heard, "heard id")
    fast = _edge_arrays(message)
    if fast is not None:  # the batched core's messages: the same bytes, from arrays
        neighbours, edge_incs, floats = fast
    else:
        neighbours = uint_ids(message.edge_sums, "edge neighbour")
        edge_incs = _edge_incarnations(message, neighbours)
        rows = [message.gamma, *(message.edge_sums[j] for j in neighbours)]
        floats = finite_array(rows, (len(rows), N_GAMMA), "gamma and edge sums")
    velocity = message.velocity_ned_m_s
    fixed = (
        round_,
        sender,
        degree,
        ready,
        incarnation,
        takeoff,
        *_vec3_f32(position_ned_m, "position_ned_m"),
        *_vec3_f32((0.0, 0.0, 0.0) if velocity is None else velocity, "velocity_ned_m_s"),
        len(heard),
        len(neighbours),
    )
    ids = heard + neighbours
    size = _consensus_size(swarm_id, len(heard), len(neighbours))
    if size > max_bytes:
        raise ValueError(f"consensus payload of {size} bytes exceeds {max_bytes}")
    return ConsensusParts(
        sender,
        _FIXED_V4.pack(*fixed),
        struct.pack(f"<{len(ids)}H", *ids),
        struct.pack(f"<{len(edge_incs)}I", *edge_incs),
        floats.tobytes(),
        size,
    )


def _consensus_size(swarm_id: str, n_heard: int, n_edges: int) -> int:
    """The bytes of a single consensus payload with these counts, header included."""
    head = len(encode_header(Kind.CONSENSUS, swarm_id, CONSENSUS_VERSION))
    return head + consensus_body_bytes(n_heard, n_edges)


class MessageColumns(NamedTuple):
    """P consensus messages of one round as columns (:func:`column_parts`): per message its
    ``senders``, ``degrees``, ``ready_hops``, ``incarnations`` and ``takeoffs`` (its
    ``takeoff_round``, -1 for None) (lists), the ``positions`` it is sent from (tuples of 3
    floats, NED, m), ``velocities`` (P, 3) and ``gamma`` (P, 18); its heard ids (``heard_at``
    the message of each, ``heard_ids``) and edges (``edge_at``, ``edge_ids``, ``edge_tags``
    (negative: not said), ``edge_sums`` (E, 18)), each ascending by (message, id)."""

    round: int
    senders: list[int]
    degrees: list[int]
    ready_hops: list[int]
    incarnations: list[int]
    takeoffs: list[int]
    positions: Sequence[tuple[float, float, float]]
    velocities: FloatArray
    gamma: FloatArray
    heard_at: npt.NDArray[np.intp]
    heard_ids: npt.NDArray[np.intp]
    edge_at: npt.NDArray[np.intp]
    edge_ids: npt.NDArray[np.intp]
    edge_tags: npt.NDArray[np.int64]
    edge_sums: FloatArray


def column_parts(
    cols: MessageColumns, swarm_id: str, *, max_bytes: int = MAX_CONSENSUS_BYTES
) -> list[ConsensusParts | None]:
    """Each message of ``cols`` laid out as :func:`consensus_parts` lays it out (the same bytes),
    in a few array operations for all of them; None for a message that :func:`consensus_parts`
    would refuse (a field out of range, not finite, too large) or when the columns are not as
    :class:`MessageColumns` says (then every one): ask :func:`consensus_parts` for the reason."""
    n = len(cols.senders)
    if n == 0:
        return []
    h_at, e_at = cols.heard_at, cols.edge_at
    all_ids = np.concatenate((cols.heard_ids, cols.edge_ids))
    if all_ids.shape[0] and not (all_ids.min() >= 0 and all_ids.max() <= MAX_DRONE_ID):
        return [None] * n
    span = MAX_DRONE_ID + 1
    for at, ids in ((h_at, cols.heard_ids), (e_at, cols.edge_ids)):
        key = at * span + ids  # strictly increasing: by message, then id, no repeat
        if key.shape[0] > 1 and not (key[1:] > key[:-1]).all():
            return [None] * n
    tags = cols.edge_tags
    if tags.shape[0] and tags.max() > MAX_U32 - 1:
        return [None] * n
    # per message: its heard ids then its edge ids; gamma then its edge sums
    id_order = np.argsort(np.concatenate((2 * h_at, 2 * e_at + 1)), kind="stable")
    ids_blob = all_ids[id_order].astype("<u2").tobytes()
    owner = np.concatenate((np.arange(n), e_at))
    row_order = np.argsort(np.concatenate((2 * np.arange(n), 2 * e_at + 1)), kind="stable")
    rows = np.concatenate((cols.gamma, cols.edge_sums))[row_order]
    floats_blob = rows.astype("<f8").tobytes()
    # a message is fine if its floats, position and velocity are all finite
    motion = np.hstack((np.asarray(cols.positions, dtype=np.float64), cols.velocities))
    fine: list[bool] = np.all(np.isfinite(motion), axis=1).tolist()
    bad_rows = ~np.isfinite(rows).all(axis=1)
    if bad_rows.any():
        clean = np.bincount(owner[row_order][bad_rows], minlength=n) == 0
        fine = [a and b for a, b in zip(fine, clean.tolist(), strict=True)]
    tags_blob = np.where(tags < 0, NO_INCARNATION, tags).astype("<u4").tobytes()
    n_heard = np.bincount(h_at, minlength=n).tolist()
    n_edges = np.bincount(e_at, minlength=n).tolist()
    id_at = itertools.accumulate(map(operator.add, n_heard, n_edges), initial=0)
    tag_at = list(itertools.accumulate(n_edges, initial=0))
    row_at = list(map(operator.add, tag_at, range(n + 1)))
    velocities = cols.velocities.tolist()
    round_, pack, f = cols.round, _FIXED_V4.pack, _FLOATS
    # None (negative) on the wire; 0xFFFFFFFF (that None) and beyond: -1, which pack refuses
    takeoffs = [NO_TAKEOFF if t < 0 else t if t < NO_TAKEOFF else -1 for t in cols.takeoffs]
    size_0 = _consensus_size(swarm_id, 0, 0) - f  # header and fixed fields
    out: list[ConsensusParts | None] = []
    for k, ((i0, i1), ok) in enumerate(zip(itertools.pairwise(id_at), fine, strict=True)):
        h, e = n_heard[k], n_edges[k]
        size = size_0 + 2 * (h + e) + 4 * e + f * (1 + e)
        if not ok or size > max_bytes:
            out.append(None)
            continue
        try:
            fixed = pack(
                round_, cols.senders[k], cols.degrees[k], cols.ready_hops[k],
                cols.incarnations[k], takeoffs[k], *cols.positions[k], *velocities[k], h, e,
            )  # fmt: skip
        except (struct.error, OverflowError):  # out of range (beyond float32 too)
            out.append(None)
            continue
        t0, t1, r0, r1 = tag_at[k], tag_at[k + 1], row_at[k], row_at[k + 1]
        out.append(
            ConsensusParts(
                cols.senders[k],
                fixed,
                ids_blob[2 * i0 : 2 * i1],
                tags_blob[4 * t0 : 4 * t1],
                floats_blob[f * r0 : f * r1],
                size,
            )
        )
    return out


def _edge_arrays(message: ConsensusMessage) -> tuple[list[int], list[int], FloatArray] | None:
    """For a message whose edge sums (and incarnations) are arrays over one id array
    (:class:`~protocols.wire.consensus_message.EdgeSums`): the edge ids, their incarnations (u32,
    NO_INCARNATION where not said) and the floats (gamma, then the sums), as the general path
    makes them; None for any other message (the general path then encodes it, or says what is
    wrong with it). The ids and incarnations (a handful of small ints) are checked in Python:
    cheaper than numpy's calls."""
    sums = message.edge_sums
    if not isinstance(sums, EdgeSums):
        return None
    tags = message.edge_incarnations
    ids = sums.ids
    if (
        type(ids) is not np.ndarray
        or ids.ndim != 1
        or ids.dtype.kind not in "iu"
        or np.shape(message.gamma) != (N_GAMMA,)
    ):
        return None
    n = ids.shape[0]
    if tags is not None and not (
        isinstance(tags, EdgeIncarnations)
        and (tags.ids is ids or np.array_equal(np.asarray(tags.ids), ids))
    ):
        return None
    if np.shape(sums.sums) != (n, N_GAMMA) or (tags is not None and np.shape(tags.tags) != (n,)):
        return None
    id_list = ids.tolist()
    if n and not (
        id_list[0] >= 0
        and id_list[-1] <= MAX_DRONE_ID
        and all(map(operator.lt, id_list, id_list[1:]))
    ):
        return None
    floats = np.empty((n + 1, N_GAMMA), dtype="<f8")
    floats[0] = message.gamma
    if n:
        floats[1:] = sums.sums
    flat = floats.reshape(-1)
    if np.count_nonzero(np.isfinite(flat)) != flat.shape[0]:
        return None  # the general path says why
    if tags is None:
        incs = [NO_INCARNATION] * n
    else:
        t = np.asarray(tags.tags)
        if t.dtype.kind not in "iu":
            return None
        raw = t.tolist()
        if n and max(raw) > MAX_U32 - 1:
            return None
        incs = [NO_INCARNATION if x < 0 else x for x in raw]
    return id_list, incs, floats


def _edge_incarnations(message: ConsensusMessage, neighbours: list[int]) -> list[int]:
    """Per edge neighbour, the incarnation its sum was made with (NO_INCARNATION: not said)."""
    tags = message.edge_incarnations
    if tags is None:
        return [NO_INCARNATION] * len(neighbours)
    out = []
    for j in neighbours:
        tag = tags.get(j, -1)
        out.append(NO_INCARNATION if tag < 0 else _uint(tag, MAX_U32 - 1, "edge incarnation"))
    return out


def _vec3_f32(values: Sequence[float] | FloatArray, what: str) -> tuple[float, float, float]:
    # the usual cases, in Python: rounded to float32 by struct as numpy rounds them (to
    # nearest); a value out of float32's range is refused as below
    xyz: Any = None
    if type(values) is np.ndarray and values.shape == (3,) and values.dtype.kind == "f":
        xyz = values.tolist()
    elif type(values) is tuple and len(values) == 3 and all(type(v) is float for v in values):
        xyz = values
    if xyz is not None:
        x, y, z = xyz
        if math.isfinite(x + y + z):
            try:
                return _VEC3_F32.unpack(_VEC3_F32.pack(x, y, z))
            except OverflowError:
                pass
    vec = finite_array(values, (3,), what, "<f4")
    return (float(vec[0]), float(vec[1]), float(vec[2]))


def _fixed(data: bytes, swarm_id: str, max_bytes: int) -> tuple[int, int, tuple[Any, ...]]:
    """The offset after the fixed fields, the version and the fields' values (round, sender,
    degree, ready_hops (0 from version 1), incarnation (0 before version 3), takeoff round as on
    the wire (NO_TAKEOFF before version 4), position (3), velocity (3, from version 2), n_heard,
    n_edges), after checking the header and that the position and velocity are finite."""
    off, version = open_versioned(data, Kind.CONSENSUS, swarm_id, max_bytes, CONSENSUS_VERSIONS)
    layout = _FIXED[version]
    if len(data) < off + layout.size:
        raise WireError(Reason.TRUNCATED, f"consensus: {len(data)} bytes, shorter than its fields")
    values = layout.unpack_from(data, off)
    if version == 1:
        values = (*values[:3], 0, *values[3:])
    if version < 4:
        if version < 3:
            values = (*values[:4], 0, *values[4:])
        values = (*values[:5], NO_TAKEOFF, *values[5:])
    if not math.isfinite(sum(values[6:-2])):  # float32s: the sum cannot overflow
        raise WireError(Reason.NOT_FINITE, "consensus position or velocity is NaN or infinite")
    return off + layout.size, version, values


def consensus_origin(
    data: bytes, swarm_id: str, *, max_bytes: int = MAX_CONSENSUS_BYTES
) -> tuple[int, tuple[float, float, float]]:
    """The sender and its position (NED, m) from a consensus payload's header and fixed fields,
    without decoding the rest: lets a receiver apply the radio range before paying for a full
    :func:`decode_consensus`. WireError if the header, position or velocity is bad."""
    sender, _, origin = consensus_head(data, swarm_id, max_bytes=max_bytes)
    return sender, origin


def consensus_head(
    data: bytes, swarm_id: str, *, max_bytes: int = MAX_CONSENSUS_BYTES
) -> tuple[int, int, tuple[float, float, float]]:
    """The sender, round and position (NED, m) of a consensus payload, as :func:`consensus_origin`
    (the round too: a receiver applies the radio range between the two drones' positions of the
    same round)."""
    _, _, values = _fixed(data, swarm_id, max_bytes)
    return values[1], values[0], values[6:9]


def decode_consensus(
    data: bytes, swarm_id: str, *, max_bytes: int = MAX_CONSENSUS_BYTES
) -> ConsensusPacket:
    """Decode a consensus payload of swarm ``swarm_id``; WireError for anything malformed.

    The arrays of the returned message are float64 copies, read-only; its ``position_ned_m`` is
    the packet's, its ``velocity_ned_m_s`` None from a version-1 sender, its ``takeoff_round``
    None when the payload does not say (0xFFFFFFFF, or before version 4). Its edge sums and
    incarnations are array-backed mappings (:class:`~protocols.wire.consensus_message.EdgeSums`,
    :class:`~protocols.wire.consensus_message.EdgeIncarnations`, the incarnations said only), as the
    batched core's own messages: a receiver's estimator reads them as arrays.
    """
    off, version, fields = _fixed(data, swarm_id, max_bytes)
    round_, sender, degree, ready, incarnation, takeoff = fields[:6]
    n_heard, n_edges = fields[-2:]
    n_ids = n_heard + n_edges
    n_tags = n_edges if version >= 3 else 0
    off_tags = off + 2 * n_ids
    off_floats = off_tags + 4 * n_tags
    expect_length(data, off_floats + _FLOATS * (1 + n_edges), "consensus")
    # a native, aligned, writable copy (made read-only below)
    floats = np.frombuffer(data, "<f8", N_GAMMA * (1 + n_edges), off_floats).astype(np.float64)
    flat = floats.reshape(-1)
    if np.count_nonzero(np.isfinite(flat)) != flat.shape[0]:  # (cheaper than .all())
        raise WireError(Reason.NOT_FINITE, "consensus gamma or an edge sum is NaN or infinite")
    # the ids checked in Python (a handful of small ints: cheaper than numpy's reductions)
    id_list = list(struct.unpack_from(f"<{n_ids}H", data, off))
    heard_ids, edge_ids = id_list[:n_heard], id_list[n_heard:]
    if n_heard > 1 and not all(map(operator.lt, heard_ids, heard_ids[1:])):
        raise WireError(Reason.BAD_VALUE, "heard ids must be strictly increasing")
    if n_edges > 1 and not all(map(operator.lt, edge_ids, edge_ids[1:])):
        raise WireError(Reason.BAD_VALUE, "edge neighbour ids must be strictly increasing")
    floats = floats.reshape(-1, N_GAMMA)
    floats.setflags(write=False)
    neighbours = np.array(edge_ids, dtype=np.intp)
    neighbours.setflags(write=False)
    motion = np.array(fields[6:-2])  # position (3), then velocity (3) from version 2
    motion.setflags(write=False)
    position = motion[:3]
    edge_tags: EdgeIncarnations | None = None
    if version >= 3:  # the ones said (a plain mapping of them, as the arrays it is made of)
        tags = np.frombuffer(data, "<u4", n_tags, off_tags).astype(np.int64)
        # no 0xFFFFFFFF anywhere in the block: every one said (found: look at each)
        if data.find(_NOT_SAID, off_tags, off_floats) < 0:
            edge_tags = EdgeIncarnations(neighbours, tags)
        else:
            said = tags != NO_INCARNATION
            edge_tags = EdgeIncarnations(neighbours[said], tags[said])
    message = ConsensusMessage(
        sender=sender,
        round=round_,
        gamma=floats[0],
        edge_sums=EdgeSums(neighbours, floats[1:]),
        heard=frozenset(heard_ids),
        degree=degree,
        ready_hops=ready,
        position_ned_m=position,
        velocity_ned_m_s=None if version == 1 else motion[3:],
        incarnation=incarnation,
        edge_incarnations=edge_tags,
        takeoff_round=None if takeoff == NO_TAKEOFF else takeoff,
    )
    return ConsensusPacket(message, position)
