"""The ground station's per-drone bookkeeping: link quality from status counters, liveliness
events, vehicle texts, and the ``swarm status`` table against the vehicles' true positions."""

from __future__ import annotations

import numpy as np

from gcs.station.swarm_watch import SwarmWatch, text_kind
from gcs.station.telemetry import VehicleState
from protocols.wire.status import AgentMode, AgentStatus, Health, StatusCounters


def _status(drone: int, round_: int, rx: int, neighbours: tuple[int, ...]) -> AgentStatus:
    estimate = np.array([1.0, 0.0, -2.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.0])
    return AgentStatus(
        drone,
        round_,
        round_ / 50,
        AgentMode.FLYING,
        True,
        Health(0),
        estimate,
        neighbours,
        StatusCounters(rx=rx),
    )


def test_link_quality_is_the_share_of_expected_messages_smoothed() -> None:
    watch = SwarmWatch()
    watch.on_status(_status(0, 10, 0, (1, 2)))
    assert 0 not in watch.link_quality  # needs two statuses
    watch.on_status(_status(0, 12, 4, (1, 2)))  # 2 rounds x 2 neighbours, all 4 came
    assert watch.link_quality[0] == 1.0
    for k in range(1, 60):  # from now on half of them
        watch.on_status(_status(0, 12 + 2 * k, 4 + 2 * k, (1, 2)))
    assert abs(watch.link_quality[0] - 0.5) < 0.01
    watch.on_status(_status(0, 5, 0, (1, 2)))  # a restarted agent: rounds went back, no update
    assert abs(watch.link_quality[0] - 0.5) < 0.01


def test_liveliness_and_vehicle_texts_give_events() -> None:
    watch = SwarmWatch()
    assert watch.on_liveliness(3, True) == "agent_joined"
    assert watch.on_liveliness(3, True) is None
    assert watch.on_liveliness(3, False) == "dropout_detected"
    assert watch.on_liveliness(3, False) is None
    assert watch.on_vehicle_text(1, 4, "Failsafe: no offboard setpoint") == "failsafe"
    assert watch.on_vehicle_text(1, 6, "Armed") == "vehicle_text"
    assert watch.failsafes == {1: 1}
    assert text_kind(0, "anything") == "crash"
    assert text_kind(2, "Failure injected: all motors off") == "crash"


def test_status_table_errors_against_the_alive_vehicles() -> None:
    watch = SwarmWatch()
    vehicles = {
        0: VehicleState(position_ned_m=(0.0, 0.0, -2.0), armed=True),
        1: VehicleState(position_ned_m=(2.0, 0.0, -2.0), armed=True),
        2: VehicleState(position_ned_m=(50.0, 0.0, 0.0)),  # its agent is not alive: left out
    }
    for i in (0, 1):
        watch.on_liveliness(i, True)
        watch.on_status(_status(i, 10, 0, (1 - i,)))
    rows = watch.table(vehicles)
    assert [r["drone"] for r in rows] == [0, 1, 2]
    assert rows[0]["estimate_error_m"] == 0.0  # the estimate (1, 0, -2) is the true centre
    assert rows[2]["mode"] is None and rows[2]["alive"] is False
    assert watch.worst_error_m(vehicles) == 0.0
    assert SwarmWatch().worst_error_m({}) is None


def test_link_quality_expects_every_alive_drone_in_radio_range() -> None:
    """With the radio's range and the vehicles' positions, a drone is expected to hear every
    other alive drone in range once a round. Regression: the share used to be taken over the
    neighbours the agent integrated that round, which fall with the messages lost, so a 50 %
    loss drill showed 100 %."""
    vehicles = {i: VehicleState(position_ned_m=(2.0 * i, 0.0, -3.0)) for i in range(5)}
    vehicles[5] = VehicleState(position_ned_m=(40.0, 0.0, -3.0))  # alive but out of range
    watch = SwarmWatch(range_m=10.0)
    for i in range(6):
        watch.on_liveliness(i, True)
    watch.on_liveliness(4, False)  # left the swarm: no longer expected
    assert watch.senders(_status(0, 10, 0, ()), vehicles) == 3  # 1, 2, 3
    watch.on_status(_status(0, 10, 0, (1, 2, 3)), vehicles)
    rx = 0
    for k in range(1, 80):  # half of the 3 messages a round come; one neighbour integrated
        rx += 3
        watch.on_status(_status(0, 10 + 2 * k, rx, (1 + k % 3,)), vehicles)
    assert abs(watch.link_quality[0] - 0.5) < 0.01
    for k in range(80, 160):  # none come: the quality falls, though no neighbour is listed
        watch.on_status(_status(0, 10 + 2 * k, rx, ()), vehicles)
    assert watch.link_quality[0] < 0.01
    # without the range (or the drone's position) it falls back to the listed neighbours
    assert SwarmWatch().senders(_status(0, 10, 0, (1, 2)), vehicles) == 2
    assert watch.senders(_status(7, 10, 0, (1,)), vehicles) == 1


def test_link_quality_of_a_clean_link_is_full_though_messages_straddle_statuses() -> None:
    """Every message arrives, but one lands just after a status now and then: 14 then 18 of the
    16 expected. The smoothed share stays at 100 % (clipping each status's share at 1 read 94 %)."""
    watch = SwarmWatch()
    rx = 0
    for k in range(100):
        rx += 14 if k % 2 else 18
        watch.on_status(_status(0, 2 * k, rx, tuple(range(1, 9))))
    assert watch.link_quality[0] > 0.99


def test_crashed_and_departed_drones_keep_their_row_with_the_reason_and_time() -> None:
    from gcs.cli.operator import format_reply
    from gcs.station.commands import Reply

    watch = SwarmWatch()
    for i in range(3):
        watch.on_liveliness(i, True, 0.5)
        watch.on_status(_status(i, 50, 0, ()))
    assert watch.on_vehicle_text(1, 0, "Crashed: all motors off", 30.0) == "crash"
    watch.on_liveliness(1, False, 30.1)  # its agent leaves after the crash: the crash is why
    assert watch.on_liveliness(2, False, 41.0) == "dropout_detected"
    rows = {r["drone"]: r for r in watch.table({})}
    assert rows[0]["mode"] == "FLYING" and rows[0]["lost"] is None
    assert rows[1]["mode"] == "LOST"
    assert rows[1]["lost"] == {"t_s": 30.0, "reason": "vehicle crashed: Crashed: all motors off"}
    assert rows[2]["mode"] == "LOST" and rows[2]["lost"]["t_s"] == 41.0
    lines = format_reply("status", Reply(True, "t = 50.00 s", 1, tuple(rows.values())))
    assert "drone 1 lost at t = 30.0 s: vehicle crashed: Crashed: all motors off" in lines
    assert "drone 2 lost at t = 41.0 s: its agent left the swarm" in lines
    watch.on_liveliness(2, True, 45.0)  # restarted: back in the swarm
    assert {r["drone"]: r for r in watch.table({})}[2]["lost"] is None
