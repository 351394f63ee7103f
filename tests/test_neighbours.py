"""Neighbour positions and velocities from an agent's inbox of consensus messages."""

from __future__ import annotations

import numpy as np
import pytest

from drone_agent.core.neighbours import NeighbourTable, neighbour_arrays, neighbours_from_inbox
from drone_agent.core.separation.filter import SeparationParams, filter_accelerations
from protocols.wire.consensus_message import ConsensusMessage
from protocols.wire.format import decode_consensus, encode_consensus

pytestmark = pytest.mark.timeout(60)

DT = 0.02


def msg(sender: int, round_: int, pos: tuple[float, float, float] | None = (0.0, 0.0, -5.0),
        vel: tuple[float, float, float] | None = (0.0, 0.0, 0.0)) -> ConsensusMessage:  # fmt: skip
    return ConsensusMessage(
        sender, round_, np.zeros(18), {}, frozenset(), 0,
        position_ned_m=None if pos is None else np.array(pos),
        velocity_ned_m_s=None if vel is None else np.array(vel),
    )  # fmt: skip


def test_newest_per_sender_extrapolated_by_velocity_times_age() -> None:
    inbox = [
        msg(3, 98, (0.0, 0.0, -5.0), (1.0, 0.0, 0.0)),
        msg(3, 99, (0.02, 0.0, -5.0), (1.0, 0.0, 0.0)),  # the newest of 3: one tick old
        msg(1, 97, (5.0, 5.0, -5.0), (0.0, -2.0, 0.5)),  # three ticks old
    ]
    nb = neighbours_from_inbox(inbox, own=0, round_now=100, dt_s=DT)
    assert nb.ids == (1, 3) and nb.age_rounds.tolist() == [3, 1]
    np.testing.assert_allclose(nb.position_ned_m, [[5.0, 4.88, -4.97], [0.04, 0.0, -5.0]])
    np.testing.assert_allclose(nb.velocity_ned_m_s, [[0.0, -2.0, 0.5], [1.0, 0.0, 0.0]])
    assert nb.velocity_known.all()
    raw = neighbours_from_inbox(inbox, own=0, round_now=100, dt_s=DT, extrapolate=False)
    np.testing.assert_allclose(raw.position_ned_m, [[5.0, 5.0, -5.0], [0.02, 0.0, -5.0]])


def test_stale_own_future_and_positionless_messages_are_left_out() -> None:
    inbox = [
        msg(1, 94),  # 6 ticks old: beyond the heard timeout
        msg(0, 100),  # our own
        msg(2, 101),  # from the future (a later round): ignored this tick ...
        msg(2, 99),  # ... its message of a past round is used
        msg(4, 100, pos=None),  # no position: cannot be avoided
        msg(5, 95),  # exactly 5 ticks old: still heard
    ]
    nb = neighbours_from_inbox(inbox, own=0, round_now=100, dt_s=DT)
    assert nb.ids == (2, 5) and nb.age_rounds.tolist() == [1, 5]
    assert neighbours_from_inbox(inbox, own=0, round_now=100, dt_s=DT, max_age_rounds=2).ids == (2,)


def test_a_version_1_sender_is_taken_at_rest() -> None:
    nb = neighbours_from_inbox([msg(7, 98, (1.0, 2.0, -3.0), None)], 0, 100, DT)
    assert nb.ids == (7,) and not nb.velocity_known[0]
    assert nb.position_ned_m.tolist() == [[1.0, 2.0, -3.0]]
    assert nb.velocity_ned_m_s.tolist() == [[0.0, 0.0, 0.0]]


def test_the_table_keeps_the_newest_message_of_each_sender_across_ticks() -> None:
    table = NeighbourTable(DT)
    table.hear([0], 6, [[msg(1, 5, (1.0, 0.0, -5.0)), msg(2, 3, (2.0, 0.0, -5.0))]])
    table.hear([0], 7, [[msg(1, 4, (9.0, 0.0, -5.0)), msg(2, 6, (3.0, 0.0, -5.0))]])
    pairs = table.query([0], 7)
    assert pairs.ids.tolist() == [1, 2] and pairs.age_rounds.tolist() == [2, 1]
    assert pairs.position_ned_m[:, 0].tolist() == [1.0, 3.0]  # round 4 of 1 came too late
    assert table.query([0], 11).ids.tolist() == [2]  # 1 is 6 rounds old: gone, 2 is 5


def test_a_message_from_a_later_round_waits_for_it() -> None:
    table = NeighbourTable(DT)
    table.hear([0], 10, [[msg(1, 9, (1.0, 0.0, -5.0)), msg(1, 11, (2.0, 0.0, -5.0))]])
    assert table.query([0], 10).position_ned_m[:, 0].tolist() == [1.0]  # round 9's
    table.hear([0], 11, [[]])
    assert table.query([0], 11).position_ned_m[:, 0].tolist() == [2.0]  # round 11's, now


def test_equal_rounds_keep_the_first_copy_and_agents_keep_their_own_views() -> None:
    table = NeighbourTable(DT)
    a, b = msg(2, 4, (1.0, 0.0, -5.0)), msg(2, 4, (7.0, 0.0, -5.0))
    table.hear([0, 1], 5, [[a, b], [b, a]])
    pairs = table.query([0, 1], 5)
    assert pairs.owner.tolist() == [0, 1] and pairs.position_ned_m[:, 0].tolist() == [1.0, 7.0]
    assert table.query([3], 5).counts.tolist() == [0]  # an agent that heard nothing


def test_from_the_wire_to_the_filter() -> None:
    """Two drones head-on: each one's message, through the wire, is what the other avoids."""
    states = {0: ((0.0, 0.0, -5.0), (2.0, 0.0, 0.0)), 1: ((1.4, 0.0, -5.0), (-2.0, 0.0, 0.0))}
    wire = {
        j: decode_consensus(encode_consensus(msg(j, 41, vel=v), p, "demo"), "demo").message
        for j, (p, v) in states.items()
    }
    per_agent = [neighbours_from_inbox(wire.values(), own=i, round_now=42, dt_s=DT)
                 for i in (0, 1)]  # fmt: skip
    pos, vel, mask, ids = neighbour_arrays(per_agent)
    assert ids.tolist() == [[1], [0]] and mask.all()
    own_p = np.array([np.add(states[i][0], np.multiply(states[i][1], DT)) for i in (0, 1)])
    np.testing.assert_allclose(pos[:, 0], own_p[::-1], atol=1e-6)  # extrapolated one tick
    own_v = np.array([states[i][1] for i in (0, 1)])
    r = filter_accelerations(own_p, own_v, np.zeros((2, 3)), pos, vel, mask, SeparationParams())
    assert r.active.all() and r.accel_ned_m_s2[0, 0] < 0 < r.accel_ned_m_s2[1, 0]  # both brake


def test_arrays_pad_agents_with_fewer_neighbours() -> None:
    a = neighbours_from_inbox([msg(1, 9), msg(2, 9)], 0, 10, DT)
    b = neighbours_from_inbox([], 1, 10, DT)
    pos, vel, mask, ids = neighbour_arrays([a, b])
    assert pos.shape == vel.shape == (2, 2, 3)
    assert mask.tolist() == [[True, True], [False, False]] and ids.tolist() == [[1, 2], [-1, -1]]
    assert neighbour_arrays([])[0].shape == (0, 1, 3)


def _query_rule(table: NeighbourTable, rows: np.ndarray, round_now: int) -> tuple[np.ndarray, ...]:
    """NeighbourTable.query's rule as numpy wrote it, on the table's arrays (the reference of
    the compiled pass): owner, ids, positions, velocities, ages, velocity known, counts."""
    width = table._width
    age = round_now - table._round[rows, :width]
    heard = (age >= 0) & (age <= table.max_age_rounds)
    owner, ids = np.nonzero(heard)
    age_p = age[owner, ids]
    vel = table._vel[rows[owner], ids]
    pos = table._pos[rows[owner], ids] + vel * (age_p * table.dt_s)[:, None]
    known = table._known[rows[owner], ids]
    return owner, ids, pos, vel, age_p, known, np.bincount(owner, minlength=rows.shape[0])


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_the_query_is_the_numpy_rule_to_the_last_bit(seed: int) -> None:
    """NeighbourTable.query (one compiled pass) gives the pairs, in order, and every value bit
    for bit as the numpy rule it replaced, over random tables: senders heard at random rounds
    (some in the future, some too old), agents queried in any order and subsets, positions and
    velocities over many scales, version-1 senders (velocity unknown), an agent that heard
    nobody."""
    rng = np.random.default_rng(seed)
    dt = float(rng.choice([0.02, 0.01, 1 / 30]))
    table = NeighbourTable(dt)
    agents = list(range(20))
    table.rows_of(agents)
    k, width = len(agents), 40
    table._width = width
    table._round[:k, :width] = rng.integers(-10, 110, (k, width))
    table._round[:k, :width][rng.random((k, width)) < 0.3] = np.iinfo(np.int64).min // 2
    table._round[7] = np.iinfo(np.int64).min // 2  # heard nobody
    scale = 10.0 ** rng.integers(-3, 4, (k, 1, 1))
    table._pos[:k, :width] = rng.normal(size=(k, width, 3)) * scale
    table._vel[:k, :width] = rng.normal(size=(k, width, 3)) * scale / 7.0
    table._known[:k, :width] = rng.random((k, width)) < 0.8
    for _ in range(30):
        ask = [int(a) for a in rng.permutation(k)[: int(rng.integers(1, k + 1))]]
        round_now = int(rng.integers(0, 110))
        got = table.query(ask, round_now)
        want = _query_rule(table, np.array(ask, dtype=np.intp), round_now)
        fields = (got.owner, got.ids, got.position_ned_m, got.velocity_ned_m_s, got.age_rounds,
                  got.velocity_known, got.counts)  # fmt: skip
        for name, a, b in zip(("owner", "ids", "pos", "vel", "age", "known", "counts"),
                              fields, want, strict=True):  # fmt: skip
            assert a.dtype.kind == b.dtype.kind and a.shape == b.shape, name
            assert a.tobytes() == np.ascontiguousarray(b, dtype=a.dtype).tobytes(), name
    assert got.owner.shape[0] > 0
