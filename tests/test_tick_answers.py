"""Whether agents keep up with the control ticks (sitl_sim/vehicle/tick_answers.py): answered in
time, late, skipped, a drop-out that is not an overload."""

from __future__ import annotations

from sitl_sim.vehicle.tick_answers import TickAnswers


def test_an_agent_that_keeps_up_answers_every_tick_in_time() -> None:
    t = TickAnswers(2)
    for k in range(100):
        t.sent(k, [0, 1])
        t.echo(0, k)
        t.echo(1, k)
    stats = t.interval()
    assert stats.share(0) == 1.0 and stats.swarm_share == 1.0
    assert stats.worst_lag == 0 and not stats.overloaded


def test_a_slow_agent_answers_late_and_skips_ticks() -> None:
    t = TickAnswers(2)
    for k in range(100):
        t.sent(k, [0, 1])
        t.echo(0, k)
        if k % 2 == 1:  # agent 1 answers every other tick, one tick late
            t.echo(1, k - 1)
    stats = t.interval()
    assert stats.share(0) == 1.0
    assert stats.share(1) == 0.0  # never in time
    assert stats.worst_lag_ticks[1] == 2  # its newest answer is up to two ticks behind
    assert stats.expected[1] >= 98
    assert stats.overloaded and stats.swarm_share is not None and stats.swarm_share < 0.6


def test_an_agent_that_dies_is_a_drop_out_not_an_overload() -> None:
    t = TickAnswers(2)
    for k in range(50):
        t.sent(k, [0, 1])
        t.echo(0, k)
        if k < 20:
            t.echo(1, k)
    stats = t.interval()
    assert stats.share(1) == 1.0 and not stats.overloaded
    assert stats.worst_lag_ticks[1] == 0  # a silence that has not ended is not a lag
    for k in range(50, 100):
        t.sent(k, [0, 1])
        t.echo(0, k)
    stats = t.interval()
    assert not stats.active[1] and stats.share(1) is None and stats.swarm_share == 1.0


def test_a_stalled_agent_that_comes_back_counts_what_it_missed() -> None:
    t = TickAnswers(1)
    for k in range(10):
        t.sent(k, [0])
        t.echo(0, k)
    for k in range(10, 40):  # a 30-tick stall
        t.sent(k, [0])
    t.echo(0, 12)  # a stale answer
    stats = t.interval()
    assert stats.worst_lag == 29  # ticks 10..39 went out with tick 9 the newest answer
    assert stats.in_time[0] == 10 and stats.expected[0] == 39  # tick 39 still awaited
    assert t.interval().expected[0] == 0  # the new interval starts empty


def test_ticks_never_sent_and_echoes_of_the_future_are_ignored() -> None:
    t = TickAnswers(1)
    t.echo(0, 5)
    t.echo(0, None)
    stats = t.interval()
    assert not stats.active[0] and stats.swarm_share is None and not stats.overloaded


def test_the_ticks_before_an_agents_first_answer_are_not_counted() -> None:
    """An agent still starting (its process joining the swarm) is not late: its ticks count
    from its first answer on; a stall after that counts in full."""
    t = TickAnswers(2)
    for k in range(30):
        t.sent(k, [0, 1])
        t.echo(0, k)
        if k >= 20:  # agent 1 answers from tick 20 on, every tick in time
            t.echo(1, k)
    stats = t.interval()
    assert stats.expected[1] == 10 and stats.in_time[1] == 10 and stats.share(1) == 1.0
    assert stats.worst_lag_ticks[1] == 0 and not stats.overloaded
    for k in range(30, 60):  # then it stalls for 20 ticks and answers again
        t.sent(k, [0, 1])
        t.echo(0, k)
        if k >= 50:
            t.echo(1, k)
    stats = t.interval()
    assert stats.expected[1] == 30 and stats.in_time[1] == 10 and stats.overloaded
