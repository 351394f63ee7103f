"""Message-interval bookkeeping: rates in control ticks, changes, defaults, sharing."""

from __future__ import annotations

import pytest

from sitl_sim.mavlink_edge.streams import (
    AGENT_RATES_HZ,
    ATTITUDE,
    HEARTBEAT,
    LOCAL_POSITION_NED,
    StreamSchedule,
    StreamTable,
)

CONTROL_HZ = 50


def _counts(schedule: StreamSchedule, ticks: int) -> dict[int, int]:
    counts: dict[int, int] = {}
    for k in range(ticks):
        for msg_id in schedule.due(k):
            counts[msg_id] = counts.get(msg_id, 0) + 1
    return counts


def test_default_agent_rates_over_ten_seconds() -> None:
    counts = _counts(StreamSchedule(AGENT_RATES_HZ, CONTROL_HZ), 10 * CONTROL_HZ)
    assert counts[ATTITUDE] == counts[LOCAL_POSITION_NED] == 500
    assert counts[HEARTBEAT] == 10


@pytest.mark.parametrize("rate_hz", [1.0, 7.0, 10.0, 20.0, 30.0, 45.0, 50.0])
def test_any_rate_up_to_the_control_rate_is_met_on_average(rate_hz: float) -> None:
    schedule = StreamSchedule(AGENT_RATES_HZ, CONTROL_HZ)
    assert schedule.set_interval_us(ATTITUDE, 1e6 / rate_hz)
    assert _counts(schedule, 100 * CONTROL_HZ)[ATTITUDE] == pytest.approx(100 * rate_hz, abs=1)


def test_faster_than_the_control_rate_is_capped() -> None:
    schedule = StreamSchedule(AGENT_RATES_HZ, CONTROL_HZ)
    assert schedule.set_interval_us(ATTITUDE, 1000)  # 1 kHz asked
    assert _counts(schedule, 100)[ATTITUDE] == 100
    assert schedule.interval_us(ATTITUDE) == 20_000


def test_off_default_and_unknown_messages() -> None:
    schedule = StreamSchedule(AGENT_RATES_HZ, CONTROL_HZ)
    assert schedule.set_interval_us(ATTITUDE, -1)
    assert schedule.interval_us(ATTITUDE) == -1
    assert ATTITUDE not in _counts(schedule, 100)
    assert schedule.set_interval_us(ATTITUDE, 0)
    assert schedule.interval_us(ATTITUDE) == 20_000
    assert not schedule.set_interval_us(148, 1e5)  # AUTOPILOT_VERSION is not streamed
    assert not schedule.set_interval_us(ATTITUDE, float("nan"))
    assert schedule.interval_us(148) == 0


def test_due_is_idempotent_within_a_tick() -> None:
    schedule = StreamSchedule(AGENT_RATES_HZ, CONTROL_HZ)
    first = schedule.due(0)
    assert schedule.due(0) == first and HEARTBEAT in first
    assert HEARTBEAT not in schedule.due(1)


def test_a_late_schedule_does_not_burst() -> None:
    schedule = StreamSchedule(AGENT_RATES_HZ, CONTROL_HZ)
    schedule.due(0)
    assert schedule.due(500).count(HEARTBEAT) == 1
    assert HEARTBEAT not in schedule.due(501)


def test_table_copies_on_write() -> None:
    table = StreamTable(3, AGENT_RATES_HZ, CONTROL_HZ)
    assert table.of(0) is table.of(2) is table.shared
    table.own(1).set_interval_us(ATTITUDE, 1e5)
    assert table.of(1) is not table.shared
    assert table.shared.interval_us(ATTITUDE) == 20_000
    assert table.of(1).interval_us(ATTITUDE) == 100_000
