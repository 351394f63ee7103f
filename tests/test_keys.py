"""Zenoh key expressions of a swarm: swarm ids, spatial cells and their coverage, key parsing."""

from __future__ import annotations

import math

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols.bus.memory import key_matches
from protocols.wire.keys import (
    SwarmKeys,
    cell_of,
    cell_size_for,
    neighbourhood,
    track_cell,
    validate_drone_id,
    validate_swarm_id,
)

pytestmark = pytest.mark.timeout(60)


@pytest.mark.parametrize("sid", ["a", "demo", "Swarm_01", "x-y", "9", "A" * 32])
def test_valid_swarm_ids(sid: str) -> None:
    assert validate_swarm_id(sid) == sid
    assert SwarmKeys(sid, 10.0).prefix == f"swarm/{sid}"


@pytest.mark.parametrize(
    "sid", ["", "a/b", "a*", "**", "$x", "a#", "a?b", "é", "-lead", "_lead", "a b", "A" * 33]
)
def test_invalid_swarm_ids_are_refused_with_the_rule(sid: str) -> None:
    with pytest.raises(ValueError, match="1-32 characters"):
        validate_swarm_id(sid)
    with pytest.raises(ValueError):
        SwarmKeys(sid, 10.0)


@pytest.mark.parametrize("drone", [-1, 65536, 1.0, True, "3"])
def test_invalid_drone_ids(drone: object) -> None:
    with pytest.raises(ValueError, match="drone id"):
        validate_drone_id(drone)  # type: ignore[arg-type]


def test_keys_of_a_swarm() -> None:
    keys = SwarmKeys("demo", 12.0)
    assert keys.consensus((0, -1, 2), 7) == "swarm/demo/consensus/0/-1/2/7"
    assert keys.consensus_cell((0, -1, 2)) == "swarm/demo/consensus/0/-1/2/*"
    assert keys.alive(3) == "swarm/demo/alive/3"
    assert keys.alive_all() == "swarm/demo/alive/*"
    assert keys.status(3) == "swarm/demo/status/3"
    assert keys.status_all() == "swarm/demo/status/*"
    assert keys.plan == "swarm/demo/plan"
    assert keys.fault == "swarm/demo/fault"
    assert keys.command == "swarm/demo/command"
    assert keys.consensus_all() == "swarm/demo/consensus/**"
    with pytest.raises(ValueError):
        SwarmKeys("demo", 0.0)
    with pytest.raises(ValueError):
        SwarmKeys("demo", math.inf)


def test_every_key_is_a_valid_zenoh_key_expression() -> None:
    keys = SwarmKeys("demo", 12.0)
    built = [keys.consensus((-3, 0, 4), 65535), keys.alive(0), keys.status(9), keys.plan]
    built += [
        keys.fault,
        keys.command,
        keys.alive_all(),
        keys.consensus_all(),
        *keys.consensus_subscriptions((0, 0, -1)),
    ]
    for key in built:
        assert str(zenoh.KeyExpr(key)) == key


def test_drone_of_parses_only_this_swarms_keys() -> None:
    keys = SwarmKeys("demo", 12.0)
    assert keys.drone_of("swarm/demo/consensus/1/-2/3/42") == 42
    assert keys.drone_of("swarm/demo/alive/0") == 0
    assert keys.drone_of("swarm/demo/status/65535") == 65535
    for bad in (
        "swarm/other/alive/1",  # another swarm
        "swarm/demo/plan",
        "swarm/demo/alive/01",  # leading zero: one spelling per drone
        "swarm/demo/alive/65536",
        "swarm/demo/alive/-1",
        "swarm/demo/alive/x",
        "swarm/demo/alive/١",  # a non-ASCII digit
        "swarm/demo/consensus/0/0/7",  # too few chunks
        "swarm/demo/alive/1/2",
        "fleet/demo/alive/1",
    ):
        assert keys.drone_of(bad) is None, bad


def test_cells_floor_positions_also_below_zero() -> None:
    assert cell_of([0.0, 9.99, 10.0], 10.0) == (0, 0, 1)
    assert cell_of([-0.01, -10.0, -10.01], 10.0) == (-1, -1, -2)
    with pytest.raises(ValueError, match="finite"):
        cell_of([math.nan, 0.0, 0.0], 10.0)
    with pytest.raises(ValueError, match="3 components"):
        cell_of([0.0, 0.0], 10.0)


def test_neighbourhood_is_the_3x3x3_block() -> None:
    block = neighbourhood((5, -1, 0))
    assert len(set(block)) == 27 and (5, -1, 0) in block
    assert all(max(abs(a - b) for a, b in zip(c, (5, -1, 0), strict=True)) <= 1 for c in block)
    subs = SwarmKeys("demo", 10.0).consensus_subscriptions((5, -1, 0))
    assert len(set(subs)) == 27


def test_track_cell_keeps_a_drone_on_a_boundary_in_one_cell() -> None:
    cell = None
    seen = set()
    for k in range(100):  # on the ground at z = 0, jittering by a micrometre
        cell = track_cell(cell, [3.0, 4.0, (-1) ** k * 1e-6], 12.0, 1.0)
        seen.add(cell)
    assert len(seen) == 1
    assert track_cell((0, 0, 0), [12.9, 0.0, 0.0], 12.0, 1.0) == (0, 0, 0)  # within hysteresis
    assert track_cell((0, 0, 0), [13.0, 0.0, 0.0], 12.0, 1.0) == (1, 0, 0)  # past it
    assert track_cell((0, 0, 0), [30.0, 0.0, 0.0], 12.0, 1.0) == (2, 0, 0)  # a jump


coordinate = st.floats(-200.0, 200.0, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(
    p=st.tuples(coordinate, coordinate, coordinate),
    direction=st.tuples(coordinate, coordinate, coordinate),
    distance_fraction=st.floats(0.0, 0.999),
    lag_p=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
    lag_q=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
    comm_range_m=st.floats(1.0, 50.0),
    hysteresis_fraction=st.floats(0.0, 0.3),
)
def test_the_27_cells_cover_every_drone_in_range(
    p: tuple[float, float, float],
    direction: tuple[float, float, float],
    distance_fraction: float,
    lag_p: tuple[float, float, float],
    lag_q: tuple[float, float, float],
    comm_range_m: float,
    hysteresis_fraction: float,
) -> None:
    """Whatever cell each drone still holds (lagging by up to the hysteresis), a sender within
    range publishes into one of the 27 cells its receiver subscribes to."""
    norm = math.sqrt(sum(d * d for d in direction))
    if norm < 1e-6:
        return
    h = hysteresis_fraction * comm_range_m
    size = cell_size_for(comm_range_m, h)
    q = [a + d / norm * distance_fraction * comm_range_m for a, d in zip(p, direction, strict=True)]

    def held_cell(x: list[float] | tuple[float, ...], lag: tuple[float, ...]) -> tuple[int, ...]:
        before = cell_of([a + b * h for a, b in zip(x, lag, strict=True)], size)
        return track_cell(before, x, size, h)

    assert held_cell(q, lag_q) in neighbourhood(held_cell(p, lag_p))  # type: ignore[arg-type]


chunk = st.sampled_from(["swarm", "demo", "0", "-1", "7", "consensus", "alive"])


@settings(max_examples=300, deadline=None)
@given(
    key=st.lists(chunk, min_size=1, max_size=6),
    expr=st.lists(
        st.sampled_from(["swarm", "demo", "0", "-1", "7", "*", "**"]), min_size=1, max_size=6
    ),
)
def test_memory_bus_matching_agrees_with_zenoh(key: list[str], expr: list[str]) -> None:
    k = "/".join(key)
    e = str(zenoh.KeyExpr.autocanonize("/".join(expr)))  # Zenoh only takes canonical forms
    assert key_matches("/".join(expr), k) == key_matches(e, k)
    assert key_matches(e, k) == zenoh.KeyExpr(e).intersects(zenoh.KeyExpr(k))


def test_the_cell_of_a_consensus_key() -> None:
    keys = SwarmKeys("s1", 10.0)
    assert keys.cell_of_key(keys.consensus((-1, 2, 0), 7)) == (-1, 2, 0)
    assert keys.cell_of_key("swarm/s1/consensus/1/2/3/x") == (1, 2, 3)  # a bad id: drone_of's
    for key in ("swarm/s2/consensus/1/2/3/7", "swarm/s1/status/7", "swarm/s1/consensus/a/2/3/7",
                "swarm/s1/consensus/1/2/7"):  # fmt: skip
        assert keys.cell_of_key(key) is None, key
