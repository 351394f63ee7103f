"""Wire format: golden bytes, layout by hand, round trips, malformed input and fuzzing."""

from __future__ import annotations

import contextlib
import math
import struct
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols.model.trajectory import DescriptorTrajectory
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.format import (
    CONSENSUS_VERSION,
    MAX_CONSENSUS_BYTES,
    WIRE_VERSION,
    Kind,
    Reason,
    WireError,
    consensus_origin,
    decode_consensus,
    encode_consensus,
)
from protocols.wire.keys import MAX_SWARM
from protocols.wire.plan import FlightCommand, PlanMessage, decode_plan, encode_plan
from protocols.wire.status import (
    STATUS_VERSION,
    AgentMode,
    AgentStatus,
    Health,
    StatusCounters,
    decode_status,
    encode_status,
)

pytestmark = pytest.mark.timeout(60)

SID = "demo"
GAMMA = (np.arange(18) * 0.125 - 1.0).astype(np.float64)
MESSAGE = ConsensusMessage(
    sender=2,
    round=1000,
    gamma=GAMMA,
    edge_sums={5: (2.0 ** -np.arange(18)).astype(np.float64), 1: -np.arange(18.0)},
    heard=frozenset({7, 1, 5}),
    degree=3,
    ready_hops=9,
    velocity_ned_m_s=np.array([0.5, -3.0, 0.125]),
    incarnation=950,
    edge_incarnations={5: 40, 1: 0},
    takeoff_round=980,
)
POSITION = (1.5, -2.25, -10.0)
VELOCITY = (0.5, -3.0, 0.125)
#: Version 4: the round its swarm took off (u32) after the sender's incarnation.
CONSENSUS_HEX = (
    "5104010464656d6fe8030000020003000900b6030000d40300000000c03f000010c0000020c10000"
    "003f000040c00000003e03000200010005000700010005000000000028000000000000000000f0bf"
    "000000000000ecbf000000000000e8bf000000000000e4bf000000000000e0bf000000000000d8bf"
    "000000000000d0bf000000000000c0bf0000000000000000000000000000c03f000000000000d03f"
    "000000000000d83f000000000000e03f000000000000e43f000000000000e83f000000000000ec3f"
    "000000000000f03f000000000000f23f0000000000000080000000000000f0bf00000000000000c0"
    "00000000000008c000000000000010c000000000000014c000000000000018c00000000000001cc0"
    "00000000000020c000000000000022c000000000000024c000000000000026c000000000000028c0"
    "0000000000002ac00000000000002cc00000000000002ec000000000000030c000000000000031c0"
    "000000000000f03f000000000000e03f000000000000d03f000000000000c03f000000000000b03f"
    "000000000000a03f000000000000903f000000000000803f000000000000703f000000000000603f"
    "000000000000503f000000000000403f000000000000303f000000000000203f000000000000103f"
    "000000000000003f000000000000f03e000000000000e03e"
)
#: Version 3 (the same message from a sender of an older build: no take-off round): the
#: sender's incarnation (u32) after the settled level, and one u32 incarnation per edge
#: neighbour after the ids.
CONSENSUS_V3_HEX = (
    "5103010464656d6fe8030000020003000900b60300000000c03f000010c0000020c10000003f0000"
    "40c00000003e03000200010005000700010005000000000028000000000000000000f0bf00000000"
    "0000ecbf000000000000e8bf000000000000e4bf000000000000e0bf000000000000d8bf00000000"
    "0000d0bf000000000000c0bf0000000000000000000000000000c03f000000000000d03f00000000"
    "0000d83f000000000000e03f000000000000e43f000000000000e83f000000000000ec3f00000000"
    "0000f03f000000000000f23f0000000000000080000000000000f0bf00000000000000c000000000"
    "000008c000000000000010c000000000000014c000000000000018c00000000000001cc000000000"
    "000020c000000000000022c000000000000024c000000000000026c000000000000028c000000000"
    "00002ac00000000000002cc00000000000002ec000000000000030c000000000000031c000000000"
    "0000f03f000000000000e03f000000000000d03f000000000000c03f000000000000b03f00000000"
    "0000a03f000000000000903f000000000000803f000000000000703f000000000000603f00000000"
    "0000503f000000000000403f000000000000303f000000000000203f000000000000103f00000000"
    "0000003f000000000000f03e000000000000e03e"
)
#: Version 2 (the same message from a sender of an older build: no incarnations).
CONSENSUS_V2_HEX = (
    "5102010464656d6fe80300000200030009000000c03f000010c0000020c10000003f000040c00000003e"
    "0300020001000500070001000500000000000000f0bf000000000000ecbf000000000000e8bf0000"
    "00000000e4bf000000000000e0bf000000000000d8bf000000000000d0bf000000000000c0bf0000"
    "000000000000000000000000c03f000000000000d03f000000000000d83f000000000000e03f0000"
    "00000000e43f000000000000e83f000000000000ec3f000000000000f03f000000000000f23f0000"
    "000000000080000000000000f0bf00000000000000c000000000000008c000000000000010c00000"
    "0000000014c000000000000018c00000000000001cc000000000000020c000000000000022c00000"
    "0000000024c000000000000026c000000000000028c00000000000002ac00000000000002cc00000"
    "000000002ec000000000000030c000000000000031c0000000000000f03f000000000000e03f0000"
    "00000000d03f000000000000c03f000000000000b03f000000000000a03f000000000000903f0000"
    "00000000803f000000000000703f000000000000603f000000000000503f000000000000403f0000"
    "00000000303f000000000000203f000000000000103f000000000000003f000000000000f03e0000"
    "00000000e03e"
)
#: Version 1 (the same message from a sender of an older build: no velocity).
CONSENSUS_V1_HEX = (
    "5101010464656d6fe8030000020003000000c03f000010c0000020c1030002000100050007000100"
    "0500000000000000f0bf000000000000ecbf000000000000e8bf000000000000e4bf000000000000"
    "e0bf000000000000d8bf000000000000d0bf000000000000c0bf0000000000000000000000000000"
    "c03f000000000000d03f000000000000d83f000000000000e03f000000000000e43f000000000000"
    "e83f000000000000ec3f000000000000f03f000000000000f23f0000000000000080000000000000"
    "f0bf00000000000000c000000000000008c000000000000010c000000000000014c0000000000000"
    "18c00000000000001cc000000000000020c000000000000022c000000000000024c0000000000000"
    "26c000000000000028c00000000000002ac00000000000002cc00000000000002ec0000000000000"
    "30c000000000000031c0000000000000f03f000000000000e03f000000000000d03f000000000000"
    "c03f000000000000b03f000000000000a03f000000000000903f000000000000803f000000000000"
    "703f000000000000603f000000000000503f000000000000403f000000000000303f000000000000"
    "203f000000000000103f000000000000003f000000000000f03e000000000000e03e"
)
STATUS = AgentStatus(
    drone=2,
    round=1000,
    t_s=20.0,
    mode=AgentMode.FLYING,
    armed=True,
    health=Health.VEHICLE_LINK | Health.ESTIMATE_FINITE | Health.CONVERGED | Health.PLAN,
    estimate=np.array([1, 2, -10, 0, 0, 0.5, 4, 2.25, 1]),
    neighbours=(1, 5),
    counters=StatusCounters(100, 1, 2, 3, 50, 0, 4),
    plan_seq=7,
    takeoff_round=980,
)
#: Status version 3: the messages the radio's limits dropped (a 7th u64 counter).
STATUS_HEX = (
    "5103020464656d6f0200e8030000000000000000344003010f07000000d4030000000000000000f0"
    "3f000000000000004000000000000024c000000000000000000000000000000000000000000000e0"
    "3f00000000000010400000000000000240000000000000f03f640000000000000001000000000000"
    "00020000000000000003000000000000003200000000000000000000000000000004000000000000"
    "00020001000500"
)
#: the status before the radio's counter (from an older build: it decodes with 0 there)
STATUS_BEFORE_RADIO = replace(STATUS, counters=StatusCounters(100, 1, 2, 3, 50, 0))
#: Status version 2: the round the swarm took off (u32) after the plan's sequence number.
STATUS_V2_HEX = (
    "5102020464656d6f0200e8030000000000000000344003010f07000000d4030000000000000000f0"
    "3f000000000000004000000000000024c000000000000000000000000000000000000000000000e0"
    "3f00000000000010400000000000000240000000000000f03f640000000000000001000000000000"
    "000200000000000000030000000000000032000000000000000000000000000000020001000500"
)
#: Status version 1 (the same status from an agent of an older build: no take-off round).
STATUS_V1_HEX = (
    "5101020464656d6f0200e8030000000000000000344003010f07000000000000000000f03f000000"
    "000000004000000000000024c000000000000000000000000000000000000000000000e03f000000"
    "00000010400000000000000240000000000000f03f64000000000000000100000000000000020000"
    "0000000000030000000000000032000000000000000000000000000000020001000500"
)
_COEFFS = np.zeros((1, 9, 6))
_COEFFS[0, :, 0] = [0, 0, -10, 0, 0, 0, 4, 4, 1]
_COEFFS[0, 0, 1] = 0.5
PLAN = PlanMessage(DescriptorTrajectory(7, np.array([0.0, 10.0]), _COEFFS), FlightCommand.FLY)
PLAN_HEX = (  # header, seq 7, FLY, 2 knots, knots 0 and 10 s, then 54 coefficients, mostly 0
    "5101030464656d6f07000000010200"
    + "0000000000000000"
    + "0000000000002440"
    + "0000000000000000" * 1
    + "000000000000e03f"  # x: 0 + 0.5 tau
    + "0000000000000000" * 4
    + "0000000000000000" * 6  # y
    + "00000000000024c0"  # z: -10
    + "0000000000000000" * 5
    + "0000000000000000" * 18  # roll, pitch, yaw
    + ("0000000000001040" + "0000000000000000" * 5) * 2  # s1, s2: 4 m^2
    + "000000000000f03f"  # s3: 1 m^2
    + "0000000000000000" * 5
)


def same_message(a: ConsensusMessage, b: ConsensusMessage) -> bool:
    """Field by field, floats bit for bit (so -0.0 differs from 0.0); no edge incarnations
    (None) is the same as none said for any edge ({})."""
    tags_a = dict(a.edge_incarnations or {})
    tags_b = dict(b.edge_incarnations or {})
    return (
        (a.sender, a.round, a.heard, a.degree, a.ready_hops, a.incarnation, tags_a)
        == (b.sender, b.round, b.heard, b.degree, b.ready_hops, b.incarnation, tags_b)
        and a.takeoff_round == b.takeoff_round
        and np.asarray(a.gamma, dtype=np.float64).tobytes() == b.gamma.tobytes()
        and sorted(a.edge_sums) == sorted(b.edge_sums)
        and all(
            np.asarray(q, dtype=np.float64).tobytes() == b.edge_sums[j].tobytes()
            for j, q in a.edge_sums.items()
        )
    )


# --- golden bytes ------------------------------------------------------------------------------


def test_consensus_golden_bytes() -> None:
    data = encode_consensus(MESSAGE, POSITION, SID)
    assert data.hex() == CONSENSUS_HEX
    packet = decode_consensus(bytes.fromhex(CONSENSUS_HEX), SID)
    assert same_message(MESSAGE, packet.message)
    assert packet.position_ned_m.tolist() == list(POSITION)
    assert packet.message.position_ned_m is not None
    assert packet.message.position_ned_m.tolist() == list(POSITION)
    assert packet.velocity_ned_m_s is not None and packet.velocity_ned_m_s.tolist() == [*VELOCITY]
    assert not packet.velocity_ned_m_s.flags.writeable
    assert packet.message.takeoff_round == 980


def test_takeoff_round_round_trips_and_none_is_not_said() -> None:
    """A take-off round (0..0xFFFFFFFE) comes back as sent; None goes as 0xFFFFFFFF and comes
    back None."""
    for takeoff in (None, 0, 1, 123_456, 2**32 - 2):
        data = encode_consensus(replace(MESSAGE, takeoff_round=takeoff), POSITION, SID)
        assert len(data) == 504
        assert data[22:26] == struct.pack("<I", 0xFFFF_FFFF if takeoff is None else takeoff)
        packet = decode_consensus(data, SID)
        assert packet.message.takeoff_round == takeoff
        assert same_message(replace(MESSAGE, takeoff_round=takeoff), packet.message)
        assert consensus_origin(data, SID) == (2, POSITION)


@pytest.mark.parametrize("takeoff", [-1, 2**32 - 1, 2**32, True, 1.0])
def test_encoder_refuses_a_takeoff_round_out_of_range(takeoff: object) -> None:
    with pytest.raises(ValueError, match="takeoff_round"):
        encode_consensus(_with(takeoff_round=takeoff), POSITION, SID)


def test_version_3_consensus_still_decodes_without_a_takeoff_round() -> None:
    """A sender of an older build (schema 3) is heard: everything as sent, its take-off round
    not said (None)."""
    data = bytes.fromhex(CONSENSUS_V3_HEX)
    packet = decode_consensus(data, SID)
    assert packet.message.takeoff_round is None
    assert same_message(replace(MESSAGE, takeoff_round=None), packet.message)
    assert packet.velocity_ned_m_s is not None and packet.velocity_ned_m_s.tolist() == [*VELOCITY]
    assert consensus_origin(data, SID) == (2, POSITION)


def test_version_2_consensus_still_decodes_without_incarnations() -> None:
    """A sender of an older build (schema 2) is heard: incarnation 0, its sums taken as they are
    (no edge incarnations)."""
    data = bytes.fromhex(CONSENSUS_V2_HEX)
    packet = decode_consensus(data, SID)
    older = replace(MESSAGE, incarnation=0, edge_incarnations=None, takeoff_round=None)
    assert same_message(older, packet.message)
    assert packet.velocity_ned_m_s is not None and packet.velocity_ned_m_s.tolist() == [*VELOCITY]
    assert consensus_origin(data, SID) == (2, POSITION)


def test_edge_incarnations_not_given_go_as_not_said() -> None:
    """No edge incarnations (or a negative one: not known) are sent as 0xFFFFFFFF and decode
    as absent."""
    for tags in (None, {5: -1, 1: -1}):
        data = encode_consensus(replace(MESSAGE, edge_incarnations=tags), POSITION, SID)
        assert decode_consensus(data, SID).message.edge_incarnations == {}
    data = encode_consensus(replace(MESSAGE, edge_incarnations={5: 7}), POSITION, SID)
    assert decode_consensus(data, SID).message.edge_incarnations == {5: 7}
    with pytest.raises(ValueError, match="incarnation"):
        encode_consensus(replace(MESSAGE, incarnation=2**32), POSITION, SID)


def test_version_1_consensus_still_decodes_without_a_velocity() -> None:
    """A sender of an older build (schema 1, no velocity) is heard; its velocity is unknown."""
    data = bytes.fromhex(CONSENSUS_V1_HEX)
    packet = decode_consensus(data, SID)
    older = replace(
        MESSAGE, ready_hops=0, incarnation=0, edge_incarnations=None, takeoff_round=None
    )
    assert same_message(older, packet.message)  # v1: no settled level, no incarnations
    assert packet.position_ned_m.tolist() == list(POSITION)
    assert packet.message.position_ned_m is not None
    assert packet.velocity_ned_m_s is None and packet.message.velocity_ned_m_s is None
    assert consensus_origin(data, SID) == (2, POSITION)


def test_consensus_without_a_velocity_is_sent_at_rest() -> None:
    data = encode_consensus(replace(MESSAGE, velocity_ned_m_s=None), POSITION, SID)
    velocity = decode_consensus(data, SID).velocity_ned_m_s
    assert velocity is not None and velocity.tolist() == [0.0, 0.0, 0.0]


def test_consensus_layout_by_hand() -> None:
    """The layout of the module docstring, assembled with struct, is what the encoder writes."""
    ids = struct.pack("<3H", 1, 5, 7) + struct.pack("<2H", 1, 5)
    floats = (
        struct.pack("<18d", *GAMMA)
        + struct.pack("<18d", *-np.arange(18.0))
        + struct.pack("<18d", *2.0 ** -np.arange(18))
    )
    body = ids + floats
    expected = (
        bytes([0x51, CONSENSUS_VERSION, Kind.CONSENSUS, 4])
        + b"demo"
        + struct.pack("<IHHHII3f3fHH", 1000, 2, 3, 9, 950, 980, *POSITION, *VELOCITY, 3, 2)
        + ids
        + struct.pack("<2I", 0, 40)  # edge neighbours 1 and 5: their incarnations
        + floats
    )
    assert CONSENSUS_VERSION == 4
    assert encode_consensus(MESSAGE, POSITION, SID) == expected
    assert len(expected) == 504  # 500 at version 3, + 4 (take-off round)
    assert expected.hex() == CONSENSUS_HEX
    version_3 = (
        bytes([0x51, 3, Kind.CONSENSUS, 4])
        + b"demo"
        + struct.pack("<IHHHI3f3fHH", 1000, 2, 3, 9, 950, *POSITION, *VELOCITY, 3, 2)
        + ids
        + struct.pack("<2I", 0, 40)
        + floats
    )
    assert version_3.hex() == CONSENSUS_V3_HEX
    version_2 = (
        bytes([0x51, 2, Kind.CONSENSUS, 4])
        + b"demo"
        + struct.pack("<IHHH3f3fHH", 1000, 2, 3, 9, *POSITION, *VELOCITY, 3, 2)
        + body
    )
    assert version_2.hex() == CONSENSUS_V2_HEX
    version_1 = (
        bytes([0x51, 1, Kind.CONSENSUS, 4])
        + b"demo"
        + struct.pack("<IHH3fHH", 1000, 2, 3, *POSITION, 3, 2)
        + body
    )
    assert version_1.hex() == CONSENSUS_V1_HEX


def test_status_golden_bytes() -> None:
    assert STATUS_VERSION == 3
    assert encode_status(STATUS, SID).hex() == STATUS_HEX
    assert decode_status(bytes.fromhex(STATUS_HEX), SID) == STATUS
    assert decode_status(bytes.fromhex(STATUS_HEX), SID).counters.rx_lost_radio == 4
    # drone, round, t_s, mode FLYING, armed, health, plan_seq, take-off round, estimate,
    # counters (the radio's last), 2 neighbours
    fields = (2, 1000, 20.0, 3, 1, 15, 7, 980, *STATUS.estimate, 100, 1, 2, 3, 50, 0, 4, 2)
    by_hand = (
        bytes([0x51, STATUS_VERSION, Kind.STATUS, 4])
        + b"demo"
        + struct.pack("<HIdBBBII9d7QH", *fields)
        + struct.pack("<2H", 1, 5)
    )
    assert by_hand.hex() == STATUS_HEX
    # an agent of an older build (version 2: no radio counter) is read with 0 there
    older = decode_status(bytes.fromhex(STATUS_V2_HEX), SID)
    assert older == STATUS_BEFORE_RADIO and older.counters.rx_lost_radio == 0
    # decoded as the constructor makes a status: its enums, a read-only float estimate
    decoded = decode_status(bytes.fromhex(STATUS_HEX), SID)
    assert type(decoded.mode) is AgentMode and type(decoded.health) is Health
    assert decoded.estimate.dtype == np.float64 and not decoded.estimate.flags.writeable
    assert decoded.counters == StatusCounters(100, 1, 2, 3, 50, 0, 4)
    assert type(decoded.neighbours) is tuple and decoded.neighbours == (1, 5)


def test_status_takeoff_round_round_trips_and_version_1_decodes_without_one() -> None:
    for takeoff in (None, 0, 980, 2**32 - 2):
        status = replace(STATUS, takeoff_round=takeoff)
        decoded = decode_status(encode_status(status, SID), SID)
        assert decoded == status and decoded.takeoff_round == takeoff
    assert decode_status(encode_status(STATUS, SID), SID) != replace(STATUS, takeoff_round=None)
    older = decode_status(bytes.fromhex(STATUS_V1_HEX), SID)  # an agent of an older build
    assert older.takeoff_round is None
    assert older == replace(STATUS_BEFORE_RADIO, takeoff_round=None)
    for bad in (-1, 2**32 - 1, 2**32, True):
        with pytest.raises(ValueError, match="takeoff_round"):
            replace(STATUS, takeoff_round=bad)
    forced = replace(STATUS)
    object.__setattr__(forced, "takeoff_round", 2**32 - 1)  # set around AgentStatus's check
    with pytest.raises(ValueError, match="takeoff_round"):
        encode_status(forced, SID)


def test_plan_golden_bytes() -> None:
    assert encode_plan(PLAN, SID).hex() == PLAN_HEX
    assert decode_plan(bytes.fromhex(PLAN_HEX), SID) == PLAN


def test_eight_neighbour_message_is_compact_and_decodes_read_only() -> None:
    rng = np.random.default_rng(3)
    msg = ConsensusMessage(
        sender=0,
        round=5,
        gamma=rng.normal(size=18),
        edge_sums={j: rng.normal(size=18) for j in range(1, 9)},
        heard=frozenset(range(1, 9)),
        degree=8,
    )
    data = encode_consensus(msg, (0.0, 0.0, 0.0), SID)
    assert len(data) == 8 + 46 + 2 * 16 + 4 * 8 + 8 * 18 * 9  # 1414 bytes
    packet = decode_consensus(data, SID)
    assert not packet.message.gamma.flags.writeable
    assert not packet.message.edge_sums[3].flags.writeable
    assert consensus_origin(data, SID) == (0, (0.0, 0.0, 0.0))


# --- round trips -------------------------------------------------------------------------------

f64 = st.floats(allow_nan=False, allow_infinity=False)
vec18 = st.lists(f64, min_size=18, max_size=18).map(np.array)
ids = st.integers(0, 0xFFFF)


f32x3 = st.tuples(*[st.floats(width=32, allow_nan=False, allow_infinity=False)] * 3)


@st.composite
def consensus_messages(draw: st.DrawFn) -> ConsensusMessage:
    return ConsensusMessage(
        sender=draw(ids),
        round=draw(st.integers(0, 2**32 - 1)),
        gamma=draw(vec18),
        edge_sums=draw(st.dictionaries(ids, vec18, max_size=8)),
        heard=draw(st.frozensets(ids, max_size=20)),
        degree=draw(ids),
        velocity_ned_m_s=np.array(draw(f32x3)),
        takeoff_round=draw(st.none() | st.integers(0, 2**32 - 2)),
    )


@settings(max_examples=200, deadline=None)
@given(
    msg=consensus_messages(),
    position=f32x3,
    sid=st.from_regex(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}", fullmatch=True),
)
def test_consensus_round_trip_is_exact(
    msg: ConsensusMessage, position: tuple[float, float, float], sid: str
) -> None:
    data = encode_consensus(msg, position, sid)
    packet = decode_consensus(data, sid)
    assert same_message(msg, packet.message)
    assert packet.position_ned_m.tolist() == list(position)
    assert packet.velocity_ned_m_s is not None and msg.velocity_ned_m_s is not None
    assert packet.velocity_ned_m_s.tobytes() == msg.velocity_ned_m_s.tobytes()
    assert consensus_origin(data, sid) == (msg.sender, position)


@settings(max_examples=200, deadline=None)
@given(
    drone=ids,
    round_=st.integers(0, 2**32 - 1),
    t_s=f64,
    mode=st.sampled_from(AgentMode),
    armed=st.booleans(),
    health=st.integers(0, 15).map(Health),
    estimate=st.lists(st.floats(), min_size=9, max_size=9),  # NaN allowed: reported as is
    neighbours=st.frozensets(ids, max_size=30),
    counters=st.lists(st.integers(0, 2**64 - 1), min_size=7, max_size=7),
    plan_seq=st.none() | st.integers(0, 2**32 - 2),
    takeoff=st.none() | st.integers(0, 2**32 - 2),
)
def test_status_round_trip(
    drone: int,
    round_: int,
    t_s: float,
    mode: AgentMode,
    armed: bool,
    health: Health,
    estimate: list[float],
    neighbours: frozenset[int],
    counters: list[int],
    plan_seq: int | None,
    takeoff: int | None,
) -> None:
    status = AgentStatus(
        drone, round_, t_s, mode, armed, health, np.array(estimate), tuple(neighbours),
        StatusCounters(*counters), plan_seq, takeoff,
    )  # fmt: skip
    assert decode_status(encode_status(status, SID), SID) == status


@settings(max_examples=100, deadline=None)
@given(
    seq=st.integers(0, 2**32 - 1),
    gaps=st.lists(st.floats(1e-3, 1e3), min_size=1, max_size=5),
    start=st.floats(-1e4, 1e4),
    data=st.data(),
    command=st.sampled_from(FlightCommand),
)
def test_plan_round_trip(
    seq: int, gaps: list[float], start: float, data: st.DataObject, command: FlightCommand
) -> None:
    knots = start + np.cumsum([0.0, *gaps])
    if not np.all(np.diff(knots) > 0):
        return
    n = (len(knots) - 1) * 54
    coeffs = np.array(data.draw(st.lists(f64, min_size=n, max_size=n))).reshape(-1, 9, 6)
    plan = PlanMessage(DescriptorTrajectory(seq, knots, coeffs), command)
    assert decode_plan(encode_plan(plan, SID), SID) == plan


# --- encoder refusals --------------------------------------------------------------------------


def _with(**changes: object) -> ConsensusMessage:
    return replace(MESSAGE, **changes)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("message", "position", "match"),
    [
        (_with(gamma=np.full(18, math.nan)), POSITION, "finite"),
        (_with(edge_sums={1: np.full(18, math.inf)}), POSITION, "finite"),
        (_with(gamma=np.zeros(17)), POSITION, "shape"),
        (_with(sender=70000), POSITION, "sender"),
        (_with(round=-1), POSITION, "round"),
        (_with(heard=frozenset({-3})), POSITION, "heard"),
        (MESSAGE, (0.0, 0.0, 1e39), "finite"),  # overflows float32
        (MESSAGE, (0.0, math.nan, 0.0), "finite"),
        (_with(velocity_ned_m_s=np.array([0.0, math.inf, 0.0])), POSITION, "velocity"),
        (_with(velocity_ned_m_s=np.zeros(2)), POSITION, "velocity"),
    ],
)
def test_encoder_refuses_what_cannot_be_sent(
    message: ConsensusMessage, position: tuple[float, ...], match: str
) -> None:
    with pytest.raises(ValueError, match=match):
        encode_consensus(message, position, SID)


def test_the_largest_message_of_the_largest_swarm_is_sent_and_read() -> None:
    """A drone of a 250-drone swarm that has heard, and kept an edge to, every other one (edges
    stay while their link is down: a drone that flew past the swarm carries them all), under the
    longest swarm id, fits the default limit and reads back bit for bit."""
    others = [j for j in range(MAX_SWARM) if j != 7]
    big = _with(
        sender=7,
        heard=frozenset(others),
        edge_sums={j: np.full(18, 0.5 + j) for j in others},
        edge_incarnations=dict.fromkeys(others, 3),
        degree=len(others),
    )
    sid = "s" * 32
    data = encode_consensus(big, POSITION, sid)
    assert len(data) == MAX_CONSENSUS_BYTES
    got = decode_consensus(data, sid).message
    assert got.heard == big.heard and list(got.edge_sums) == others
    assert all(got.edge_sums[j].tobytes() == big.edge_sums[j].tobytes() for j in others)


def test_encoder_refuses_oversized_messages_and_bad_swarm_ids() -> None:
    big = _with(edge_sums={j: np.zeros(18) for j in range(200)})
    with pytest.raises(ValueError, match="exceeds"):
        encode_consensus(big, POSITION, SID, max_bytes=16 * 1024)
    encode_consensus(big, POSITION, SID)
    with pytest.raises(ValueError, match="swarm id"):
        encode_consensus(MESSAGE, POSITION, "no/slash")


# --- malformed input ---------------------------------------------------------------------------


def raw_consensus(
    *,
    magic: int = 0x51,
    version: int = CONSENSUS_VERSION,
    kind: int = Kind.CONSENSUS,
    sid: bytes = b"demo",
    sid_len: int | None = None,
    sender: int = 2,
    position: tuple[float, float, float] = (0.0, 0.0, 0.0),
    velocity: tuple[float, ...] = (0.0, 0.0, 0.0),
    heard: tuple[int, ...] = (1, 3),
    edge_ids: tuple[int, ...] = (1, 3),
    floats: list[float] | None = None,
    n_heard: int | None = None,
    n_edges: int | None = None,
    takeoff: int = 12,
    tail: bytes = b"",
) -> bytes:
    """A consensus payload packed by hand, without any validation (version 1: no velocity;
    before version 3: no incarnations; before version 4: no take-off round)."""
    floats = [0.25] * 18 * (1 + len(edge_ids)) if floats is None else floats
    velocity = () if version == 1 else velocity
    ready = () if version == 1 else (0,)
    incarnation = (5, takeoff) if version >= 4 else (5,) if version == 3 else ()
    tags = struct.pack(f"<{len(edge_ids)}I", *range(len(edge_ids))) if version >= 3 else b""
    return (
        bytes([magic, version, kind, len(sid) if sid_len is None else sid_len])
        + sid
        + struct.pack(
            f"<IHH{len(ready)}H{len(incarnation)}I3f{len(velocity)}fHH",
            7,
            sender,
            len(heard),
            *ready,
            *incarnation,
            *position,
            *velocity,
            len(heard) if n_heard is None else n_heard,
            len(edge_ids) if n_edges is None else n_edges,
        )
        + struct.pack(f"<{len(heard) + len(edge_ids)}H", *heard, *edge_ids)
        + tags
        + struct.pack(f"<{len(floats)}d", *floats)
        + tail
    )


def _floats_with(index: int, value: float) -> list[float]:
    floats = [0.25] * 18 * 3
    floats[index] = value
    return floats


MALFORMED_CONSENSUS = [
    ("empty", b"", Reason.TRUNCATED),
    ("three bytes", b"\x51\x01\x01", Reason.TRUNCATED),
    ("header only", raw_consensus()[:8], Reason.TRUNCATED),
    ("bad magic", raw_consensus(magic=0x52), Reason.BAD_MAGIC),
    ("newer version", raw_consensus(version=CONSENSUS_VERSION + 1), Reason.BAD_VERSION),
    ("version 0", raw_consensus(version=0), Reason.BAD_VERSION),
    ("status kind", raw_consensus(kind=Kind.STATUS), Reason.WRONG_KIND),
    ("unknown kind", raw_consensus(kind=200), Reason.WRONG_KIND),
    ("another swarm", raw_consensus(sid=b"other"), Reason.WRONG_SWARM),
    ("empty swarm id", raw_consensus(sid=b""), Reason.WRONG_SWARM),
    ("swarm id past the end", raw_consensus(sid_len=250)[:40], Reason.TRUNCATED),
    ("one byte short", raw_consensus()[:-1], Reason.TRUNCATED),
    ("one byte long", raw_consensus(tail=b"\0"), Reason.TRAILING),
    ("edge count too high", raw_consensus(n_edges=3), Reason.TRUNCATED),
    ("heard count too low", raw_consensus(n_heard=1), Reason.TRAILING),
    ("heard count huge", raw_consensus(n_heard=0xFFFF), Reason.TRUNCATED),
    ("NaN gamma", raw_consensus(floats=_floats_with(0, math.nan)), Reason.NOT_FINITE),
    ("inf edge sum", raw_consensus(floats=_floats_with(40, -math.inf)), Reason.NOT_FINITE),
    ("NaN position", raw_consensus(position=(0.0, math.nan, 0.0)), Reason.NOT_FINITE),
    ("inf velocity", raw_consensus(velocity=(0.0, 0.0, -math.inf)), Reason.NOT_FINITE),
    ("inf - inf", raw_consensus(velocity=(math.inf, -math.inf, 0.0)), Reason.NOT_FINITE),
    ("version 1 one byte short", raw_consensus(version=1)[:-1], Reason.TRUNCATED),
    ("version 1 NaN", raw_consensus(version=1, position=(math.nan, 0, 0)), Reason.NOT_FINITE),
    ("version 2 one byte short", raw_consensus(version=2)[:-1], Reason.TRUNCATED),
    ("version 2 with tags", raw_consensus(version=2, tail=bytes(8)), Reason.TRAILING),
    ("version 3 one byte short", raw_consensus(version=3)[:-1], Reason.TRUNCATED),
    ("version 3 with a takeoff", raw_consensus(version=3, tail=bytes(4)), Reason.TRAILING),
    # version 4 cut in its take-off round, and at the end of its fixed fields
    ("version 4 cut in its takeoff", raw_consensus(version=4)[: 8 + 16], Reason.TRUNCATED),
    ("version 4 fields only", raw_consensus(version=4)[: 8 + 46], Reason.TRUNCATED),
    ("version 4 one byte short", raw_consensus(version=4)[:-1], Reason.TRUNCATED),
    ("duplicate heard id", raw_consensus(heard=(3, 3)), Reason.BAD_VALUE),
    ("unsorted edge ids", raw_consensus(edge_ids=(3, 1)), Reason.BAD_VALUE),
    ("oversized", raw_consensus(tail=bytes(MAX_CONSENSUS_BYTES)), Reason.OVERSIZED),
]


@pytest.mark.parametrize(("data", "reason"), [c[1:] for c in MALFORMED_CONSENSUS],
                         ids=[c[0] for c in MALFORMED_CONSENSUS])  # fmt: skip
def test_malformed_consensus_is_rejected_with_its_reason(data: bytes, reason: Reason) -> None:
    with pytest.raises(WireError) as info:
        decode_consensus(data, SID)
    assert info.value.reason is reason
    assert str(info.value).startswith(reason.value)


@pytest.mark.parametrize("version", [1, 2, 3, 4])
def test_hand_packed_reference_payload_decodes(version: int) -> None:
    packet = decode_consensus(raw_consensus(version=version, velocity=(1.0, 2.0, 3.0)), SID)
    assert packet.message.heard == frozenset({1, 3}) and sorted(packet.message.edge_sums) == [1, 3]
    assert packet.message.incarnation == (5 if version >= 3 else 0)
    assert packet.message.takeoff_round == (12 if version >= 4 else None)
    tags = packet.message.edge_incarnations
    assert tags == ({1: 0, 3: 1} if version >= 3 else None)
    velocity = packet.velocity_ned_m_s
    assert velocity is None if version == 1 else velocity.tolist() == [1.0, 2.0, 3.0]


def test_size_limit_is_configurable() -> None:
    data = raw_consensus()
    with pytest.raises(WireError) as info:
        decode_consensus(data, SID, max_bytes=len(data) - 1)
    assert info.value.reason is Reason.OVERSIZED
    decode_consensus(data, SID, max_bytes=len(data))


def _status_bytes(
    mode: int = 3,
    armed: int = 1,
    health: int = 15,
    t_s: float = 1.0,
    version: int = STATUS_VERSION,
) -> bytes:
    takeoff = (40,) if version >= 2 else ()
    counters = 7 if version >= 3 else 6
    fixed = struct.pack(f"<HIdBBBI{len(takeoff)}I9d{counters}QH", 2, 9, t_s, mode, armed, health,
                        7, *takeoff, *[0.0] * 9, *[0] * counters, 2)  # fmt: skip
    return bytes([0x51, version, Kind.STATUS, 4]) + b"demo" + fixed + struct.pack("<2H", 1, 5)


def test_hand_packed_statuses_of_every_version_decode() -> None:
    assert decode_status(_status_bytes(), SID).takeoff_round == 40
    assert decode_status(_status_bytes(version=2), SID).takeoff_round == 40
    assert decode_status(_status_bytes(version=1), SID).takeoff_round is None


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (_status_bytes(version=1)[:-2], Reason.TRUNCATED),
        (_status_bytes(version=1) + b"\0", Reason.TRAILING),
        (_status_bytes(version=4), Reason.BAD_VERSION),
        (_status_bytes(version=0), Reason.BAD_VERSION),
        (_status_bytes()[: 8 + 20], Reason.TRUNCATED),  # cut in its take-off round
        (_status_bytes(mode=99), Reason.BAD_VALUE),
        (_status_bytes(armed=2), Reason.BAD_VALUE),
        (_status_bytes(health=0x80), Reason.BAD_VALUE),
        (_status_bytes(t_s=math.nan), Reason.NOT_FINITE),
        (_status_bytes()[:-2], Reason.TRUNCATED),
        (_status_bytes() + b"\0", Reason.TRAILING),
        (_status_bytes()[:-4] + struct.pack("<2H", 5, 1), Reason.BAD_VALUE),
        (raw_consensus(), Reason.WRONG_KIND),
    ],
)
def test_malformed_status_is_rejected(data: bytes, reason: Reason) -> None:
    assert decode_status(_status_bytes(), SID).neighbours == (1, 5)
    with pytest.raises(WireError) as info:
        decode_status(data, SID)
    assert info.value.reason is reason


def _plan_bytes(k: int = 2, command: int = 1, knots: tuple[float, ...] = (0.0, 1.0),
                coeff: float = 0.0, n_coeffs: int | None = None) -> bytes:  # fmt: skip
    n = 54 * (len(knots) - 1) if n_coeffs is None else n_coeffs
    body = struct.pack("<IBH", 3, command, k) + struct.pack(f"<{len(knots)}d", *knots)
    return (
        bytes([0x51, WIRE_VERSION, Kind.PLAN, 4])
        + b"demo"
        + body
        + struct.pack(f"<{n}d", *[coeff] * n)
    )


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (_plan_bytes(k=1, knots=(0.0,), n_coeffs=0), Reason.BAD_VALUE),
        (_plan_bytes(knots=(1.0, 0.0)), Reason.BAD_VALUE),
        (_plan_bytes(command=9), Reason.BAD_VALUE),
        (_plan_bytes(coeff=math.nan), Reason.NOT_FINITE),
        (_plan_bytes(k=3), Reason.TRUNCATED),
        (_plan_bytes(n_coeffs=55), Reason.TRAILING),
    ],
)
def test_malformed_plan_is_rejected(data: bytes, reason: Reason) -> None:
    assert decode_plan(_plan_bytes(), SID).seq == 3
    with pytest.raises(WireError) as info:
        decode_plan(data, SID)
    assert info.value.reason is reason


# --- fuzzing: nothing but WireError ------------------------------------------------------------

DECODERS: list[Callable[[bytes, str], object]] = [
    decode_consensus,
    decode_status,
    decode_plan,
    consensus_origin,
    decode_consensus,
    decode_consensus,
    decode_status,
]
VALID = [
    bytes.fromhex(CONSENSUS_HEX),
    bytes.fromhex(STATUS_HEX),
    bytes.fromhex(PLAN_HEX),
    bytes.fromhex(CONSENSUS_HEX),
    bytes.fromhex(CONSENSUS_V1_HEX),
    bytes.fromhex(CONSENSUS_V3_HEX),
    bytes.fromhex(STATUS_V1_HEX),
    bytes.fromhex(STATUS_V2_HEX),
]


@settings(max_examples=300, deadline=None)
@given(data=st.binary(max_size=600))
def test_random_bytes_raise_only_wire_errors(data: bytes) -> None:
    for decode in DECODERS:
        for payload in (data, bytes([0x51, WIRE_VERSION]) + data):
            with contextlib.suppress(WireError):
                decode(payload, SID)


@settings(max_examples=300, deadline=None)
@given(
    which=st.integers(0, len(DECODERS) - 1),
    flips=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=6),
    cut=st.integers(0, 10_000),
    extra=st.binary(max_size=40),
)
def test_mutated_payloads_raise_only_wire_errors(
    which: int, flips: list[tuple[int, int]], cut: int, extra: bytes
) -> None:
    """Valid payloads with bytes changed, cut short or extended: decoded or WireError."""
    data = bytearray(VALID[which])
    for at, value in flips:
        data[at % len(data)] = value
    payload = bytes(data[: max(cut, 1)]) + extra if cut < len(data) else bytes(data) + extra
    with contextlib.suppress(WireError):
        DECODERS[which](payload, SID)


def test_consensus_head_reads_sender_round_and_origin_of_every_version() -> None:
    from protocols.wire.format import consensus_head

    data = encode_consensus(MESSAGE, POSITION, SID)
    assert consensus_head(data, SID) == (MESSAGE.sender, MESSAGE.round, POSITION)
    assert consensus_head(bytes.fromhex(CONSENSUS_V1_HEX), SID) == (2, 1000, POSITION)
    assert consensus_head(bytes.fromhex(CONSENSUS_V3_HEX), SID) == (2, 1000, POSITION)
