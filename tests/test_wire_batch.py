"""The consensus batch (protocols/wire/batch.py) and the status batch (protocols/wire/status.py):
golden bytes, round trip, malformed input, and the process hub that sends and takes batches
(drone_agent/transport_link.ConsensusHub) on the in-memory bus: several hosted agents' messages
(statuses) of a pass go as one sample per cell (one sample), each agent still applies its own
range, and a process of one agent sends the single-message schema."""

from __future__ import annotations

import contextlib
import struct
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drone_agent.process.transport_link import AgentLink, ConsensusHub, LinkSettings
from protocols.bus.interface import Congestion
from protocols.bus.memory import MemoryBus
from protocols.wire.batch import (
    BATCH_VERSION,
    encode_batch,
    encode_columns,
    open_batch,
    split_batch,
)
from protocols.wire.consensus_message import ConsensusMessage, EdgeIncarnations, EdgeSums
from protocols.wire.format import (
    Kind,
    Reason,
    WireError,
    consensus_parts,
    decode_consensus,
    encode_consensus,
)
from protocols.wire.status import (
    STATUS_BATCH_VERSION,
    STATUS_VERSION,
    AgentMode,
    AgentStatus,
    Health,
    StatusCounters,
    decode_statuses,
    encode_status,
    encode_status_batch,
)

pytestmark = pytest.mark.timeout(60)

SID = "demo"


def _message(sender: int, round_: int = 7) -> ConsensusMessage:
    return ConsensusMessage(
        sender=sender,
        round=round_,
        gamma=np.full(18, 0.5 * sender),
        edge_sums={},
        heard=frozenset(),
        degree=0,
    )


#: drone 3's and drone 4's round-7 messages (consensus schema version 4, no edges, take-off
#: round not said)
INNER_3 = (
    "5104010464656d6f0700000003000000000000000000ffffffff0000803f00000040000040c00000"
    "0000000000000000000000000000" + "000000000000f83f" * 18
)
INNER_4 = (
    "5104010464656d6f0700000004000000000000000000ffffffff0000003f00000000000080bf0000"
    "0000000000000000000000000000" + "0000000000000040" * 18
)
#: magic, batch schema 1, kind 6, swarm "demo"; 2 messages; their lengths (198 bytes each)
BATCH_HEX = "5101060464656d6f" + "0200" + "c6000000" + "c6000000" + INNER_3 + INNER_4
#: the same messages at consensus schema version 3 (no take-off round), as an older build's
#: version-1 batch carries them (194 bytes each)
INNER_3_V3 = (
    "5103010464656d6f07000000030000000000000000000000803f00000040000040c0000000000000"
    "00000000000000000000" + "000000000000f83f" * 18
)
INNER_4_V3 = (
    "5103010464656d6f07000000040000000000000000000000003f00000000000080bf000000000000"
    "00000000000000000000" + "0000000000000040" * 18
)
BATCH_V3_INNER_HEX = "5101060464656d6f0200c2000000c2000000" + INNER_3_V3 + INNER_4_V3


def test_a_version_1_batch_of_version_3_messages_still_opens() -> None:
    entries = split_batch(bytes.fromhex(BATCH_V3_INNER_HEX), SID)
    assert [(e.sender, e.round, e.origin) for e in entries] == [
        (3, 7, (1.0, 2.0, -3.0)),
        (4, 7, (0.5, 0.0, -1.0)),
    ]
    batch = open_batch(bytes.fromhex(BATCH_V3_INNER_HEX), SID)
    for k in range(2):
        message = batch.packet(k, SID, 16 * 1024).message
        assert message.takeoff_round is None and message.sender == 3 + k


def test_batch_golden_bytes() -> None:
    a = encode_consensus(_message(3), (1.0, 2.0, -3.0), SID)
    b = encode_consensus(_message(4), (0.5, 0.0, -1.0), SID)
    assert a.hex() == INNER_3 and b.hex() == INNER_4
    assert encode_batch([(3, a), (4, b)], SID).hex() == BATCH_HEX
    entries = split_batch(bytes.fromhex(BATCH_HEX), SID)
    assert [(e.sender, e.round, e.origin) for e in entries] == [
        (3, 7, (1.0, 2.0, -3.0)),
        (4, 7, (0.5, 0.0, -1.0)),
    ]
    assert decode_consensus(entries[1].payload, SID).message.gamma.tolist() == [2.0] * 18


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (bytes.fromhex(BATCH_HEX)[:-1], Reason.TRUNCATED),
        (bytes.fromhex(BATCH_HEX) + b"\0", Reason.TRAILING),
        (bytes.fromhex(BATCH_HEX)[:12], Reason.TRUNCATED),
        (bytes.fromhex("5102060464656d6f") + bytes.fromhex(BATCH_HEX)[8:], Reason.BAD_VERSION),
        (bytes.fromhex("5101060465656d6f") + bytes.fromhex(BATCH_HEX)[8:], Reason.WRONG_SWARM),
        (bytes.fromhex(INNER_3), Reason.WRONG_KIND),
        # one message only: a batch holds two or more
        (bytes.fromhex("5101060464656d6f0100c6000000" + INNER_3), Reason.BAD_VALUE),
        # senders out of order
        (bytes.fromhex(BATCH_HEX[:36] + INNER_4 + INNER_3), Reason.BAD_VALUE),
    ],
)
def test_malformed_batches_are_rejected_with_their_reason(data: bytes, reason: Reason) -> None:
    with pytest.raises(WireError) as err:
        split_batch(data, SID)
    assert err.value.reason == reason


def test_encoder_refuses_what_is_not_a_batch() -> None:
    a = bytes.fromhex(INNER_3)
    with pytest.raises(ValueError, match=r"2\.\."):
        encode_batch([(3, a)], SID)
    with pytest.raises(ValueError, match="increasing"):
        encode_batch([(4, a), (3, a)], SID)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=600))
def test_random_bytes_raise_only_wire_errors(data: bytes) -> None:
    for blob in (data, bytes.fromhex(BATCH_HEX)[:16] + data):
        with contextlib.suppress(WireError):
            split_batch(blob, SID)


# -- versions 2 and 3: the messages in columns (what hosting processes send) --------------------

#: drone 3's (one edge, to 4, made with its incarnation 2; its swarm took off at round 5) and
#: drone 4's (no edge, moving, take-off round not said) round-7 messages
COLUMNS_HEX = (
    "5103060464656d6f"  # magic, batch schema 3, kind 6, swarm "demo"
    "0200"  # 2 messages
    # drone 3: round 7, sender 3, degree 1, ready 2, incarnation 1, take-off round 5,
    # position (1, 2, -3), velocity 0, 1 heard, 1 edge
    "07000000"
    "0300"
    "0100"
    "0200"
    "01000000"
    "05000000"
    "0000803f"
    "00000040"
    "000040c0"
    "00000000"
    "00000000"
    "00000000"
    "0100"
    "0100"
    # drone 4: round 7, sender 4, degree 2, ready 0, incarnation 9, take-off round not said,
    # position (0.5, 0, -1), velocity (0.5, 0, 0), 2 heard, no edge
    "07000000"
    "0400"
    "0200"
    "0000"
    "09000000"
    "ffffffff"
    "0000003f"
    "00000000"
    "000080bf"
    "0000003f"
    "00000000"
    "00000000"
    "0200"
    "0000"
    "0400"
    "0400"
    "0300"
    "0500"  # ids: 3 heard {4}, its edge 4; 4 heard {3, 5}
    "02000000"  # the edge incarnations: 3's edge to 4 made with 4's incarnation 2
    + "000000000000f83f" * 18  # 3's gamma
    + "000000000000d03f" * 18  # 3's edge sum to 4
    + "0000000000000040" * 18  # 4's gamma
)
#: the same messages in a version-2 batch (an older build's: consensus version 3's fixed
#: fields, no take-off round)
COLUMNS_V2_HEX = (
    "5102060464656d6f"  # magic, batch schema 2, kind 6, swarm "demo"
    "0200"  # 2 messages
    # drone 3: round 7, sender 3, degree 1, ready 2, incarnation 1, position (1, 2, -3),
    # velocity 0, 1 heard, 1 edge
    "07000000"
    "0300"
    "0100"
    "0200"
    "01000000"
    "0000803f"
    "00000040"
    "000040c0"
    "00000000"
    "00000000"
    "00000000"
    "0100"
    "0100"
    # drone 4: round 7, sender 4, degree 2, ready 0, incarnation 9, position (0.5, 0, -1),
    # velocity (0.5, 0, 0), 2 heard, no edge
    "07000000"
    "0400"
    "0200"
    "0000"
    "09000000"
    "0000003f"
    "00000000"
    "000080bf"
    "0000003f"
    "00000000"
    "00000000"
    "0200"
    "0000"
    "0400"
    "0400"
    "0300"
    "0500"  # ids: 3 heard {4}, its edge 4; 4 heard {3, 5}
    "02000000"  # the edge incarnations: 3's edge to 4 made with 4's incarnation 2
    + "000000000000f83f" * 18  # 3's gamma
    + "000000000000d03f" * 18  # 3's edge sum to 4
    + "0000000000000040" * 18  # 4's gamma
)


def _pair() -> tuple[ConsensusMessage, ConsensusMessage]:
    a = ConsensusMessage(
        sender=3,
        round=7,
        gamma=np.full(18, 1.5),
        edge_sums={4: np.full(18, 0.25)},
        heard=frozenset({4}),
        degree=1,
        ready_hops=2,
        incarnation=1,
        edge_incarnations={4: 2},
        takeoff_round=5,
    )
    b = ConsensusMessage(
        sender=4,
        round=7,
        gamma=np.full(18, 2.0),
        edge_sums={},
        heard=frozenset({3, 5}),
        degree=2,
        velocity_ned_m_s=np.array([0.5, 0.0, 0.0]),
        incarnation=9,
    )
    return a, b


def _same(got: ConsensusMessage, want: ConsensusMessage) -> None:
    """Field by field (arrays bit for bit; mappings as dicts)."""
    assert (
        got.sender,
        got.round,
        got.degree,
        got.ready_hops,
        got.incarnation,
        got.heard,
        got.takeoff_round,
    ) == (
        want.sender,
        want.round,
        want.degree,
        want.ready_hops,
        want.incarnation,
        want.heard,
        want.takeoff_round,
    )
    for name in ("gamma", "position_ned_m", "velocity_ned_m_s"):
        g, w = getattr(got, name), getattr(want, name)
        assert g.dtype == w.dtype and g.tobytes() == w.tobytes() and not g.flags.writeable
    assert list(got.edge_sums) == list(want.edge_sums)
    for j in want.edge_sums:
        assert got.edge_sums[j].tobytes() == want.edge_sums[j].tobytes()
    assert isinstance(got.edge_sums, EdgeSums) and not got.edge_sums.sums.flags.writeable
    want_tags = None if want.edge_incarnations is None else dict(want.edge_incarnations)
    got_tags = None if got.edge_incarnations is None else dict(got.edge_incarnations)
    assert got_tags == want_tags


def test_columns_golden_bytes() -> None:
    a, b = _pair()
    parts = [consensus_parts(a, (1.0, 2.0, -3.0), SID), consensus_parts(b, (0.5, 0.0, -1.0), SID)]
    assert BATCH_VERSION == 3
    assert encode_columns(parts, SID).hex() == COLUMNS_HEX
    batch = open_batch(bytes.fromhex(COLUMNS_HEX), SID)
    assert (batch.senders, batch.rounds) == ([3, 4], [7, 7])
    assert batch.origins == [(1.0, 2.0, -3.0), (0.5, 0.0, -1.0)]
    for k, (m, pos) in enumerate(((a, (1.0, 2.0, -3.0)), (b, (0.5, 0.0, -1.0)))):
        packet = batch.packet(k, SID, 16 * 1024)
        want = decode_consensus(encode_consensus(m, pos, SID), SID)
        _same(packet.message, want.message)
        assert packet.position_ned_m.tobytes() == want.position_ned_m.tobytes()
    assert [batch.packet(k, SID, 16 * 1024).message.takeoff_round for k in (0, 1)] == [5, None]


def test_a_version_2_batch_still_opens_without_takeoff_rounds() -> None:
    """An older build's batch in columns (consensus version 3's fixed fields) decodes to what
    its messages decode to alone at that version: each as sent, its take-off round None."""
    from dataclasses import replace

    a, b = _pair()
    batch = open_batch(bytes.fromhex(COLUMNS_V2_HEX), SID)
    assert (batch.senders, batch.rounds) == ([3, 4], [7, 7])
    assert batch.origins == [(1.0, 2.0, -3.0), (0.5, 0.0, -1.0)]
    for k, (m, pos) in enumerate(((a, (1.0, 2.0, -3.0)), (b, (0.5, 0.0, -1.0)))):
        packet = batch.packet(k, SID, 16 * 1024)
        assert packet.message.takeoff_round is None
        want = decode_consensus(encode_consensus(replace(m, takeoff_round=None), pos, SID), SID)
        _same(packet.message, want.message)
    # its messages' size is checked as the version-3 payloads they were: 8 + 42 + 4 + 4 + 288
    open_batch(bytes.fromhex(COLUMNS_V2_HEX), SID, max_consensus_bytes=346)
    with pytest.raises(WireError) as err:
        open_batch(bytes.fromhex(COLUMNS_V2_HEX), SID, max_consensus_bytes=345)
    assert err.value.reason == Reason.OVERSIZED
    with pytest.raises(WireError) as err:
        open_batch(bytes.fromhex(COLUMNS_V2_HEX)[:-1], SID)
    assert err.value.reason == Reason.TRUNCATED


def test_a_version_1_batch_still_opens() -> None:
    batch = open_batch(bytes.fromhex(BATCH_HEX), SID)
    assert batch.senders == [3, 4] and batch.origins[1] == (0.5, 0.0, -1.0)
    assert batch.packet(1, SID, 16 * 1024).message.gamma.tolist() == [2.0] * 18


def _columns(edit: Callable[[str], str]) -> bytes:
    return bytes.fromhex(edit(COLUMNS_HEX))


NAN_F64 = "000000000000f87f"


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (_columns(lambda h: h[:-2]), Reason.TRUNCATED),
        (_columns(lambda h: h + "00"), Reason.TRAILING),
        (_columns(lambda h: h[:40]), Reason.TRUNCATED),
        (_columns(lambda h: h[:20]), Reason.TRUNCATED),
        (_columns(lambda h: "5104" + h[4:]), Reason.BAD_VERSION),
        (_columns(lambda h: h[: 20 + 2 * 46 + 30]), Reason.TRUNCATED),  # in 4's take-off round
        (_columns(lambda h: h[:8] + "65" + h[10:]), Reason.WRONG_SWARM),
        (_columns(lambda h: h[:16] + "0100" + h[20:]), Reason.BAD_VALUE),  # a batch of one
        # drone 4's message first: senders out of order
        (_columns(lambda h: h[:20] + h[112:204] + h[20:112] + h[204:]), Reason.BAD_VALUE),
        # 4's heard ids {5, 3}: not increasing
        (_columns(lambda h: h.replace("0400040003000500", "0400040005000300")), Reason.BAD_VALUE),
        # NaN in 4's gamma, in 3's edge sum, in 3's position
        (_columns(lambda h: h[:-16] + NAN_F64), Reason.NOT_FINITE),
        (_columns(lambda h: h.replace("000000000000d03f", NAN_F64, 1)), Reason.NOT_FINITE),
        (_columns(lambda h: h.replace("0000803f", "0000c07f", 1)), Reason.NOT_FINITE),
    ],
)
def test_malformed_columns_are_rejected_with_their_reason(data: bytes, reason: Reason) -> None:
    with pytest.raises(WireError) as err:
        open_batch(data, SID)
    assert err.value.reason == reason


def test_a_batched_message_over_the_receivers_limit_rejects_the_batch() -> None:
    data = bytes.fromhex(COLUMNS_HEX)
    # drone 3's message alone would be 8 + 46 + 4 + 4 + 2 x 144 = 350 bytes
    open_batch(data, SID, max_consensus_bytes=350)
    with pytest.raises(WireError) as err:
        open_batch(data, SID, max_consensus_bytes=349)
    assert err.value.reason == Reason.OVERSIZED


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=600))
def test_random_bytes_raise_only_wire_errors_from_either_version(data: bytes) -> None:
    heads = (
        b"",
        bytes.fromhex(COLUMNS_HEX)[:10],
        bytes.fromhex(COLUMNS_V2_HEX)[:10],
        bytes.fromhex(BATCH_HEX)[:10],
    )
    for blob in (head + data for head in heads):
        with contextlib.suppress(WireError):
            open_batch(blob, SID)


def _random_message(rng: np.random.Generator, sender: int) -> ConsensusMessage:
    n = int(rng.integers(0, 12))
    ids = np.sort(rng.choice(300, n, replace=False)).astype(np.intp)
    tags = rng.integers(-1, 50, n).astype(np.int64)
    mode = int(rng.integers(0, 3))  # tags as arrays, as a dict, or none
    return ConsensusMessage(
        sender=sender,
        round=int(rng.integers(0, 2**32 - 1)),
        gamma=rng.normal(size=18),
        edge_sums=(
            EdgeSums(ids, rng.normal(size=(n, 18)))
            if mode != 1
            else {int(j): rng.normal(size=18) for j in ids}
        ),
        heard=frozenset(rng.choice(300, int(rng.integers(0, 8)), replace=False).tolist()),
        degree=int(rng.integers(0, 300)),
        ready_hops=int(rng.integers(0, 9)),
        velocity_ned_m_s=None if rng.random() < 0.3 else rng.normal(size=3),
        incarnation=int(rng.integers(0, 10**6)),
        takeoff_round=None if rng.random() < 0.3 else int(rng.integers(0, 2**32 - 1)),
        edge_incarnations=(
            EdgeIncarnations(ids, tags)
            if mode == 0
            else ({int(j): int(t) for j, t in zip(ids, tags, strict=True)} if mode == 1 else None)
        ),
    )


@pytest.mark.parametrize("seed", range(20))
def test_columns_decode_to_what_the_single_messages_decode_to(seed: int) -> None:
    rng = np.random.default_rng(seed)
    senders = np.sort(rng.choice(250, int(rng.integers(2, 9)), replace=False)).tolist()
    messages = [_random_message(rng, s) for s in senders]
    origins = [tuple(rng.normal(size=3) * 100) for _ in messages]
    parts = [consensus_parts(m, o, SID) for m, o in zip(messages, origins, strict=True)]
    batch = open_batch(encode_columns(parts, SID), SID)
    assert batch.senders == senders and batch.rounds == [m.round for m in messages]
    for k, (m, o) in enumerate(zip(messages, origins, strict=True)):
        want = decode_consensus(encode_consensus(m, o, SID), SID)
        assert batch.origins[k] == tuple(want.position_ned_m.tolist())
        _same(batch.packet(k, SID, 16 * 1024).message, want.message)


def test_column_encoder_refuses_what_is_not_a_batch() -> None:
    a, b = _pair()
    pa, pb = consensus_parts(a, (0, 0, 0), SID), consensus_parts(b, (0, 0, 0), SID)
    with pytest.raises(ValueError, match=r"2\.\."):
        encode_columns([pa], SID)
    with pytest.raises(ValueError, match="increasing"):
        encode_columns([pb, pa], SID)


SETTINGS = LinkSettings(SID, comm_range_m=10.0)
KEYS = SETTINGS.keys()


def _kinds(bus: MemoryBus) -> list[tuple[str, int]]:
    seen: list[tuple[str, int]] = []
    bus_session = bus.session()
    bus_session.subscribe_callback(KEYS.consensus_all(), lambda k, p: seen.append((k, p[2])))
    return seen


def test_hosted_agents_send_one_batch_per_cell_and_each_applies_its_own_range() -> None:
    memory = MemoryBus()
    seen = _kinds(memory)
    host_bus, other_bus = memory.session(), memory.session()
    hub = ConsensusHub(host_bus, SETTINGS, batch=True)
    # drones 0 and 1 in one process, 8 m apart; drone 2 alone, 9 m from drone 0 and 17 m from 1
    a = AgentLink(host_bus, 0, (1.0, 1.0, -1.0), SETTINGS, hub)
    b = AgentLink(host_bus, 1, (9.0, 1.0, -1.0), SETTINGS, hub)
    c = AgentLink(other_bus, 2, (1.0, 10.0, -1.0), SETTINGS)
    for link, pos in ((a, (1.0, 1.0, -1.0)), (b, (9.0, 1.0, -1.0))):
        link.publish_consensus(_message(link.drone, 3), pos)
    assert not seen  # staged until the pass ends
    hub.flush()
    assert [kind for _, kind in seen] == [Kind.CONSENSUS_BATCH]
    assert seen[0][0] == KEYS.consensus(KEYS.cell((1.0, 1.0, -1.0)), 0)
    c.publish_consensus(_message(2, 3), (1.0, 10.0, -1.0))
    assert [kind for _, kind in seen][1:] == [Kind.CONSENSUS]  # one agent: the single schema
    assert [p.message.sender for p in a.receive()] == [1, 2]
    assert [p.message.sender for p in b.receive()] == [0]  # drone 2 is out of its range
    assert [p.message.sender for p in c.receive()] == [0]  # drone 1 is out of its range
    assert a.counters().rx == 2 and b.counters().out_of_range == 1
    for link in (a, b, c):
        link.close()
    hub.close()


def test_a_bad_batch_is_counted_by_each_agent_that_hears_it() -> None:
    memory = MemoryBus()
    bus = memory.session()
    hub = ConsensusHub(bus, SETTINGS, batch=True)
    a = AgentLink(bus, 0, (1.0, 1.0, -1.0), SETTINGS, hub)
    b = AgentLink(bus, 1, (2.0, 1.0, -1.0), SETTINGS, hub)
    rogue = memory.session().publisher(
        KEYS.consensus(KEYS.cell((3.0, 1.0, -1.0)), 5), Congestion.DROP
    )
    rogue.put(bytes.fromhex(BATCH_HEX)[:-3])
    # a batch whose key names another drone than its first message
    rogue.put(bytes.fromhex(BATCH_HEX))
    assert a.receive() == [] and b.receive() == []
    for link in (a, b):
        counters = link.counters()
        assert counters.rx == 2 and counters.malformed == 2
    a.close()
    b.close()
    hub.close()


def test_batch_lengths_are_little_endian_u32() -> None:
    data = bytes.fromhex(BATCH_HEX)
    assert struct.unpack_from("<H2I", data, 8) == (2, 198, 198)


def test_messages_of_the_batched_core_encode_to_the_same_bytes_as_plain_ones() -> None:
    from protocols.wire.consensus_message import EdgeIncarnations, EdgeSums

    rng = np.random.default_rng(3)
    for n in (0, 1, 4, 17):
        ids = np.sort(rng.choice(200, n, replace=False)).astype(np.intp)
        sums = rng.normal(size=(n, 18))
        tags = rng.integers(-1, 5000, n).astype(np.int64)
        for with_tags in (True, False):
            arrays = ConsensusMessage(
                sender=250,
                round=99,
                gamma=rng.normal(size=18),
                edge_sums=EdgeSums(ids, sums),
                heard=frozenset(rng.choice(200, 5, replace=False).tolist()),
                degree=5,
                ready_hops=2,
                velocity_ned_m_s=np.array([0.1, 0.2, -0.3]),
                incarnation=12,
                edge_incarnations=EdgeIncarnations(ids, tags) if with_tags else None,
            )
            plain = ConsensusMessage(
                **{
                    **arrays.__dict__,
                    "edge_sums": {int(j): sums[k] for k, j in enumerate(ids)},
                    "edge_incarnations": (
                        {int(j): int(t) for j, t in zip(ids, tags, strict=True)}
                        if with_tags
                        else None
                    ),
                }
            )
            assert encode_consensus(arrays, (1, 2, 3), SID) == encode_consensus(
                plain, (1, 2, 3), SID
            )
    bad = ConsensusMessage(
        sender=1,
        round=1,
        gamma=np.zeros(18),
        edge_sums=EdgeSums(np.array([2]), np.full((1, 18), np.nan)),
        heard=frozenset(),
        degree=0,
    )
    with pytest.raises(ValueError, match="finite"):
        encode_consensus(bad, (0, 0, 0), SID)


# -- the status batch (protocols/wire/status.py, Kind.STATUS_BATCH) ----------------------------


def _status(drone: int, takeoff_round: int | None = None) -> AgentStatus:
    return AgentStatus(
        drone=drone,
        round=1000,
        t_s=20.0,
        mode=AgentMode.FLYING,
        armed=True,
        health=Health.VEHICLE_LINK | Health.PLAN,
        estimate=np.arange(9.0),
        neighbours=(1, 5),
        counters=StatusCounters(100, 1, 2, 3, 50, 0),
        plan_seq=7,
        takeoff_round=takeoff_round,
    )


def test_status_batch_golden_bytes_and_round_trip() -> None:
    a, b = encode_status(_status(2), SID), encode_status(_status(6), SID)
    assert len(a) == len(b) == 167 and STATUS_BATCH_VERSION == 1
    batch = encode_status_batch([(2, a), (6, b)], SID)
    # magic, status batch schema 1, kind 7, swarm "demo"; 2 statuses of 167 bytes each
    assert batch.hex() == "5101070464656d6f" + "0200" + "a7000000" * 2 + a.hex() + b.hex()
    assert decode_statuses(batch, SID) == [_status(2), _status(6)]
    assert decode_statuses(a, SID) == [_status(2)]  # one status alone: the single schema


def test_status_batch_carries_take_off_rounds_and_statuses_of_either_version() -> None:
    """The batch's statuses are complete payloads: each with its take-off round (or None), and
    a version-1 status (an older agent's, no take-off round) decodes in it as alone."""
    statuses = [_status(2, 1234), _status(6), _status(9, 0)]
    batch = encode_status_batch([(s.drone, encode_status(s, SID)) for s in statuses], SID)
    decoded = decode_statuses(batch, SID)
    assert decoded == statuses and [s.takeoff_round for s in decoded] == [1234, None, 0]
    current = encode_status(_status(6, 77), SID)
    assert current[1] == STATUS_VERSION == 3
    # the same status at version 1: no u32 take-off round after the plan's sequence number, no
    # 7th counter (the radio's) after the six
    older = bytes([0x51, 1]) + current[2:27] + current[31:153] + current[161:]
    assert len(older) == len(current) - 12
    mixed = encode_status_batch([(2, encode_status(_status(2, 5), SID)), (6, older)], SID)
    assert decode_statuses(mixed, SID) == [_status(2, 5), _status(6)]
    assert decode_statuses(older, SID) == [_status(6)]


@pytest.mark.parametrize(
    ("cut", "reason"),
    [
        (lambda x: x[:-1], Reason.TRUNCATED),
        (lambda x: x + b"\0", Reason.TRAILING),
        (lambda x: x[:10], Reason.TRUNCATED),
        (lambda x: x[:1] + b"\2" + x[2:], Reason.BAD_VERSION),
        (lambda x: x[:8] + b"\1\0" + x[10:], Reason.BAD_VALUE),  # a batch of one
    ],
)
def test_malformed_status_batches_are_rejected_with_their_reason(
    cut: Callable[[bytes], bytes], reason: Reason
) -> None:
    a, b = encode_status(_status(2), SID), encode_status(_status(6), SID)
    with pytest.raises(WireError) as err:
        decode_statuses(cut(encode_status_batch([(2, a), (6, b)], SID)), SID)
    assert err.value.reason == reason
    unsorted = encode_status_batch([(2, b), (6, a)], SID)  # the drones inside are 6, 2
    with pytest.raises(WireError, match="increasing"):
        decode_statuses(unsorted, SID)
    with pytest.raises(ValueError, match=r"2\.\."):
        encode_status_batch([(2, a)], SID)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=600))
def test_random_status_bytes_raise_only_wire_errors(data: bytes) -> None:
    for blob in (data, bytes.fromhex("5101070464656d6f0200") + data):
        with contextlib.suppress(WireError):
            decode_statuses(blob, SID)


def test_hosted_agents_send_their_statuses_of_a_pass_in_one_sample() -> None:
    memory = MemoryBus()
    seen: list[tuple[str, bytes]] = []
    memory.session().subscribe_callback(KEYS.status_all(), lambda k, p: seen.append((k, p)))
    bus = memory.session()
    hub = ConsensusHub(bus, SETTINGS, batch=True)
    a = AgentLink(bus, 6, (1.0, 1.0, -1.0), SETTINGS, hub)
    b = AgentLink(bus, 2, (2.0, 1.0, -1.0), SETTINGS, hub)
    alone = AgentLink(memory.session(), 9, (3.0, 1.0, -1.0), SETTINGS)
    a.publish_status(_status(6))
    b.publish_status(_status(2))
    assert not seen  # staged until the pass ends
    hub.flush()
    assert [k for k, _ in seen] == [KEYS.status(2)]  # on the first drone's key
    assert [s.drone for s in decode_statuses(seen[0][1], SID)] == [2, 6]
    alone.publish_status(_status(9))  # one agent: the single schema, at once
    assert seen[1] == (KEYS.status(9), encode_status(_status(9), SID))
    a.publish_status(_status(6))
    a.close()  # what it staged goes out before its publisher closes
    assert seen[2] == (KEYS.status(6), encode_status(_status(6), SID))
    for link in (b, alone):
        link.close()
    hub.close()


def test_a_steps_messages_are_laid_out_in_columns_as_one_by_one() -> None:
    """The messages of a batched consensus step, laid out together from the step's arrays
    (transport_link.wire_parts: protocols.wire.format.column_parts), are byte for byte what
    consensus_parts makes of each: over rounds with partial hearing, a listening row, a restart
    (edges with and without incarnations), messages without motion, two steps mixed, a message
    rebuilt by hand; and one that cannot be sent still raises."""
    from dataclasses import replace

    from drone_agent.core.consensus.estimator import BatchConsensus
    from drone_agent.core.consensus.packing import message_columns
    from drone_agent.core.consensus.scalar import ConsensusParams
    from drone_agent.process.transport_link import wire_parts
    from protocols.wire.format import column_parts

    ids = (0, 3, 4, 9, 12)
    rng = np.random.default_rng(11)
    batches = [
        BatchConsensus(ids[:3], ConsensusParams()),
        BatchConsensus(ids[3:], ConsensusParams()),
    ]
    inboxes: list[list[ConsensusMessage]] = [[] for _ in ids]
    checked = 0
    for round_ in range(12):
        if round_ == 5:
            batches[0].set_observing(1, True)
        if round_ == 8:
            batches[1].restart(0)
        made: list[ConsensusMessage] = []
        for b, batch in enumerate(batches):
            rows = list(range(len(batch.agent_ids)))
            zeta = rng.normal(size=(len(rows), 18))
            motion = None if round_ % 4 == 3 else (rng.normal(size=(len(rows), 3)),
                                                   rng.normal(size=(len(rows), 3)))  # fmt: skip
            first = 0 if b == 0 else 3
            box = inboxes[first : first + len(rows)]
            _, out, _, _ = batch.step_outgoing(rows, round_, zeta, box, [None] * len(rows), motion)
            # take-off rounds: none said (before take-off), said by some, or by each
            takeoffs = (
                None
                if round_ < 3
                else [None if (round_ + r) % 3 == 0 else 2 + r for r in rows]
                if round_ < 7
                else [2] * len(rows)
            )
            made += out.messages([round_ % 3] * len(rows), takeoffs)
        levels = [replace(m, ready_hops=m.ready_hops + 1) for m in made]  # as a host publishes
        hand = replace(levels[2], edge_sums=dict(levels[2].edge_sums))  # no longer a step's
        sent = [*levels[:2], hand, *levels[3:]]
        where = [tuple(rng.normal(size=3).tolist()) for _ in sent]
        expected = [consensus_parts(m, p, SID) for m, p in zip(sent, where, strict=True)]
        assert wire_parts(sent, where, SID) == expected
        assert message_columns(sent[3:], where[3:]) is not None  # the columns path was taken
        checked += sum(len(m.edge_sums) for m in sent)
        # each drone hears a few of the others this round (lossy radio)
        inboxes = [[m for m in made if m.sender != i and rng.random() < 0.7] for i in ids]
    assert checked > 40  # edges were laid out, not only empty messages
    bad = replace(levels[4], gamma=np.full(18, np.nan))
    with pytest.raises(ValueError, match="finite"):
        wire_parts([levels[3], bad], [(0.0, 0.0, 0.0)] * 2, SID)
    with pytest.raises(ValueError, match="exceeds"):
        wire_parts(levels[3:], [(0.0, 0.0, 0.0)] * 2, SID, max_bytes=200)
    # the columns themselves: a message with a NaN, or a position beyond float32, is left to
    # consensus_parts (None), the others laid out
    cols = message_columns(levels[:3], [(0.0, 0.0, 0.0)] * 3)
    assert cols is not None and cols.edge_sums.shape[0] > 0
    gamma = cols.gamma.copy()
    gamma[0, 4] = np.inf
    sums = cols.edge_sums.copy()
    sums[-1, 0] = np.nan  # the last message's last edge
    far = [(0.0, 0.0, 0.0), (1e39, 0.0, 0.0), (0.0, 0.0, 0.0)]
    laid = column_parts(cols._replace(gamma=gamma, edge_sums=sums, positions=far), SID)
    assert laid == [None, None, None]
    laid = column_parts(cols._replace(gamma=gamma), SID)
    assert laid[0] is None and laid[1:] == [consensus_parts(m, (0, 0, 0), SID) for m in levels[1:3]]
    # a take-off round out of range (0xFFFFFFFF is None's) is left to consensus_parts, which
    # refuses it; negative is None (not said)
    laid = column_parts(cols._replace(takeoffs=[2**32 - 1, -1, 2**32]), SID)
    assert laid[0] is None and laid[2] is None
    assert laid[1] == consensus_parts(replace(levels[1], takeoff_round=None), (0, 0, 0), SID)
    for bad in (2**32 - 1, 2**32, -1):
        with pytest.raises(ValueError, match="takeoff_round"):
            consensus_parts(replace(levels[0], takeoff_round=bad), (0, 0, 0), SID)
    laid = column_parts(cols._replace(takeoffs=[0, 2**32 - 2, 17]), SID)
    for m, got, takeoff in zip(levels[:3], laid, (0, 2**32 - 2, 17), strict=True):
        assert got == consensus_parts(replace(m, takeoff_round=takeoff), (0, 0, 0), SID)


def test_a_steps_messages_carry_their_take_off_rounds_to_the_wire() -> None:
    """Outgoing.messages puts each row's take-off round on its message (None: None each), and
    packing.with_level puts a level and a take-off round on one (the same message when
    both are already its): what the columns and the single payloads then carry."""
    import dataclasses

    from drone_agent.core.consensus.estimator import BatchConsensus
    from drone_agent.core.consensus.packing import with_level
    from drone_agent.core.consensus.scalar import ConsensusParams
    from drone_agent.process.transport_link import wire_parts

    ids = (0, 1, 2)
    batch = BatchConsensus(ids, ConsensusParams())
    motion = (np.ones((3, 3)), np.zeros((3, 3)))
    _, out, _, _ = batch.step_outgoing(ids, 0, np.ones((3, 18)), [[], [], []], [None] * 3, motion)
    assert [m.takeoff_round for m in out.messages()] == [None] * 3
    made = out.messages([1, 2, 3], [40, None, 0])
    assert [(m.ready_hops, m.takeoff_round) for m in made] == [(1, 40), (2, None), (3, 0)]
    with pytest.raises(ValueError):
        out.messages(None, [1, 2])  # one per row
    where = [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (2.0, 0.0, 0.0)]
    parts = wire_parts(made, where, SID)
    assert parts == [consensus_parts(m, p, SID) for m, p in zip(made, where, strict=True)]
    opened = open_batch(encode_columns(parts, SID), SID)
    assert [opened.packet(k, SID, 16 * 1024).message.takeoff_round for k in range(3)] == [
        40,
        None,
        0,
    ]
    message = out.messages()[1]
    leveled = with_level(message, 4, takeoff_round=12)
    expected = dataclasses.replace(message, ready_hops=4, takeoff_round=12)
    for f in dataclasses.fields(expected):
        assert getattr(leveled, f.name) is getattr(expected, f.name) or (
            getattr(leveled, f.name) == getattr(expected, f.name)
        ), f.name
    assert with_level(leveled, 4, takeoff_round=12) is leveled
    assert with_level(message, message.ready_hops) is message
    assert with_level(leveled, 4).takeoff_round is None  # both set: None is not flying
    assert with_level(message, 0, takeoff_round=3).takeoff_round == 3
    packet = decode_consensus(encode_consensus(leveled, (0, 0, 0), SID), SID)
    assert (packet.message.ready_hops, packet.message.takeoff_round) == (4, 12)


def test_a_sole_hub_hands_its_agents_messages_over_and_sends_them_to_other_sessions_only() -> None:
    """The process's one hub (``sole``, as ``swarm agent`` makes it) gives its agents their
    siblings' messages directly and publishes remote-only: the bus carries its batch to the
    other processes only, and each agent takes what it took when the batch came back through
    the bus (same senders, same messages: a batched core's message as it is, any other decoded
    from its bytes), range and counters applied as before."""
    from dataclasses import replace

    from drone_agent.core.consensus.estimator import BatchConsensus
    from drone_agent.core.consensus.scalar import ConsensusParams

    where = [(1.0, 1.0, -1.0), (9.0, 1.0, -1.0), (2.0, 2.0, -1.0)]
    batch = BatchConsensus((0, 1), ConsensusParams())
    motion = (np.array(where[:2], dtype=np.float32).astype(float), np.full((2, 3), 0.25))
    _, out, _, _ = batch.step_outgoing([0, 1], 3, np.ones((2, 18)), [[], []], [None] * 2, motion)
    made = [*out.messages([1, 2]), replace(_message(2, 3), edge_sums={0: np.full(18, 0.5)})]

    def taken(sole: bool) -> tuple[list[list[bytes]], list[tuple[str, int]], list[str], list[int]]:
        memory = MemoryBus()
        seen = _kinds(memory)
        host_bus, other_bus = memory.session(), memory.session()
        own: list[str] = []
        host_bus.subscribe_callback(KEYS.consensus_all(), lambda k, _p: own.append(k))
        hub = ConsensusHub(host_bus, SETTINGS, batch=True, sole=sole)
        links = [AgentLink(host_bus, i, where[i], SETTINGS, hub) for i in range(3)]
        far = AgentLink(other_bus, 5, (1.0, 10.0, -1.0), SETTINGS)
        for link, message in zip(links, made, strict=True):
            link.publish_consensus(message, where[link.drone])
        hub.flush()
        got = [
            [encode_consensus(p.message, p.position_ned_m, SID) for p in link.receive()]
            for link in (*links, far)
        ]
        counts = [link.counters().rx for link in (*links, far)]
        for link in (*links, far):
            link.close()
        hub.close()
        return got, seen, own, counts

    through_bus, seen_before, own_before, counts_before = taken(sole=False)
    handed, seen_now, own_now, counts_now = taken(sole=True)
    assert handed == through_bus and counts_now == counts_before
    assert [len(g) for g in handed] == [2, 2, 2, 2]  # drone 1 is 12 m from drone 5: out
    assert seen_now == seen_before and [kind for _, kind in seen_now] == [Kind.CONSENSUS_BATCH]
    assert own_before and not own_now  # nothing came back to the host's own session
