"""The report's agent timing (gcs/report/agent_timing.py): figures from the simulator's
NAMED_VALUE_FLOAT in flight.tlog, overload intervals, and each failsafe explained."""

from __future__ import annotations

import numpy as np

from gcs.report.agent_timing import explain_failsafes, summary_lines, timing_metrics
from gcs.report.tlog import TlogTrack, VehicleTrack


def _track(named: dict[str, np.ndarray]) -> VehicleTrack:
    empty3 = np.zeros((0, 3))
    track = VehicleTrack(np.zeros(0), empty3, empty3, np.zeros(0), empty3, empty3)
    track.named = named
    return track


def test_figures_per_drone_and_overloaded_intervals() -> None:
    t = np.arange(1.0, 6.0)
    good = _track({"agt_intime": np.c_[t, np.ones(5)], "agt_lag_ms": np.c_[t, np.zeros(5)]})
    shares = np.array([1.0, 0.98, 0.4, 1.0, 1.0])
    bad = _track({"agt_intime": np.c_[t, shares], "agt_lag_ms": np.c_[t, [0, 20, 300, 0, 0]]})
    m = timing_metrics(TlogTrack({1: good, 2: bad}), [])
    assert m["measured"] and m["overloaded"]
    assert m["overloaded_intervals"] == 1  # (1 + 0.4) / 2 = 0.7; (1 + 0.98) / 2 = 0.99 is not
    assert m["per_drone"]["1"]["in_time_min"] == 0.4 and m["per_drone"]["1"]["worst_lag_ms"] == 300
    assert m["per_drone"]["0"]["in_time_min"] == 1.0
    lines = summary_lines(m)
    assert "worst agent 40.0% of ticks, worst lag 300 ms" in lines[0]
    assert "OVERLOAD" in lines[1] and "--clock lockstep" in lines[1]


def test_lockstep_runs_have_no_figures() -> None:
    m = timing_metrics(TlogTrack({1: _track({})}), [])
    assert not m["measured"] and not m["overloaded"] and m["in_time_min"] is None
    assert summary_lines(m) == []


def test_failsafes_are_blamed_on_an_overload_only_when_one_was_reported_near_them() -> None:
    events = [
        {"t_s": 10.0, "kind": "failsafe", "drone": 3, "text": "Failsafe: offboard lost (0.5 s)"},
        {"t_s": 10.6, "kind": "overload", "drone": 3, "text": "Agent late: 40% of ticks in time"},
        {"t_s": 10.5, "kind": "failsafe", "drone": 3, "text": "Failsafe: descending to land"},
        {"t_s": 20.0, "kind": "overload", "drone": 1, "text": "Agent late: 80% of ticks"},
        {"t_s": 30.0, "kind": "failsafe", "drone": 1, "text": "Failsafe: offboard lost (0.5 s)"},
    ]
    explained = explain_failsafes(events)
    assert [(f["drone"], f["cause"]) for f in explained] == [(3, "overload"), (1, "no setpoints")]
    assert explained[0]["detail"].startswith("Agent late: 40%")
    lines = summary_lines({"measured": False, "failsafes": explained})
    assert lines[0] == (
        "  drone 3 failed safe at 10.0 s: its agent fell behind (Agent late: 40% of ticks in time)"
    )
    assert lines[1].endswith("its agent stopped or left the swarm")


def test_a_failsafe_after_the_agent_left_is_blamed_on_the_leaving_not_on_lateness() -> None:
    # large_grid25 in realtime: drone 19's agent is dropped by the scenario at 12.0 s, its
    # vehicle fails safe at 12.5 s, and the interval report at 12.22 s still says it was late
    # (its ticks before 12.0): the summary said "its agent fell behind"
    events = [
        {"t_s": 0.0, "kind": "agent_joined", "drone": 19},
        {"t_s": 11.2, "kind": "overload", "drone": 19, "text": "Agent late: 71% of ticks"},
        {"t_s": 12.0, "kind": "dropout_detected", "drone": 19},
        {"t_s": 12.22, "kind": "overload", "drone": 19, "text": "Agent late: 73% of ticks"},
        {"t_s": 12.5, "kind": "failsafe", "drone": 19, "text": "Failsafe: offboard lost (0.5 s)"},
        # drone 4 left and came back (a restart drill): a later failsafe is judged afresh
        {"t_s": 5.0, "kind": "dropout_detected", "drone": 4},
        {"t_s": 8.0, "kind": "agent_joined", "drone": 4},
        {"t_s": 20.0, "kind": "overload", "drone": 4, "text": "Agent late: 50% of ticks"},
        {"t_s": 20.5, "kind": "failsafe", "drone": 4, "text": "Failsafe: offboard lost (0.5 s)"},
    ]
    explained = explain_failsafes(events)
    assert [(f["drone"], f["cause"]) for f in explained] == [(19, "agent left"), (4, "overload")]
    lines = summary_lines({"measured": False, "failsafes": explained})
    assert lines[0] == "  drone 19 failed safe at 12.5 s: its agent had left the swarm at 12.0 s"


def test_a_few_dips_in_a_long_flight_are_reported_as_brief_not_as_a_machine_that_cannot() -> None:
    # large_grid25 in realtime on two cores: 96-100 % of the ticks in time per 10 s, 1-8 of
    # ~45 one-second intervals below 90 %, a lag of two ticks at worst
    t = np.arange(1.0, 41.0)
    shares = np.ones(40)
    shares[[6, 25]] = 0.8
    lag = np.full(40, 20.0)
    lag[6] = 40.0
    m = timing_metrics(TlogTrack({1: _track({"agt_intime": np.c_[t, shares],
                                             "agt_lag_ms": np.c_[t, lag]})}), [])  # fmt: skip
    assert m["overloaded"] and not m["sustained"]
    assert m["intervals"] == 40 and m["overloaded_intervals"] == 2 and m["in_time_mean"] == 0.99
    line = summary_lines(m)[1]
    assert line.startswith("  behind realtime briefly: 2 of 40 one-second intervals below 90%")
    assert "99.0% in time over the run, worst lag 40 ms" in line and "OVERLOAD" not in line
