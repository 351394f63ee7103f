"""The lockstep barrier with injected wall-clock times: join, echo, await, drop, leave."""

from __future__ import annotations

import pytest

from sitl_sim.mavlink_edge.lockstep import LockstepBarrier


def test_first_echo_joins_and_then_each_tick_waits_for_it() -> None:
    b = LockstepBarrier(drop_timeout_s=2.0)
    b.open_tick(0, [0, 1], wall_s=0.0)
    assert b.complete and not b.members
    assert b.echo(0, 0) and b.members == {0}
    assert b.complete  # joined with the current tick's echo: nothing awaited
    b.open_tick(1, [0, 1], wall_s=0.1)
    assert not b.complete and b.awaiting == {0}
    assert not b.echo(0, 0)  # an old tick does not count
    assert not b.complete
    b.echo(0, 1)
    assert b.complete


def test_only_agents_that_got_the_tick_are_awaited() -> None:
    b = LockstepBarrier(2.0)
    b.open_tick(0, [0, 1], 0.0)
    b.echo(0, 0), b.echo(1, 0)
    b.open_tick(1, [1], 0.1)  # vehicle 0's agent asked for a lower rate
    assert b.awaiting == {1}


def test_a_silent_agent_is_dropped_after_the_timeout_and_can_rejoin() -> None:
    b = LockstepBarrier(drop_timeout_s=2.0)
    b.open_tick(0, [0, 1], 0.0)
    b.echo(0, 0), b.echo(1, 0)
    b.open_tick(1, [0, 1], 10.0)
    b.echo(1, 1)
    assert b.deadline_wall_s() == pytest.approx(12.0)
    assert b.expire(11.9) == []
    assert b.expire(12.0) == [0]
    assert b.members == {1} and b.complete
    b.open_tick(2, [0, 1], 12.1)
    assert b.echo(0, 1)  # a late echo of a recent tick: back in, awaited from the next tick
    assert b.awaiting == {1}


def test_echoes_of_future_or_ancient_ticks_or_no_tick_are_ignored() -> None:
    b = LockstepBarrier(2.0, join_window_ticks=50)
    b.open_tick(100, [0], 0.0)
    assert not b.echo(0, 101)
    assert not b.echo(0, 49)
    assert not b.echo(0, None)
    assert not b.members


def test_leave_removes_at_once() -> None:
    b = LockstepBarrier(2.0)
    b.open_tick(0, [0], 0.0)
    b.echo(0, 0)
    b.open_tick(1, [0], 0.0)
    b.leave(0)
    assert b.complete and not b.members and b.deadline_wall_s() is None


def test_timeout_must_be_positive() -> None:
    with pytest.raises(ValueError):
        LockstepBarrier(0.0)
